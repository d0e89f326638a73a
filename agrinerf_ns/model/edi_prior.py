"""EvDeblurNeRF's EDI prior: the frame ray's colour pulled towards the event-deblurred frame (Pan et al.'s event-based
double integral, EvDeblurNeRF's ``utils/edi.py`` and ``use_pts0_prior edi``).

A blurred pixel B is the mean of the sharp pixel over the exposure, and the events say how its log intensity moved
in that time: with E_j = log L(t_j) - log L(t_mid) at ``steps`` times spread over the exposure (the contrast
thresholds times the signed event counts between them), L(t_mid) = B / mean_j exp(E_j). EvDeblurNeRF compares the
unwarped (mid-exposure) ray's colour with that image, at weight 0.01 decayed on a cosine to 1e-5 over 10k steps,
from step 0 (``pts0_target_weight*``, ``pts0_edi_steps 9``).

Here the events come from the event camera's own pixels: each RGB pixel's ray meets the alignment plane (the depth
the dataset warps its event frames at, or infinity), and the event pixel that sees that point gives the counts
(nearest pixel); the division is done in linear radiance (EvDeblurNeRF divides its frames as stored). The factor is
computed per ray when the batch is drawn (two binary searches per interval, ``EventStream.counts``), so no deblurred
image is stored.
"""

from __future__ import annotations

import math
from typing import Tuple, Union

import numpy as np
import torch
from jaxtyping import Bool, Float, Int
from torch import Tensor

from agrinerf_ns.dataparsers.event_stream import EventCamera, EventStream

EDI_STEPS = 9
"""Times across the exposure (``pts0_edi_steps``): 8 intervals, the 5th time is mid-exposure."""
EDI_WEIGHT = (0.01, 1e-5, 10_000)
"""Start weight, end weight and the steps of its cosine decay (``pts0_target_weight``, ``_end``, ``_steps``)."""


def cosine_weight(
    step: int, start: float = EDI_WEIGHT[0], end: float = EDI_WEIGHT[1], steps: int = EDI_WEIGHT[2]
) -> float:
    """EvDeblurNeRF's cosine annealing from `start` at step 0 to `end` at `steps` (then constant)."""
    if step >= steps:
        return end
    factor = (1.0 + math.cos(math.pi * max(step, 0) / steps)) / 2.0
    return start * factor + end * (1.0 - factor)


def event_pixels(
    camera: EventCamera,
    local_directions: Float[Tensor, "n 3"],
    plane_depth: float = math.inf,
) -> Tuple[Int[Tensor, " n"], Bool[Tensor, " n"]]:
    """The event pixel (``y * width + x``) that sees where each RGB ray (its direction in the RGB camera's frame,
    OpenGL axes) meets the plane at `plane_depth` along the optical axis (inf: at infinity), and whether that pixel
    exists (the point is in front of the event camera and inside its image)."""
    d = local_directions.double()
    forward = (-d[:, 2:3]).clamp(min=1e-9)  # OpenGL: the optical axis is -z
    if math.isfinite(plane_depth):
        point = d * (plane_depth / forward) - camera.centre.to(d)
    else:
        point = d
    in_event = point @ camera.rotation.to(d)  # rotation^T applied to each row: into the event camera's OpenCV axes
    ahead = in_event[:, 2] > 1e-9
    straight = torch.zeros_like(in_event[:1])
    straight[:, 2] = 1.0
    safe = torch.where(ahead[:, None], in_event, straight)
    uv = project_points(safe, camera.intrinsics, camera.distortion).round().long()
    inside = ahead & (uv[:, 0] >= 0) & (uv[:, 0] < camera.width) & (uv[:, 1] >= 0) & (uv[:, 1] < camera.height)
    pixel = torch.where(inside, uv[:, 1] * camera.width + uv[:, 0], torch.zeros_like(uv[:, 0]))
    return pixel, inside


def project_points(
    points: Float[Tensor, "n 3"], intrinsics: Tuple[float, float, float, float], distortion: Tuple[float, ...]
) -> Float[Tensor, "n 2"]:
    """OpenCV's `projectPoints` of camera-frame points (no pose) through the pinhole and radial-tangential model
    (k1, k2, p1, p2[, k3]), on the points' device in float64, in OpenCV's order of operations: the same numbers to
    the last digit (`tests/test_host_syncs.py`). Other distortion models (8 or more coefficients, not all zero past
    the fifth) are projected by OpenCV on the host."""
    fx, fy, cx, cy = intrinsics
    k = [float(c) for c in distortion] + [0.0] * max(0, 5 - len(distortion))
    if any(k[5:]):
        import cv2

        K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        uv, _ = cv2.projectPoints(points.double().cpu().numpy(), np.zeros(3), np.zeros(3), K, np.asarray(k))
        return torch.from_numpy(uv[:, 0, :]).to(points.device)  # host: OpenCV's rare distortion models only
    p = points.double()
    z = 1.0 / p[:, 2]
    x, y = p[:, 0] * z, p[:, 1] * z
    r2 = x * x + y * y
    r4 = r2 * r2
    r6 = r4 * r2
    a1, a2, a3 = 2 * x * y, r2 + 2 * x * x, r2 + 2 * y * y
    radial = 1 + k[0] * r2 + k[1] * r4 + k[4] * r6
    xd = x * radial + k[2] * a1 + k[3] * a2
    yd = y * radial + k[2] * a3 + k[3] * a1
    return torch.stack([xd * fx + cx, yd * fy + cy], dim=-1)


def edi_factors(
    stream: EventStream,
    pixel: Int[Tensor, " n"],
    exposure: Float[Tensor, "n 2"],
    c_on: Union[float, Tensor],
    c_off: Union[float, Tensor],
    steps: int = EDI_STEPS,
) -> Float[Tensor, "n 1"]:
    """mean_j exp(E_j) of each pixel over its exposure [start, end] (seconds): the blurred value divided by this is
    the sharp mid-exposure value (1 where no event fired)."""
    fractions = torch.linspace(0.0, 1.0, steps, dtype=torch.float64, device=exposure.device)
    start, end = exposure[:, :1].double(), exposure[:, 1:2].double()
    times = torch.round((start + (end - start) * fractions[None, :]) * 1e6).long()  # [n, steps] us
    n = pixel.shape[0]
    t0, t1 = times[:, :-1].reshape(-1), times[:, 1:].reshape(-1)
    on, off = stream.counts(pixel.repeat_interleave(steps - 1), t0, t1)
    increments = (c_on * on - c_off * off).double().reshape(n, steps - 1)
    level = torch.cat([increments.new_zeros(n, 1), increments.cumsum(dim=-1)], dim=-1)  # log L(t_j) - log L(t_0)
    relative = level - level[:, steps // 2 : steps // 2 + 1]
    return relative.clamp(max=30.0).exp().mean(dim=-1, keepdim=True).float()
