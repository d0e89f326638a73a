"""Rays of training pixels at other times than their frame's: sub-poses across an exposure (blur model) and the two
ends of an event window (event loss).

A pixel's ray in the camera frame does not change when the camera moves, so the same pixel at another pose is the
frame's ray moved by the relative pose: ``d' = R' R^T d``, ``o' = t' + R' R^T (o - t)``. This holds for any camera
model Nerfstudio generated the ray with (distortion included), and needs only the trajectory, not the intrinsics.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch
from jaxtyping import Float
from nerfstudio.cameras.rays import RayBundle
from torch import Tensor

if TYPE_CHECKING:
    from agrinerf_ns.trajectory import CameraTrajectory


def exposure_times(exposure: Float[Tensor, "n 2"], samples: int) -> Float[Tensor, "n samples"]:
    """`samples` times splitting each exposure interval [start, end] into equal parts, at the parts' centres."""
    fractions = (torch.arange(samples, dtype=torch.float64, device=exposure.device) + 0.5) / samples
    start, end = exposure[:, :1].double(), exposure[:, 1:2].double()
    return start + (end - start) * fractions[None, :]


def reposed_rays(
    bundle: RayBundle,
    trajectory: "CameraTrajectory",
    frame_times: Float[Tensor, "n"],
    times: Float[Tensor, "n k"],
) -> RayBundle:
    """The `n` rays of `bundle` (taken at their frames' `frame_times`) seen from the trajectory's poses at `times`,
    as one flat bundle of n * k rays, ray-major (ray i's k copies are rows i * k ... i * k + k - 1)."""
    n, k = times.shape
    frame_pose = trajectory.poses_at_tensor(frame_times.double().cpu(), dtype=torch.float64)  # [n, 3, 4]
    new_pose = trajectory.poses_at_tensor(times.double().cpu(), dtype=torch.float64)  # [n, k, 3, 4]
    relative = new_pose[..., :3] @ frame_pose[:, None, :3, :3].transpose(-1, -2)  # [n, k, 3, 3]
    device, dtype = bundle.origins.device, bundle.origins.dtype
    relative = relative.to(device=device, dtype=dtype)
    offset = (bundle.origins.to(torch.float64).cpu() - frame_pose[:, :3, 3]).to(device=device, dtype=dtype)
    origins = new_pose[..., 3].to(device=device, dtype=dtype) + (relative @ offset[:, None, :, None])[..., 0]
    directions = (relative @ bundle.directions[:, None, :, None])[..., 0]
    return RayBundle(
        origins=origins.reshape(n * k, 3),
        directions=directions.reshape(n * k, 3),
        pixel_area=bundle.pixel_area.repeat_interleave(k, dim=0),
        camera_indices=bundle.camera_indices.repeat_interleave(k, dim=0),
    )


def camera_rows(bundle: RayBundle) -> Tensor:
    """Each ray's camera index (into the training cameras) as a flat long tensor on the CPU."""
    assert bundle.camera_indices is not None, "training rays carry their camera indices"
    return bundle.camera_indices.reshape(-1).long().cpu()

