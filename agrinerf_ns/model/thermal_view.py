"""The thermal terms rendered from the thermal camera: a thermal frame warped into the RGB camera holds, at an RGB
pixel, what the thermal camera saw along its own ray through the point of the RGB ray on the alignment plane
(`agrinerf-process --plane-depth`, at infinity by default). That ray starts at the thermal camera's centre, a few
centimetres beside the RGB camera: at the trees' depth it meets another surface than the RGB ray does (7 cm of
baseline at 1.5 m is 7 RGB pixels at 200 px width, more than a fruit is wide). Supervising the thermal outputs on
the RGB ray paints the leaves' temperature over the fruit; on the thermal camera's ray each temperature lands on the
surface the thermal camera measured (docs/model.md, Thermal rays)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Dict, Optional, Tuple

import numpy as np
import torch
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
    where that camera sits (`thermal_camera`) and `thermal_rays_per_batch` > 0 (the model's plan)."""
    return model.plan.thermal_camera_rays


def uses_thermal_view(model: AgriNeRFModel) -> bool:
    """Whether training renders the thermal terms from the thermal camera: `thermal_camera_used`, and the rig's
    trajectory gives each frame's orientation (the model's plan: `plan.thermal_view`)."""
    return model.plan.thermal_view


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
    rendered = model.render(model.collider(moved), heads=("thermal", "temperature"))
    return {PREFIX + k: v for k, v in rendered.items() if k.split("/")[0] in OUTPUTS}


def main_render_heads(model: AgriNeRFModel) -> Optional[Tuple[str, ...]]:
    """The heads the RGB rays' render needs in a training step: without the temperature head where the thermal
    camera's rays carry the temperature term (`uses_thermal_view`: no term reads it on the RGB rays); None: all."""
    if model.training and torch.is_grad_enabled() and uses_thermal_view(model):
        return ("rgb", "thermal", "fruit") if getattr(model, "fruit_head", None) is not None else ("rgb", "thermal")
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
    at = torch.zeros(flat.shape[0], dtype=torch.float64, device=flat.origins.device)  # one pose: the held-out camera's
    moved = reposed_rays(flat, CameraTrajectory(np.zeros(1), c2w[None]), at, at[:, None], **model.thermal_camera)
    rendered = model.get_outputs_for_camera_ray_bundle(moved.reshape((height, width)))
    return {**outputs, **{k: v for k, v in rendered.items() if k in OUTPUTS}}
