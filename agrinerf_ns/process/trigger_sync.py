"""Frame times in event-camera time from hardware trigger edges (``agrinerf-process --sync trigger``).

A rig triggers its cameras from one signal that the event camera also records as external-trigger events. Each
frame is matched to the trigger edge nearest its (coarsely shifted) recorded time, within half the median edge
interval; a least-squares line ``t_event = scale * t_frame + offset`` through the matched pairs (refitted once
after re-matching) maps every frame time into event time, absorbing the transport latency and clock drift of the
recorded stamps. The residuals of the matched pairs are the sync quality.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Dict, Literal, Optional

import numpy as np
from jaxtyping import Float

from agrinerf_ns.process.errors import RawInputError
from agrinerf_ns.process.readers import TriggerEvents


@dataclass(frozen=True)
class TriggerSync:
    """The fitted map from frame time to event time (seconds) and its residuals over the matched frames."""

    scale: float
    offset_s: float
    matched: int
    frames: int
    edges: int
    residual_rms_us: float
    residual_max_us: float

    def apply(self, t: Float[np.ndarray, " n"]) -> Float[np.ndarray, " n"]:
        return self.scale * np.asarray(t, np.float64) + self.offset_s

    def as_dict(self) -> Dict:
        return asdict(self)


def _match(frames: np.ndarray, edges: np.ndarray, tol: float) -> np.ndarray:
    idx = np.clip(np.searchsorted(edges, frames), 1, len(edges) - 1)
    left, right = edges[idx - 1], edges[idx]
    best = np.where(np.abs(frames - left) <= np.abs(frames - right), idx - 1, idx)
    return np.where(np.abs(edges[best] - frames) <= tol, best, -1)


def fit_trigger_sync(
    frame_times_s: Float[np.ndarray, " n"],
    triggers: TriggerEvents,
    source: Path,
    edge: Literal["rising", "falling"] = "rising",
    channel: Optional[int] = None,
    coarse_offset_s: float = 0.0,
    min_matched_frac: float = 0.5,
) -> TriggerSync:
    """Fit the frame-to-event-time map; :class:`RawInputError` naming ``source`` when it has no (matching)
    trigger events."""
    keep = triggers.p == (1 if edge == "rising" else 0)
    if channel is not None:
        keep &= triggers.id == channel
    edges = np.sort(triggers.t[keep].astype(np.float64) / 1e6)
    what = f"{edge} trigger edges" + (f" on channel {channel}" if channel is not None else "")
    if len(triggers) == 0:
        raise RawInputError(f"{source}: --sync trigger needs external-trigger events, but the file has none")
    if len(edges) < 2:
        raise RawInputError(f"{source}: --sync trigger found {len(edges)} {what} (of {len(triggers)} trigger events)")
    frames = np.asarray(frame_times_s, np.float64)
    tol = 0.5 * float(np.median(np.diff(edges)))
    a, b = 1.0, float(coarse_offset_s)
    for _ in range(2):
        m = _match(a * frames + b, edges, tol)
        ok = m >= 0
        if ok.sum() < max(2, min_matched_frac * len(frames)):
            raise RawInputError(
                f"{source}: only {int(ok.sum())} of {len(frames)} frames lie within {tol * 1e3:.2f} ms of one of the "
                f"{len(edges)} {what} ({edges[0]:.3f}..{edges[-1]:.3f} s; frames {frames[0] + b:.3f}..{frames[-1] + b:.3f}"
                f" s after the coarse offset {coarse_offset_s} s): give --trigger-offset-s (event minus frame clock)"
            )
        if ok.sum() >= 3 and np.ptp(frames[ok]) > 0:
            a, b = np.polyfit(frames[ok], edges[m[ok]], 1)
        else:
            a, b = 1.0, float(np.mean(edges[m[ok]] - frames[ok]))
    res = (a * frames[ok] + b - edges[m[ok]]) * 1e6
    return TriggerSync(
        scale=float(a),
        offset_s=float(b),
        matched=int(ok.sum()),
        frames=len(frames),
        edges=len(edges),
        residual_rms_us=float(np.sqrt(np.mean(res**2))),
        residual_max_us=float(np.abs(res).max()),
    )
