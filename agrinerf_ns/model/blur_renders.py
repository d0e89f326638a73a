"""The blur model's renders: a training pixel rendered at other poses across its frame's exposure (the rig's
trajectory) or along the learnt rigid blur kernel's rays, blended in linear radiance; and the random stream of its
own that these and the event renders draw from."""

from __future__ import annotations

import contextlib
from typing import TYPE_CHECKING, Any, Iterator, Optional

import torch
from jaxtyping import Float
from nerfstudio.cameras.rays import RayBundle
from torch import Tensor

from agrinerf_ns import colour
from agrinerf_ns.model.model_config import SIDE_STREAM_SEED

if TYPE_CHECKING:
    from agrinerf_ns.model.model import AgriNeRFModel

FRAME_TIME_ATOL_S = 1e-6
"""A blur sample this close (seconds) to its frame's time is at the frame's pose."""


@contextlib.contextmanager
def side_stream(model: AgriNeRFModel) -> Iterator[None]:
    """The blur and event renders draw their pixels, windows and sample jitter from a random stream of their own
    (seeded by the step), so that turning them on leaves the draws of the RGB batches as they were: an ablation
    row and its baseline stay paired (common random numbers)."""
    devices = [model.device] if model.device.type == "cuda" else []
    with torch.random.fork_rng(devices=devices):
        torch.manual_seed(SIDE_STREAM_SEED + model.step)
        yield


def render_at(
    model: AgriNeRFModel, bundle: RayBundle, times: Tensor, term: str, **camera: Any
) -> Float[Tensor, "n k 3"]:
    """RGB of `bundle`'s pixels rendered from the trajectory's poses at `times` [n, k] for the loss `term` (its
    density gradient scale; `camera`: the `camera_centre` and `plane_depth` of another rig camera whose frames
    were warped onto these pixels)."""
    from agrinerf_ns.model.timed_rays import camera_rows, reposed_rays

    assert model.trajectory is not None and model.frame_times is not None
    frame_times = model.frame_times[camera_rows(bundle)]
    moved = model.collider(reposed_rays(bundle, model.trajectory, frame_times, times, **camera))
    n, k = times.shape
    rendered = model.render(moved, routed=False, density_scale=model.density_gradient_scale(term), heads=("rgb",))
    return rendered["rgb"].reshape(n, k, 3)


def blurred_rgb(
    model: AgriNeRFModel, bundle: RayBundle, sharp_rgb: Optional[Float[Tensor, "n 3"]] = None
) -> Float[Tensor, "n 3"]:
    """The blur model: the mean in linear radiance of `blur_samples` renders across each frame's exposure.

    `sharp_rgb`: the frame ray's own render (for the RGB loss). An odd number of samples puts the middle one at the
    exposure's centre; where that is the frame's time (mid-exposure time stamps), the middle pose is the frame's pose
    and its render is `sharp_rgb`, another draw of the same samplers: it is reused, not rendered again."""
    from agrinerf_ns.model.timed_rays import camera_rows, exposure_times

    assert model.exposure is not None and model.frame_times is not None
    rows = camera_rows(bundle)
    times = exposure_times(model.exposure[rows], model.config.blur_samples)
    middle = times.shape[1] // 2
    at_frame = times.shape[1] % 2 == 1 and torch.allclose(
        times[:, middle], model.frame_times[rows].double(), rtol=0.0, atol=FRAME_TIME_ATOL_S
    )
    if sharp_rgb is not None and at_frame:
        others = render_at(model, bundle, torch.cat([times[:, :middle], times[:, middle + 1 :]], dim=1), "rgb_loss")
        renders = torch.cat([others[:, :middle], sharp_rgb[:, None, :], others[:, middle:]], dim=1)
    else:
        renders = render_at(model, bundle, times, "rgb_loss")
    return colour.linear_to_srgb(colour.srgb_to_linear(renders).mean(dim=1))


def kernel_rgb(model: AgriNeRFModel, bundle: RayBundle, frame_rgb: Float[Tensor, "n 3"]) -> Float[Tensor, "n 3"]:
    """The learnt blur kernel: the frame ray's colour and the renders of its learnt rigid motions, blended in linear
    radiance with the learnt weights (`model/rigid_blur.py`)."""
    from agrinerf_ns.model.rigid_blur import blend, warp_rays
    from agrinerf_ns.model.timed_rays import camera_rows

    assert model.blur_kernel is not None
    rotation, translation, weights = model.blur_kernel(camera_rows(bundle).to(frame_rgb.device))
    origins, directions = warp_rays(bundle.origins, bundle.directions, rotation, translation)
    n, m = origins.shape[:2]
    assert bundle.camera_indices is not None
    moved = RayBundle(
        origins=origins.reshape(n * m, 3),
        directions=directions.reshape(n * m, 3),
        pixel_area=bundle.pixel_area.repeat_interleave(m, dim=0),
        camera_indices=bundle.camera_indices.repeat_interleave(m, dim=0),
    )
    scale = model.density_gradient_scale("rgb_loss")
    renders = model.render(model.collider(moved), routed=False, density_scale=scale, heads=("rgb",))["rgb"].reshape(
        n, m, 3
    )
    linear = colour.srgb_to_linear(torch.cat([frame_rgb[:, None, :], renders], dim=1))
    return colour.linear_to_srgb(blend(linear, weights))
