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
from typing import Tuple

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
    import cv2

    d = local_directions.double().cpu()
    forward = (-d[:, 2:3]).clamp(min=1e-9)  # OpenGL: the optical axis is -z
    if math.isfinite(plane_depth):
        point = d * (plane_depth / forward) - camera.centre.double()
    else:
        point = d
    in_event = point @ camera.rotation.double()  # rotation^T applied to each row: into the event camera's OpenCV axes
    ahead = in_event[:, 2] > 1e-9
    fx, fy, cx, cy = camera.intrinsics
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    safe = torch.where(ahead[:, None], in_event, in_event.new_tensor([0.0, 0.0, 1.0]))
    uv, _ = cv2.projectPoints(safe.numpy(), np.zeros(3), np.zeros(3), K, np.asarray(camera.distortion, np.float64))
    uv = torch.from_numpy(uv[:, 0, :]).round().long()  # cpu: OpenCV's projection, beside the CPU event stream
    inside = ahead & (uv[:, 0] >= 0) & (uv[:, 0] < camera.width) & (uv[:, 1] >= 0) & (uv[:, 1] < camera.height)
    pixel = torch.where(inside, uv[:, 1] * camera.width + uv[:, 0], torch.zeros_like(uv[:, 0]))
    return pixel, inside


def edi_factors(
    stream: EventStream,
    pixel: Int[Tensor, " n"],
    exposure: Float[Tensor, "n 2"],
    c_on: float,
    c_off: float,
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
