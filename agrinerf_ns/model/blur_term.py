"""The blur model's term: a training pixel rendered at other poses across its frame's exposure (the rig's
trajectory) or along the learnt rigid blur kernel's rays, blended in linear radiance, for the RGB loss."""

from __future__ import annotations

from typing import Any, Dict, List, Optional

import torch
from jaxtyping import Float
from nerfstudio.cameras.rays import RayBundle
from torch import Tensor
from torch.nn import Parameter

from agrinerf_ns import colour
from agrinerf_ns.model.model_part import ModelPart
from agrinerf_ns.model.rig import RenderRays, Rig
from agrinerf_ns.model.rigid_blur import RigidBlurKernel, blend, warp_rays
from agrinerf_ns.model.timed_rays import exposure_times, frame_rows, reposed_rays

FRAME_TIME_ATOL_S = 1e-6
"""A blur sample this close (seconds) to its frame's time is at the frame's pose."""


def render_at(
    render: RenderRays, rig: Rig, bundle: RayBundle, times: Tensor, term: str, **camera: Any
) -> Float[Tensor, "n k 3"]:
    """RGB of `bundle`'s pixels rendered from the trajectory's poses at `times` [n, k] for the loss `term` (its
    density gradient scale; `camera`: the `camera_centre` and `plane_depth` of another rig camera whose frames
    were warped onto these pixels)."""
    assert rig.trajectory is not None and rig.frame_times is not None
    frame_times = frame_rows(rig.frame_times, bundle)
    moved = reposed_rays(bundle, rig.trajectory, frame_times, times, **camera)
    n, k = times.shape
    return render(moved, ("rgb",), term)["rgb"].reshape(n, k, 3)


class BlurTerm(ModelPart):
    """The blurred render of a training pixel that the RGB loss compares with the blurred frame, from
    `start_step`: the trajectory's sub-poses across the exposure, or the learnt kernel's rays (`kernel`, a module
    the model owns and optimises)."""

    def __init__(self, rig: Rig, samples: int, start_step: int, kernel: Optional[RigidBlurKernel] = None) -> None:
        self.rig, self.samples, self.start_step, self.kernel = rig, samples, start_step, kernel
        # per frame: is the middle sample at the frame's time (mid-exposure stamps)? Decided once for the dataset, so
        # that a batch needs no read-back; only a dataset with both kinds of frame checks each batch's
        self.at_frame: Optional[Tensor] = None
        if rig.exposure is not None and rig.frame_times is not None and samples % 2 == 1:
            middle = exposure_times(rig.exposure, samples)[:, samples // 2]
            self.at_frame = (middle - rig.frame_times.double()).abs() <= FRAME_TIME_ATOL_S  # allclose, rtol 0
        self.every_at_frame = self.at_frame is not None and bool(self.at_frame.all())
        self.some_at_frame = self.at_frame is not None and bool(self.at_frame.any())

    def outputs(self, render: RenderRays, bundle: RayBundle, frame: Dict[str, Tensor], step: int) -> Dict[str, Tensor]:
        """`rgb_blurred` of the training rays `bundle` (`frame`: their outputs, whose render for the RGB loss is
        the frame pose's), from `start_step`."""
        if step < self.start_step:
            return {}
        sharp_rgb = frame.get("rgb/rgb_loss", frame["rgb"])
        if self.kernel is not None:
            return {"rgb_blurred": self.kernel_rgb(render, bundle, sharp_rgb)}
        return {"rgb_blurred": self.blurred_rgb(render, bundle, sharp_rgb)}

    def param_groups(self) -> Dict[str, List[Parameter]]:
        """The learnt kernel's own group "blur_kernel"."""
        return {} if self.kernel is None else {"blur_kernel": list(self.kernel.parameters())}

    def blurred_rgb(
        self, render: RenderRays, bundle: RayBundle, sharp_rgb: Optional[Float[Tensor, "n 3"]] = None
    ) -> Float[Tensor, "n 3"]:
        """The mean in linear radiance of `samples` renders across each frame's exposure.

        `sharp_rgb`: the frame ray's own render (for the RGB loss). An odd number of samples puts the middle one at
        the exposure's centre; where that is the frame's time (mid-exposure time stamps), the middle pose is the
        frame's pose and its render is `sharp_rgb`, another draw of the same samplers: it is reused, not rendered
        again."""
        rig = self.rig
        assert rig.exposure is not None and rig.frame_times is not None
        times = exposure_times(frame_rows(rig.exposure, bundle), self.samples)
        middle = times.shape[1] // 2
        at_frame = self.every_at_frame
        if self.some_at_frame and not at_frame:
            assert self.at_frame is not None
            at_frame = bool(frame_rows(self.at_frame, bundle).all())  # frames of both kinds: this batch's
        if sharp_rgb is not None and at_frame:
            others = torch.cat([times[:, :middle], times[:, middle + 1 :]], dim=1)
            others_rgb = render_at(render, rig, bundle, others, "rgb_loss")
            renders = torch.cat([others_rgb[:, :middle], sharp_rgb[:, None, :], others_rgb[:, middle:]], dim=1)
        else:
            renders = render_at(render, rig, bundle, times, "rgb_loss")
        return colour.linear_to_srgb(colour.srgb_to_linear(renders).mean(dim=1))

    def kernel_rgb(
        self, render: RenderRays, bundle: RayBundle, frame_rgb: Float[Tensor, "n 3"]
    ) -> Float[Tensor, "n 3"]:
        """The frame ray's colour and the renders of its learnt rigid motions, blended in linear radiance with the
        learnt weights (`model/rigid_blur.py`)."""
        assert self.kernel is not None and bundle.camera_indices is not None
        # the rows on the rays' device: the kernel's weights live there (no round trip through the host)
        rotation, translation, weights = self.kernel(bundle.camera_indices.reshape(-1).long())
        origins, directions = warp_rays(bundle.origins, bundle.directions, rotation, translation)
        n, m = origins.shape[:2]
        moved = RayBundle(
            origins=origins.reshape(n * m, 3),
            directions=directions.reshape(n * m, 3),
            pixel_area=bundle.pixel_area.repeat_interleave(m, dim=0),
            camera_indices=bundle.camera_indices.repeat_interleave(m, dim=0),
        )
        renders = render(moved, ("rgb",), "rgb_loss")["rgb"].reshape(n, m, 3)
        linear = colour.srgb_to_linear(torch.cat([frame_rgb[:, None, :], renders], dim=1))
        return colour.linear_to_srgb(blend(linear, weights))
