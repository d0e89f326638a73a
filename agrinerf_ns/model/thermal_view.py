"""The thermal terms rendered from the thermal camera: a thermal frame warped into the RGB camera holds, at an RGB
pixel, what the thermal camera saw along its own ray through the point of the RGB ray on the alignment plane
(`agrinerf-process --plane-depth`, at infinity by default). That ray starts at the thermal camera's centre, a few
centimetres beside the RGB camera: at the trees' depth it meets another surface than the RGB ray does (7 cm of
baseline at 1.5 m is 7 RGB pixels at 200 px width, more than a fruit is wide). Supervising the thermal outputs on
the RGB ray paints the leaves' temperature over the fruit; on the thermal camera's ray each temperature lands on the
surface the thermal camera measured (docs/model.md, Thermal rays)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Dict

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

THERMAL_TERMS = ("thermal_loss", "thermal_camera_loss", "temperature_loss")
"""The data terms whose targets are the thermal camera's frames (the cross-spectral L_reg terms stay on the RGB
ray: their targets are RGB luma and event frames)."""


def uses_thermal_view(model: AgriNeRFModel) -> bool:
    """Whether training renders the thermal terms from the thermal camera: the dataset records where that camera sits
    (`thermal_camera`), the rig's trajectory gives each frame's orientation, and `thermal_rays_per_batch` > 0."""
    return (
        model.use_thermal
        and model.config.thermal_rays_per_batch > 0
        and "camera_centre" in model.thermal_camera
        and model.trajectory is not None
        and model.frame_times is not None
    )


def thermal_view_outputs(model: AgriNeRFModel, bundle: RayBundle) -> Dict[str, Tensor]:
    """The thermal outputs of the first `thermal_rays_per_batch` rays of `bundle` rendered from the thermal camera's
    centre through their points on the alignment plane (averaged over `thermal_footprint_samples` sub-rays across
    one thermal pixel), with their routed copies, keys prefixed with `PREFIX`."""
    from agrinerf_ns.model.timed_rays import camera_rows, reposed_rays

    assert model.trajectory is not None and model.frame_times is not None
    m = min(model.config.thermal_rays_per_batch, bundle.origins.shape[0])
    head = bundle[:m]
    frame_times = model.frame_times[camera_rows(head)].double()
    moved = reposed_rays(head, model.trajectory, frame_times, frame_times[:, None], **model.thermal_camera)
    k = footprint_side(model)
    if k > 1:
        moved = footprint_rays(moved, model.trajectory.poses_at_tensor(frame_times, dtype=torch.float64), k,
                               float(model.thermal_pixel_angle))  # fmt: skip
    rendered = model.render(model.collider(moved), heads=("thermal",))
    keep = ("thermal", "thermal_camera", "temperature")
    return {
        PREFIX + name: value.reshape(m, k * k, -1).mean(dim=1)
        for name, value in rendered.items()
        if name.split("/")[0] in keep and torch.is_tensor(value)
    }


def footprint_side(model: AgriNeRFModel) -> int:
    """Sub-rays per side of a thermal pixel's footprint (1: one ray), from `thermal_footprint_samples`."""
    side = int(round(math.sqrt(max(model.config.thermal_footprint_samples, 1))))
    if side * side != max(model.config.thermal_footprint_samples, 1):
        raise ValueError(
            f"thermal_footprint_samples must be a square number, got {model.config.thermal_footprint_samples}"
        )
    return side if model.thermal_pixel_angle is not None else 1


def footprint_rays(bundle: RayBundle, poses: Float[Tensor, "n 3 4"], side: int, pixel_angle: float) -> RayBundle:
    """`side` x `side` sub-rays of each ray, ray-major, on a jittered grid over one pixel of `pixel_angle` radians,
    turned about the camera's x and y axes (`poses`: camera to world, OpenGL) from the ray's origin."""
    n = bundle.origins.shape[0]
    cells = (torch.arange(side, dtype=torch.float64) + 0.5) / side - 0.5
    grid = torch.stack(torch.meshgrid(cells, cells, indexing="ij"), -1).reshape(1, side * side, 2)
    offsets = (grid + (torch.rand(n, side * side, 2, dtype=torch.float64) - 0.5) / side) * pixel_angle
    axes = poses[:, :3, :2].to(bundle.directions.device)  # [n, 3, 2]: the camera's x and y axes in the world
    turn = (axes[:, None] @ offsets.to(axes.device)[..., None])[..., 0]  # [n, s, 3]
    directions = torch.nn.functional.normalize(bundle.directions.double()[:, None] + turn, dim=-1)
    s = side * side
    return RayBundle(
        origins=bundle.origins.repeat_interleave(s, dim=0),
        directions=directions.reshape(n * s, 3).to(bundle.directions.dtype),
        pixel_area=bundle.pixel_area.repeat_interleave(s, dim=0),
        camera_indices=None if bundle.camera_indices is None else bundle.camera_indices.repeat_interleave(s, dim=0),
    )


def eval_outputs(model: AgriNeRFModel, outputs: Dict[str, Tensor]) -> Dict[str, Tensor]:
    """For the held-out thermal metrics: `outputs` of the camera last rendered (`model.eval_camera`) with its thermal
    outputs rendered again from the thermal camera, what the warped frames hold, where training used that camera
    (`thermal_rays_per_batch` > 0 and its place known); otherwise `outputs` as they are."""
    from agrinerf_ns.model.timed_rays import reposed_rays
    from agrinerf_ns.trajectory import CameraTrajectory

    camera = model.eval_camera
    if camera is None or not model.use_thermal or model.config.thermal_rays_per_batch <= 0:
        return outputs
    if "camera_centre" not in model.thermal_camera or "thermal" not in outputs:
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
    keep = ("thermal", "thermal_camera", "temperature")
    return {**outputs, **{k: v for k, v in rendered.items() if k in keep}}
