"""Rays of training pixels at other times than their frame's: sub-poses across an exposure (blur model) and the two
ends of an event window (event loss).

A pixel's ray in the camera frame does not change when the camera moves, so the same pixel at another pose is the
frame's ray moved by the relative pose: ``d' = R' R^T d``, ``o' = t' + R' R^T (o - t)``. This holds for any camera
model Nerfstudio generated the ray with (distortion included), and needs only the trajectory, not the intrinsics.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Dict, Optional, Tuple

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
    frame_times: Float[Tensor, " n"],
    times: Float[Tensor, "n k"],
    camera_centre: Optional[Float[Tensor, "3"]] = None,
    plane_depth: float = math.inf,
) -> RayBundle:
    """The `n` rays of `bundle` (taken at their frames' `frame_times`) seen from the trajectory's poses at `times`,
    as one flat bundle of n * k rays, ray-major (ray i's k copies are rows i * k ... i * k + k - 1).

    `camera_centre` (the camera's frame, OpenGL axes): the rays of another camera of the rig whose frames were warped
    onto these pixels through the plane at `plane_depth` (along the optical axis; inf: at infinity): each ray then
    starts at that camera's centre and passes through the point of the original ray on the plane (at infinity: it
    keeps the original direction). This is how an event frame aligned to the RGB camera is seen from the event camera.
    """
    assert bundle.camera_indices is not None, "training rays carry their camera indices"
    n, k = times.shape
    device, dtype = bundle.origins.device, bundle.origins.dtype
    # poses on the rays' device, in float64 (trajectory times are seconds of a real clock)
    frame_pose = trajectory.poses_at_tensor(frame_times.to(device, torch.float64), dtype=torch.float64)  # [n, 3, 4]
    new_pose = trajectory.poses_at_tensor(times.to(device, torch.float64), dtype=torch.float64)  # [n, k, 3, 4]
    rot_t = frame_pose[:, :3, :3].transpose(-1, -2)
    origins = bundle.origins.to(torch.float64)
    local_o = (rot_t @ (origins - frame_pose[:, :3, 3])[..., None])[..., 0]  # [n, 3] in the camera frame
    local_d = (rot_t @ bundle.directions.to(torch.float64)[..., None])[..., 0]
    if camera_centre is not None:
        centre = on_device(camera_centre, device).to(torch.float64)
        if math.isfinite(plane_depth):
            forward = (-local_d[:, 2:3]).clamp(min=1e-9)  # OpenGL: the optical axis is -z
            on_plane = local_o + local_d * (plane_depth / forward)
            local_d = torch.nn.functional.normalize(on_plane - centre, dim=-1)
        local_o = local_o + centre
    rot = new_pose[..., :3]  # [n, k, 3, 3]
    new_o = new_pose[..., 3] + (rot @ local_o[:, None, :, None])[..., 0]
    new_d = (rot @ local_d[:, None, :, None])[..., 0]
    return RayBundle(
        origins=new_o.reshape(n * k, 3).to(dtype),
        directions=new_d.reshape(n * k, 3).to(dtype),
        pixel_area=bundle.pixel_area.repeat_interleave(k, dim=0),
        camera_indices=bundle.camera_indices.repeat_interleave(k, dim=0),
    )


def camera_rows(bundle: RayBundle) -> Tensor:
    """Each ray's camera index (into the training cameras) as a flat long tensor on the CPU, where the frames'
    timing (dataparser metadata) lives: a copy of n integers to the host, for diagnostics (the model's timed renders
    gather on the rays' device: `frame_rows`)."""
    assert bundle.camera_indices is not None, "training rays carry their camera indices"
    return bundle.camera_indices.reshape(-1).long().cpu()


_ON_DEVICE: Dict[Tuple[int, str], Tuple[Tensor, Tensor]] = {}
"""(id of a rig table, device) -> (the table, its copy there): the rig's few per-frame tables, copied once."""


def frame_rows(table: Tensor, bundle: RayBundle) -> Tensor:
    """The rows of a per-training-frame table of the rig (frame times, exposures, event windows) for each ray of
    `bundle`, gathered on the rays' device: the table is copied there once and kept, so the rows never go to the host
    and back (the round trip of `camera_rows`)."""
    assert bundle.camera_indices is not None, "training rays carry their camera indices"
    return on_device(table, bundle.camera_indices.device)[bundle.camera_indices.reshape(-1).long()]


def on_device(table: Tensor, device: torch.device) -> Tensor:
    """A fixed tensor of the rig (a per-frame table, a camera's centre) on `device`, copied there once and kept."""
    key = (id(table), str(device))
    cached = _ON_DEVICE.get(key)
    if cached is None or cached[0] is not table:  # the table is held by the entry, so its id is not reused
        cached = _ON_DEVICE[key] = (table, table.to(device))
    return cached[1]
