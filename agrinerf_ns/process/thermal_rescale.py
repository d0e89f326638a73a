"""Raw 16-bit thermal counts -> 8-bit frames.

``fieldscale`` follows the idea of Fieldscale (Gil, Jeon, Kim, RA-L 2024), written from the paper's description:

1. per frame, the minimum and maximum counts on a ``grid`` of patches (two small "fields");
2. local extrema suppression: a patch whose max is above all of its 8 neighbours' maxima is lowered to the
   largest of them (and a min below all neighbours' minima raised), so one hot or dead spot cannot set its patch;
3. ``message_passing_iters`` rounds of 3x3 message passing: each node takes max(self, mean of its 3x3
   neighbourhood) for the max field (min(...) for the min field), which spreads the range smoothly;
4. shared statistics over the sequence: the fields are smoothed along time with a Gaussian of
   ``temporal_sigma`` frames (``inf``: one pair of fields for the whole sequence), so the mapping from counts to
   grey levels does not flicker from frame to frame;
5. bilinear upsampling of both fields to full resolution, pixel-wise rescale ``(I - min) / (max - min)``
   clipped to [0, 1], with the range never below ``min_range_frac`` of the sequence's global range (flat frames
   map to mid grey, no division by zero);
6. optional gamma and CLAHE, then 8 bit.

``global`` is the plain baseline: one min/max over the whole sequence. ``per-frame`` (min/max of each frame) is
kept only as the flickering reference the tests compare against.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Dict, Iterable, List, Literal, Optional, Sequence, Tuple

import cv2
import numpy as np
from jaxtyping import Float, UInt8, UInt16

from agrinerf_ns.images import to_uint8


@dataclass
class ThermalRescaleConfig:
    """Parameters of the thermal rescaling (recorded in the dataset's ``agrinerf.thermal_rescale``)."""

    method: Literal["fieldscale", "global", "per-frame"] = "fieldscale"
    """fieldscale: local min/max fields; global: one min/max for the sequence; per-frame: min/max of each frame."""
    grid: Tuple[int, int] = (8, 8)
    """Patches per column and per row (rows, cols) of the local min/max fields."""
    min_patch_px: int = 12
    """Patches are at least this many pixels on a side (fewer patches on small frames)."""
    patch_percentile: float = 0.0
    """Robust patch extremes: percentile p and 100 - p instead of min and max (0 = strict min/max)."""
    suppress_extrema: bool = True
    """Lower isolated local maxima / raise isolated local minima of the fields to their neighbours'."""
    message_passing_iters: int = 3
    """Rounds of 3x3 message passing on the fields."""
    temporal_sigma: float = 3.0
    """Gaussian smoothing of the fields along the sequence, in frames (0: none, inf: one field for all frames)."""
    min_range_frac: float = 0.05
    """Local range floor, as a fraction of the sequence's global range (avoids noise blow-up and division by 0)."""
    global_percentile: float = 0.1
    """The global baseline's range: percentile p to 100 - p of all counts in the sequence."""
    gamma: float = 1.0
    """Output gamma (out = rescaled ** gamma)."""
    clahe: bool = False
    """Apply CLAHE after rescaling (per frame: adds some frame-to-frame variation)."""
    clahe_clip: float = 2.0
    """CLAHE clip limit."""

    def as_dict(self) -> Dict:
        d = asdict(self)
        d["grid"] = list(self.grid)
        d["temporal_sigma"] = float(self.temporal_sigma) if np.isfinite(self.temporal_sigma) else "inf"
        return d


class ThermalRescaler:
    """Fit sequence statistics with :meth:`fit` (one pass over the frames), then :meth:`apply` frame by frame."""

    def __init__(self, config: ThermalRescaleConfig) -> None:
        self.config = config
        self.lo_fields: Optional[np.ndarray] = None  # (T, gh, gw)
        self.hi_fields: Optional[np.ndarray] = None
        self.global_lo = 0.0
        self.global_hi = 1.0
        self.min_range = 1.0
        self.shape: Tuple[int, ...] = ()

    def fit(self, frames: Iterable[np.ndarray]) -> "ThermalRescaler":
        """``frames``: a sequence (or any re-iterable) of raw frames in time order."""
        cfg = self.config
        los, his, g_lo, g_hi = [], [], [], []
        for frame in frames:
            f = np.asarray(frame, dtype=np.float32)
            self.shape = f.shape
            if cfg.global_percentile > 0:
                lo, hi = np.percentile(f, [cfg.global_percentile, 100 - cfg.global_percentile])
            else:
                lo, hi = float(f.min()), float(f.max())
            g_lo.append(lo)
            g_hi.append(hi)
            if cfg.method == "fieldscale":
                lo_f, hi_f = local_minmax_fields(f, effective_grid(f.shape, cfg), cfg.patch_percentile)
                if cfg.suppress_extrema:
                    lo_f, hi_f = suppress_local_extrema(lo_f, hi_f)
                lo_f, hi_f = message_passing(lo_f, hi_f, cfg.message_passing_iters)
                los.append(lo_f)
                his.append(hi_f)
            else:
                los.append(np.full((1, 1), f.min(), np.float32))
                his.append(np.full((1, 1), f.max(), np.float32))
        if not g_lo:
            raise ValueError("no thermal frames to fit")
        self.global_lo, self.global_hi = float(min(g_lo)), float(max(g_hi))
        self.min_range = max(1.0, cfg.min_range_frac * (self.global_hi - self.global_lo))
        lo_t, hi_t = np.stack(los), np.stack(his)
        if cfg.method == "fieldscale":
            lo_t, hi_t = temporal_smooth(lo_t, cfg.temporal_sigma), temporal_smooth(hi_t, cfg.temporal_sigma)
        self.lo_fields, self.hi_fields = lo_t, hi_t
        return self

    def apply(self, frame: UInt16[np.ndarray, "h w"], index: int) -> UInt8[np.ndarray, "h w"]:
        """Rescale frame number ``index`` of the fitted sequence to 8 bit."""
        if self.lo_fields is None or self.hi_fields is None:
            raise RuntimeError("call fit() first")
        cfg = self.config
        f = np.asarray(frame, dtype=np.float32)
        h, w = f.shape
        if cfg.method == "global":
            lo = np.full_like(f, self.global_lo)
            hi = np.full_like(f, self.global_hi)
        elif cfg.method == "per-frame":
            lo = np.full_like(f, self.lo_fields[index, 0, 0])
            hi = np.full_like(f, self.hi_fields[index, 0, 0])
        else:
            lo = cv2.resize(self.lo_fields[index], (w, h), interpolation=cv2.INTER_LINEAR)
            hi = cv2.resize(self.hi_fields[index], (w, h), interpolation=cv2.INTER_LINEAR)
        out = rescale_with_fields(f, lo, hi, self.min_range if cfg.method == "fieldscale" else 1.0)
        if cfg.gamma != 1.0:
            out = np.power(out, cfg.gamma)
        img = to_uint8(out)
        if cfg.clahe:
            img = cv2.createCLAHE(clipLimit=cfg.clahe_clip, tileGridSize=tuple(cfg.grid)).apply(img)
        return img

    def params(self) -> Dict:
        """Configuration plus the fitted sequence statistics, for the dataset metadata."""
        grid = list(effective_grid(self.shape, self.config)) if self.shape else list(self.config.grid)
        return {
            **self.config.as_dict(),
            "effective_grid": grid,
            "global_lo": self.global_lo,
            "global_hi": self.global_hi,
            "min_range": self.min_range,
        }


def rescale_sequence(frames: List[UInt16[np.ndarray, "h w"]], config: ThermalRescaleConfig) -> List[np.ndarray]:
    """Convenience: fit on ``frames`` and rescale all of them."""
    r = ThermalRescaler(config).fit(frames)
    return [r.apply(f, i) for i, f in enumerate(frames)]


def effective_grid(shape: Tuple[int, ...], cfg: ThermalRescaleConfig) -> Tuple[int, int]:
    """The configured grid, reduced so that patches have at least ``min_patch_px`` pixels a side."""
    m = max(1, cfg.min_patch_px)
    return max(1, min(cfg.grid[0], shape[0] // m)), max(1, min(cfg.grid[1], shape[1] // m))


def local_minmax_fields(
    frame: Float[np.ndarray, "h w"], grid: Tuple[int, int], percentile: float = 0.0
) -> Tuple[Float[np.ndarray, "gh gw"], Float[np.ndarray, "gh gw"]]:
    """Min and max (or percentile p / 100 - p) of each patch of a ``grid`` = (rows, cols) partition."""
    h, w = frame.shape
    gh, gw = min(grid[0], h), min(grid[1], w)
    ys = np.linspace(0, h, gh + 1).round().astype(int)
    xs = np.linspace(0, w, gw + 1).round().astype(int)
    lo = np.empty((gh, gw), np.float32)
    hi = np.empty((gh, gw), np.float32)
    for i in range(gh):
        for j in range(gw):
            patch = frame[ys[i] : ys[i + 1], xs[j] : xs[j + 1]]
            if percentile > 0:
                lo[i, j], hi[i, j] = np.percentile(patch, [percentile, 100 - percentile])
            else:
                lo[i, j], hi[i, j] = patch.min(), patch.max()
    return lo, hi


def suppress_local_extrema(
    lo: Float[np.ndarray, "gh gw"], hi: Float[np.ndarray, "gh gw"]
) -> Tuple[Float[np.ndarray, "gh gw"], Float[np.ndarray, "gh gw"]]:
    """Clamp each node of the max field to its 8 neighbours' largest max (and the min field to their smallest)."""
    ring = np.ones((3, 3), np.uint8)
    ring[1, 1] = 0
    nb_max = cv2.dilate(hi, ring, borderType=cv2.BORDER_REPLICATE)
    nb_min = cv2.erode(lo, ring, borderType=cv2.BORDER_REPLICATE)
    if hi.size == 1:
        return lo, hi
    return np.maximum(lo, nb_min), np.minimum(hi, nb_max)


def message_passing(
    lo: Float[np.ndarray, "gh gw"], hi: Float[np.ndarray, "gh gw"], iters: int
) -> Tuple[Float[np.ndarray, "gh gw"], Float[np.ndarray, "gh gw"]]:
    """``iters`` rounds: hi <- max(hi, mean3x3(hi)), lo <- min(lo, mean3x3(lo)) (edges replicated)."""
    for _ in range(iters):
        hi = np.maximum(hi, cv2.blur(hi, (3, 3), borderType=cv2.BORDER_REPLICATE))
        lo = np.minimum(lo, cv2.blur(lo, (3, 3), borderType=cv2.BORDER_REPLICATE))
    return lo, hi


def temporal_smooth(fields: Float[np.ndarray, "t gh gw"], sigma: float) -> Float[np.ndarray, "t gh gw"]:
    """Gaussian smoothing along axis 0 (edges renormalised); ``inf`` gives the sequence mean for every frame."""
    t = fields.shape[0]
    if sigma <= 0 or t == 1:
        return fields
    if not np.isfinite(sigma):
        return np.repeat(fields.mean(axis=0, keepdims=True), t, axis=0)
    idx = np.arange(t, dtype=np.float64)
    wts = np.exp(-0.5 * ((idx[:, None] - idx[None, :]) / sigma) ** 2)
    wts /= wts.sum(axis=1, keepdims=True)
    return np.tensordot(wts, fields.astype(np.float64), axes=(1, 0)).astype(np.float32)


def rescale_with_fields(
    frame: Float[np.ndarray, "h w"], lo: Float[np.ndarray, "h w"], hi: Float[np.ndarray, "h w"], min_range: float
) -> Float[np.ndarray, "h w"]:
    """(I - lo) / (hi - lo) clipped to [0, 1]; ranges below ``min_range`` are widened about their centre."""
    rng = hi - lo
    mid = 0.5 * (hi + lo)
    rng_eff = np.maximum(rng, max(min_range, 1e-6))
    lo_eff = mid - 0.5 * rng_eff
    return np.clip((frame - lo_eff) / rng_eff, 0.0, 1.0)


# ----------------------------------------------------------------------------------------------------------------
# measures used by the tests and the README figure


def local_contrast(img: UInt8[np.ndarray, "h w"], window: int = 9) -> float:
    """Mean local standard deviation (grey levels) over ``window`` x ``window`` neighbourhoods."""
    f = img.astype(np.float64)
    mean = cv2.blur(f, (window, window))
    sq = cv2.blur(f * f, (window, window))
    return float(np.sqrt(np.maximum(sq - mean * mean, 0.0)).mean())


def static_pixel_flicker(
    raws: Sequence[UInt16[np.ndarray, "h w"]], outs: Sequence[UInt8[np.ndarray, "h w"]], tol_frac: float = 0.005
) -> float:
    """Flicker: mean |out_t - out_t+1| (grey levels) over pixels whose raw count changed by at most
    ``tol_frac`` of the sequence's range between the two frames (same radiance must keep the same grey level)."""
    g_lo = min(float(r.min()) for r in raws)
    g_hi = max(float(r.max()) for r in raws)
    tol = max(1.0, tol_frac * (g_hi - g_lo))
    diffs = []
    for t in range(len(raws) - 1):
        same = np.abs(raws[t].astype(np.float32) - raws[t + 1].astype(np.float32)) <= tol
        if np.any(same):
            d = np.abs(outs[t].astype(np.float32) - outs[t + 1].astype(np.float32))
            diffs.append(float(d[same].mean()))
    return float(np.mean(diffs)) if diffs else 0.0
