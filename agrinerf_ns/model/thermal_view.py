"""The thermal terms rendered from the thermal camera: a thermal frame warped into the RGB camera holds, at an RGB
pixel, what the thermal camera saw along its own ray through the point of the RGB ray on the alignment plane
(`agrinerf-process --plane-depth`, at infinity by default). That ray starts at the thermal camera's centre, a few
centimetres beside the RGB camera: at the trees' depth it meets another surface than the RGB ray does (7 cm of
baseline at 1.5 m is 7 RGB pixels at 200 px width, more than a fruit is wide). Supervising the thermal outputs on
the RGB ray paints the leaves' temperature over the fruit; on the thermal camera's ray each temperature lands on the
surface the thermal camera measured (docs/model.md, Thermal rays)."""

from __future__ import annotations

from typing import Callable, Dict

import numpy as np
import torch
from nerfstudio.cameras.cameras import Cameras
from nerfstudio.cameras.rays import RayBundle
from torch import Tensor

from agrinerf_ns.model.model_part import ModelPart
from agrinerf_ns.model.rig import RenderRays, Rig
from agrinerf_ns.model.timed_rays import frame_rows, reposed_rays
from agrinerf_ns.trajectory import CameraTrajectory

PREFIX = "thermal_view/"
"""Outputs rendered along the thermal camera's rays carry this prefix (`thermal_view/temperature`, and the routed
copies `thermal_view/thermal/thermal_loss`)."""

OUTPUTS = ("thermal", "thermal_camera", "temperature")
"""The outputs the thermal frames' terms read (L_th, the thermal-camera and temperature terms; the cross-spectral
L_reg terms stay on the RGB ray: their targets are RGB luma and event frames)."""


class ThermalView(ModelPart):
    """The thermal camera's view of a model whose plan has `thermal_camera_rays` (thermal frames, the camera's place
    known, `rays_per_batch` > 0): in training along its rays (`outputs`, where the plan's `thermal_view` says the
    trajectory gives each frame's pose), and in held-out metrics (`eval_outputs`).

    `train_along`: the plan's `thermal_view` (training renders along its rays); `fruit`: the plan's
    `fruit_thermal_view` (the thermal camera's fruit masks are supervised on them)."""

    def __init__(self, rig: Rig, rays_per_batch: int, train_along: bool = True, fruit: bool = False) -> None:
        self.rig, self.rays_per_batch, self.train_along, self.fruit = rig, rays_per_batch, train_along, fruit

    def outputs(self, render: RenderRays, bundle: RayBundle, frame: Dict[str, Tensor], step: int) -> Dict[str, Tensor]:
        """In training along its rays (`train_along`): `along`'s outputs."""
        return self.along(render, bundle, self.fruit) if self.train_along else {}

    def along(self, render: RenderRays, bundle: RayBundle, fruit: bool = False) -> Dict[str, Tensor]:
        """The thermal outputs of the first `rays_per_batch` rays of `bundle` rendered from the thermal camera's
        centre, where the rig was when it took its frame (the rig's `thermal_times`; an unsynchronised thermal camera
        takes it up to half a frame interval from the RGB frame, 5 cm at 1 m/s and 9 Hz), through their points on the
        alignment plane, with their routed copies, keys prefixed with `PREFIX`; `fruit`: the fruit head's too (the
        thermal camera's fruit masks are supervised on them)."""
        rig = self.rig
        assert rig.trajectory is not None and rig.frame_times is not None
        m = min(self.rays_per_batch, bundle.origins.shape[0])
        head = bundle[:m]
        frame_times = frame_rows(rig.frame_times, head).double()
        at = frame_times if rig.thermal_times is None else frame_rows(rig.thermal_times, head).double()
        moved = reposed_rays(head, rig.trajectory, frame_times, at[:, None], **rig.thermal_camera)
        heads = ("thermal", "temperature", "fruit") if fruit else ("thermal", "temperature")
        rendered = render(moved, heads)
        return {PREFIX + k: v for k, v in rendered.items() if k.split("/")[0] in heads + OUTPUTS}

    def eval_outputs(
        self,
        render_image: Callable[[RayBundle], Dict[str, Tensor]],
        camera: Cameras,
        outputs: Dict[str, Tensor],
        fruit: bool = False,
    ) -> Dict[str, Tensor]:
        """`outputs` of the held-out `camera` with their thermal outputs (and with `fruit` the fruit head's) rendered
        again from the thermal camera (what the warped frames hold) by `render_image` (an image's bundle ->
        outputs)."""
        if "thermal" not in outputs:
            return outputs
        bundle = camera.generate_rays(camera_indices=0, keep_shape=True)
        if tuple(bundle.shape) != tuple(outputs["thermal"].shape[:2]):  # not the camera of these outputs
            return outputs
        height, width = bundle.shape
        flat = bundle.flatten()
        c2w = camera.camera_to_worlds[0].detach().double().cpu().numpy()
        at = torch.zeros(flat.shape[0], dtype=torch.float64, device=flat.origins.device)  # one pose: the camera's
        moved = reposed_rays(flat, CameraTrajectory(np.zeros(1), c2w[None]), at, at[:, None], **self.rig.thermal_camera)
        rendered = render_image(moved.reshape((height, width)))
        names = OUTPUTS + ("fruit",) if fruit else OUTPUTS
        return {**outputs, **{k: v for k, v in rendered.items() if k in names}}
