"""The thermal terms rendered from the thermal camera: a thermal frame warped into the RGB camera holds, at an RGB
pixel, what the thermal camera saw along its own ray through the point of the RGB ray on the alignment plane
(`agrinerf-process --plane-depth`, at infinity by default). That ray starts at the thermal camera's centre, a few
centimetres beside the RGB camera: at the trees' depth it meets another surface than the RGB ray does (7 cm of
baseline at 1.5 m is 7 RGB pixels at 200 px width, more than a fruit is wide). Supervising the thermal outputs on
the RGB ray paints the leaves' temperature over the fruit; on the thermal camera's ray each temperature lands on the
surface the thermal camera measured (docs/model.md, Thermal rays)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Dict, Optional, Tuple

import numpy as np
import torch
from jaxtyping import Float
from nerfstudio.cameras.rays import RayBundle
from torch import Tensor

if TYPE_CHECKING:
    from agrinerf_ns.model.model import AgriNeRFModel

PREFIX = "thermal_view/"
"""Outputs rendered along the thermal camera's rays carry this prefix (`thermal_view/temperature`, and the routed
copies `thermal_view/thermal/thermal_loss`)."""

OUTPUTS = ("thermal", "thermal_camera", "temperature")
"""The outputs the thermal frames' terms read (L_th, the thermal-camera and temperature terms; the cross-spectral
L_reg terms stay on the RGB ray: their targets are RGB luma and event frames)."""


def thermal_camera_used(model: AgriNeRFModel) -> bool:
    """Whether the thermal terms are seen from the thermal camera: the model uses thermal frames, the dataset records
    where that camera sits (`thermal_camera`) and `thermal_rays_per_batch` > 0."""
    return model.use_thermal and model.config.thermal_rays_per_batch > 0 and "camera_centre" in model.thermal_camera


def uses_thermal_view(model: AgriNeRFModel) -> bool:
    """Whether training renders the thermal terms from the thermal camera: `thermal_camera_used`, and the rig's
    trajectory gives each frame's orientation."""
    return thermal_camera_used(model) and model.trajectory is not None and model.frame_times is not None


def thermal_frame_times(model: AgriNeRFModel) -> Optional[Tensor]:
    """When each training frame's thermal frame was taken (dataparser metadata `thermal_times`, float64 [N], from the
    dataset's `thermal_timestamp`): an unsynchronised thermal camera takes it up to half a frame interval away from
    the RGB frame, while the rig moves (5 cm at 1 m/s and 9 Hz). None: at the RGB frames' times."""
    metadata = getattr(model, "kwargs", {}).get("metadata") or {}
    return metadata.get("thermal_times")


def thermal_view_outputs(model: AgriNeRFModel, bundle: RayBundle) -> Dict[str, Tensor]:
    """The thermal outputs of the first `thermal_rays_per_batch` rays of `bundle` rendered from the thermal camera's
    centre, where the rig was when it took its frame (`thermal_frame_times`), through their points on the alignment
    plane, with their routed copies, keys prefixed with `PREFIX`."""
    from agrinerf_ns.model.timed_rays import camera_rows, reposed_rays

    assert model.trajectory is not None and model.frame_times is not None
    m = min(model.config.thermal_rays_per_batch, bundle.origins.shape[0])
    head = bundle[:m]
    rows = camera_rows(head)
    frame_times = model.frame_times[rows].double()
    thermal_times = thermal_frame_times(model)
    at = frame_times if thermal_times is None else thermal_times[rows].double()
    moved = reposed_rays(head, model.trajectory, frame_times, at[:, None], **model.thermal_camera)
    side, sigma = psf_side(model), psf_sigma_rad(model)
    if side > 1 and sigma > 0:
        moved = psf_rays(moved, model.trajectory.poses_at_tensor(at.cpu(), dtype=torch.float64), side, sigma)
    rendered = model.render(model.collider(moved), heads=("thermal", "temperature"))
    k = moved.origins.shape[0] // m
    return {PREFIX + n: v.reshape(m, k, -1).mean(dim=1) for n, v in rendered.items() if n.split("/")[0] in OUTPUTS}


def psf_side(model: AgriNeRFModel) -> int:
    """Sub-rays per side of the point-spread grid, from `thermal_psf_samples` (a square number)."""
    samples = max(int(model.config.thermal_psf_samples), 1)
    side = int(round(math.sqrt(samples)))
    if side * side != samples:
        raise ValueError(f"thermal_psf_samples must be a square number (1, 4, 9...), got {samples}")
    return side


def psf_sigma_rad(model: AgriNeRFModel) -> float:
    """The thermal frames' blur about a ray (radians, one Gaussian's sigma): the optics' (`thermal_psf_sigma_px`, or
    the calibration's `thermal_psf_sigma_px` metadata), the pixel's box (variance 1/12 px^2) and the tent of the
    warp's bilinear interpolation (1/6 px^2), in thermal pixels of the dataset's `thermal_pixel_angle`. 0: unknown
    (no thermal intrinsics in the dataset)."""
    metadata = getattr(model, "kwargs", {}).get("metadata") or {}
    angle = metadata.get("thermal_pixel_angle")
    if angle is None:
        return 0.0
    optics = model.config.thermal_psf_sigma_px
    optics = float(metadata.get("thermal_psf_sigma_px", 0.0) if optics is None else optics)
    return math.sqrt(optics**2 + 1.0 / 12.0 + 1.0 / 6.0) * float(angle)


def psf_rays(bundle: RayBundle, poses: Float[Tensor, "n 3 4"], side: int, sigma: float) -> RayBundle:
    """`side` x `side` sub-rays of each ray, ray-major, turned across the ray towards the camera's x and y axes
    (`poses`: camera to world, OpenGL; `perpendicular_axes`) by angles drawn from a Gaussian of `sigma` radians, stratified: one draw in each of `side` equal-
    probability bands per axis (the band's quantile jittered), so the sub-rays' mean follows the blurred image."""
    n, s = bundle.origins.shape[0], side * side
    bands = torch.arange(side, dtype=torch.float64)
    grid = torch.stack(torch.meshgrid(bands, bands, indexing="ij"), -1).reshape(1, s, 2)
    quantiles = ((grid + torch.rand(n, s, 2, dtype=torch.float64)) / side).clamp(1e-6, 1 - 1e-6)
    offsets = torch.special.ndtri(quantiles) * sigma  # [n, s, 2] radians
    device, dtype = bundle.directions.device, bundle.directions.dtype
    ray = torch.nn.functional.normalize(bundle.directions.double().cpu(), dim=-1)
    axes = perpendicular_axes(ray, poses[:, :3, 0].double().cpu())  # [n, 3, 2]
    turn = (axes[:, None] @ offsets[..., None])[..., 0]  # [n, s, 3]
    d = torch.nn.functional.normalize(ray[:, None] + turn, dim=-1)
    return RayBundle(
        origins=bundle.origins.repeat_interleave(s, dim=0),
        directions=d.reshape(n * s, 3).to(device=device, dtype=dtype),
        pixel_area=bundle.pixel_area.repeat_interleave(s, dim=0),
        camera_indices=None if bundle.camera_indices is None else bundle.camera_indices.repeat_interleave(s, dim=0),
    )


def main_render_heads(model: AgriNeRFModel) -> Optional[Tuple[str, ...]]:
    """The heads the RGB rays' render needs in a training step: without the temperature head where the thermal
    camera's rays carry the temperature term (`uses_thermal_view`: no term reads it on the RGB rays); None: all."""
    if model.training and torch.is_grad_enabled() and uses_thermal_view(model):
        return ("rgb", "thermal")
    return None


def eval_outputs(model: AgriNeRFModel, outputs: Dict[str, Tensor]) -> Dict[str, Tensor]:
    """For the held-out thermal metrics: `outputs` of the camera last rendered (`model.eval_camera`) with its thermal
    outputs rendered again from the thermal camera, what the warped frames hold, where training used that camera
    (`thermal_rays_per_batch` > 0 and its place known); otherwise `outputs` as they are."""
    from agrinerf_ns.model.timed_rays import reposed_rays
    from agrinerf_ns.trajectory import CameraTrajectory

    camera = model.eval_camera
    if camera is None or not thermal_camera_used(model) or "thermal" not in outputs:
        return outputs
    bundle = camera.generate_rays(camera_indices=0, keep_shape=True)
    if tuple(bundle.shape) != tuple(outputs["thermal"].shape[:2]):  # not the camera of these outputs
        return outputs
    height, width = bundle.shape
    flat = bundle.flatten()
    c2w = camera.camera_to_worlds[0].detach().double().cpu().numpy()
    at = torch.zeros(flat.shape[0], dtype=torch.float64)  # one pose: the held-out camera's
    moved = reposed_rays(flat, CameraTrajectory(np.zeros(1), c2w[None]), at, at[:, None], **model.thermal_camera)
    rendered = model.get_outputs_for_camera_ray_bundle(moved.reshape((height, width)))
    return {**outputs, **{k: v for k, v in rendered.items() if k in OUTPUTS}}


def perpendicular_axes(ray: Float[Tensor, "n 3"], x_axis: Float[Tensor, "n 3"]) -> Float[Tensor, "n 3 2"]:
    """Two unit axes across each unit `ray`: the camera's `x_axis` without its part along the ray, and its cross
    product with the ray (the camera's y axis, OpenGL, where the ray is the optical axis)."""
    e1 = torch.nn.functional.normalize(x_axis - (x_axis * ray).sum(-1, keepdim=True) * ray, dim=-1)
    return torch.stack([e1, torch.cross(e1, ray, dim=-1)], dim=-1)
