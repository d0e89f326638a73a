"""Event stream -> one event frame per RGB frame, accumulated in time windows aligned with the RGB timestamps.

Window of RGB frame k (times t_k in seconds): ``anchor="end"`` (default) is [t_k - window, t_k), the events that
led up to the frame, and ``anchor="center"`` is [t_k - window/2, t_k + window/2). ``window`` defaults to the
median RGB frame interval, so with "end" consecutive windows tile the stream between frames.

Kept per window (in the event camera's pixels, then warped into the RGB camera by :mod:`.align`):
``pos`` and ``neg``, the counts of ON and OFF events per pixel (the signed polarity sum is ``pos - neg``), and the
window bounds, saved as ``events/NNNNNN.npz`` for a later physically based event loss.

Single-channel frame in [0, 1] (``representation``):

- ``signed``: ``0.5 + 0.5 * clip((pos - neg) / scale, -1, 1)``: 0.5 means no change, above 0.5 net brightening,
  below net darkening;
- ``count``: ``clip((pos + neg) / scale, 0, 1)``.

``scale`` is ``clip_count`` when given, else shared over the sequence: the 99th percentile of the per-pixel
absolute value (over pixels with events, all windows). Written as 8-bit PNG ``round(255 * value)`` (no change = 128).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Dict, Iterable, Iterator, Literal, Optional, Tuple

import numpy as np
from jaxtyping import Float, Int32

from agrinerf_ns.process.readers import EventChunk


@dataclass
class EventFrameConfig:
    """How events become frames (recorded in the dataset's ``agrinerf.events``)."""

    window_s: Optional[float] = None
    """Window length in seconds; None = median RGB frame interval."""
    anchor: Literal["end", "center"] = "end"
    """Window placement relative to the RGB timestamp."""
    representation: Literal["signed", "count"] = "signed"
    """Single-channel frame representation (module docstring)."""
    clip_count: Optional[float] = None
    """Normalising count; None = 99th percentile of |value| over the sequence."""
    chunk_size: int = 2_000_000
    """Events read per chunk (memory is O(chunk_size + frames in flight x pixels))."""

    def as_dict(self) -> Dict:
        return asdict(self)


def event_windows(
    frame_times: Float[np.ndarray, " n"], config: EventFrameConfig
) -> Tuple[Float[np.ndarray, " n"], Float[np.ndarray, " n"], float]:
    """Window start and end times in seconds for each frame, and the window length used."""
    if config.window_s is not None:
        window = float(config.window_s)
    elif frame_times.shape[0] > 1:
        window = float(np.median(np.diff(frame_times)))
    else:
        raise ValueError("one RGB frame only: set the event window length explicitly")
    if not window > 0:
        raise ValueError(f"event window must be positive, got {window}")
    if config.anchor == "end":
        start, end = frame_times - window, frame_times.copy()
    else:
        start, end = frame_times - 0.5 * window, frame_times + 0.5 * window
    return start, end, window


def accumulate_windows(
    chunks: Iterable[EventChunk],
    t_start_s: Float[np.ndarray, " n"],
    t_end_s: Float[np.ndarray, " n"],
    width: int,
    height: int,
) -> Iterator[Tuple[int, Int32[np.ndarray, "h w"], Int32[np.ndarray, "h w"]]]:
    """Stream (frame index, ON counts, OFF counts) for windows [start, end), in frame order.

    Windows must be sorted by start and by end. Only windows that the current chunk can still touch are held in
    memory: a window is yielded as soon as the stream has passed its end.
    """
    n = t_start_s.shape[0]
    start_us = np.round(t_start_s * 1e6).astype(np.int64)
    end_us = np.round(t_end_s * 1e6).astype(np.int64)
    if np.any(np.diff(start_us) < 0) or np.any(np.diff(end_us) < 0):
        raise ValueError("event windows must be sorted")
    npix = width * height
    active: Dict[int, Tuple[np.ndarray, np.ndarray]] = {}
    next_out = 0  # first window not yet yielded; windows next_out.. are open or not yet started
    for chunk in chunks:
        if len(chunk) == 0:
            continue
        t0, t1 = int(chunk.t[0]), int(chunk.t[-1])
        lin = chunk.y.astype(np.int64) * width + chunk.x.astype(np.int64)
        on = chunk.p.astype(bool)
        k = next_out
        while k < n and start_us[k] <= t1:
            if k not in active:
                active[k] = (np.zeros(npix, np.int32), np.zeros(npix, np.int32))
            if end_us[k] > t0:
                a = int(np.searchsorted(chunk.t, start_us[k], side="left"))
                b = int(np.searchsorted(chunk.t, end_us[k], side="left"))
                if b > a:
                    sel_lin, sel_on = lin[a:b], on[a:b]
                    pos, neg = active[k]
                    pos += np.bincount(sel_lin[sel_on], minlength=npix).astype(np.int32)
                    neg += np.bincount(sel_lin[~sel_on], minlength=npix).astype(np.int32)
            # a window whose end the stream has reached is complete (windows end in order)
            if k == next_out and end_us[k] <= t1:
                pos, neg = active.pop(k)
                yield k, pos.reshape(height, width), neg.reshape(height, width)
                next_out += 1
            k += 1
    while next_out < n:
        pos, neg = active.pop(next_out, (np.zeros(npix, np.int32), np.zeros(npix, np.int32)))
        yield next_out, pos.reshape(height, width), neg.reshape(height, width)
        next_out += 1


def frame_value(
    pos: Float[np.ndarray, "h w"], neg: Float[np.ndarray, "h w"], representation: str
) -> Float[np.ndarray, "h w"]:
    """The unnormalised per-pixel value of a representation: pos - neg ("signed") or pos + neg ("count")."""
    return (pos - neg) if representation == "signed" else (pos + neg)


def robust_scale(abs_values_percentiles: Iterable[float]) -> float:
    """Sequence normaliser from per-window 99th percentiles of |value| (median over windows, at least 1)."""
    vals = [v for v in abs_values_percentiles if v > 0]
    return max(1.0, float(np.median(vals))) if vals else 1.0


def window_percentile(value: Float[np.ndarray, "h w"], q: float = 99.0) -> float:
    """q-th percentile of |value| over pixels with events (0 if none)."""
    nz = np.abs(value[value != 0])
    return float(np.percentile(nz, q)) if nz.size else 0.0


def to_unit_frame(value: Float[np.ndarray, "h w"], scale: float, representation: str) -> Float[np.ndarray, "h w"]:
    """Map the per-pixel value to [0, 1] per the representation (module docstring)."""
    scale = max(float(scale), 1e-6)
    if representation == "signed":
        return 0.5 + 0.5 * np.clip(value / scale, -1.0, 1.0)
    return np.clip(value / scale, 0.0, 1.0)
