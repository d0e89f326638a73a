"""Motion blur of the synthetic RGB camera: blur length in pixels, sub-frame count, the exposure-averaged radiance.

A blurred frame is the box-filtered average, in linear radiance, of renders at ``K`` poses of the continuous path
across the exposure interval ``[t - e/2, t + e/2]`` (the midpoints of ``K`` equal parts, so for odd ``K`` the middle
one is the sharp frame at ``t``, which is rendered anyway for the truth). ``K`` follows the measured blur length so
the sub-frames are at most ``step_px`` apart on the image.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np
from jaxtyping import Float

from agrinerf_ns.synth.raycast import Hits, PinholeRadtan
from agrinerf_ns.trajectory import exposure_subtimes

SKY_DISTANCE_M = 1e4
"""Sky pixels move by the camera's rotation only: they are treated as points this far away."""


def blur_lengths_px(
    cam: PinholeRadtan, hits: Hits, T_start: Float[np.ndarray, "4 4"], T_end: Float[np.ndarray, "4 4"]
) -> Float[np.ndarray, " n"]:
    """Per pixel, how far (pixels) the surface point seen at the pixel moves on the image between the exposure's
    start and end poses (camera-to-world): the length of the pixel's blur streak (occlusion ignored)."""
    pts = np.where(np.isfinite(hits.t)[:, None], hits.points,
                   T_start[:3, 3] + SKY_DISTANCE_M * hits.dirs_world)  # fmt: skip
    uv = []
    for T in (T_start, T_end):
        R, o = T[:3, :3], T[:3, 3]
        uv.append(cam.project((pts - o) @ R)[0])
    return np.linalg.norm(uv[1] - uv[0], axis=1)


def subframe_count(blur_px: float, step_px: float, max_k: int) -> int:
    """The odd number of sub-frames that keeps consecutive sub-frames at most ``step_px`` apart on the image."""
    k = max(1, math.ceil(blur_px / step_px - 1e-9))
    k += 1 - k % 2
    return int(min(k, max_k if max_k % 2 else max_k - 1))


def exposure_average(
    render: Callable[[float], Float[np.ndarray, "h w 3"]],
    sharp: Float[np.ndarray, "h w 3"],
    t: float,
    exposure_s: float,
    k: int,
) -> Float[np.ndarray, "h w 3"]:
    """Mean of ``render(time)`` over ``k`` sub-times of ``[t - e/2, t + e/2]``; the middle one of an odd ``k`` reuses
    ``sharp`` (the render at ``t``)."""
    if k <= 1 or exposure_s <= 0:
        return sharp
    times = exposure_subtimes(np.array([[t - exposure_s / 2, t + exposure_s / 2]]), k)[0]
    acc = np.zeros_like(sharp, dtype=np.float64)
    for j, tj in enumerate(times):
        acc += sharp if (k % 2 == 1 and j == k // 2) else render(float(tj))
    return acc / k
