"""What the event loss and the EDI prior read: event samples (EvDeblurNeRF's pairs, the stream's event pixels, or
the frames' event windows) rendered at both ends of their windows, their targets, the contrast thresholds, and the
`noise` weighting of the event term."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Dict, Tuple

import torch
from jaxtyping import Float, Int
from nerfstudio.cameras.rays import RayBundle
from torch import Tensor

from agrinerf_ns import colour
from agrinerf_ns.model import blur_renders, edi_prior, losses

if TYPE_CHECKING:
    from agrinerf_ns.model.model import AgriNeRFModel


def edi_outputs(model: AgriNeRFModel, bundle: RayBundle) -> Dict[str, Tensor]:
    """The EDI prior's per-ray factor (the blurred value over it is the sharp mid-exposure value) and where the
    event camera sees the pixel (`model/edi_prior.py`)."""
    from agrinerf_ns.model.timed_rays import camera_rows

    assert model.edi_stream is not None and model.event_camera_native is not None
    assert model.trajectory is not None and model.frame_times is not None and model.exposure is not None
    rows = camera_rows(bundle)
    pose = model.trajectory.poses_at_tensor(model.frame_times[rows].double(), dtype=torch.float64)
    local = (pose[:, :3, :3].transpose(-1, -2) @ bundle.directions.double().cpu()[..., None])[..., 0]
    depth = float(model.event_camera.get("plane_depth", math.inf))
    pixel, inside = edi_prior.event_pixels(model.event_camera_native, local, depth)
    c_on, c_off = (float(c) for c in event_thresholds(model))
    factor = edi_prior.edi_factors(model.edi_stream, pixel, model.exposure[rows], c_on, c_off)
    device = bundle.origins.device
    return {"edi_factor": factor.to(device), "edi_valid": inside.float()[:, None].to(device)}


def _render_event_rays(
    model: AgriNeRFModel,
    like: RayBundle,
    origins: Float[Tensor, "m 2 3"],
    directions: Float[Tensor, "m 2 3"],
    frames: Int[Tensor, " m"],
) -> Float[Tensor, "m 2 3"]:
    """RGB of `m` event samples' rays at both their times (the device, dtype and pixel area of `like`; camera index:
    the training frame `frames` [m] of each), with the event loss's density gradient scale."""
    m = int(origins.shape[0])
    device, dtype = like.origins.device, like.origins.dtype
    bundle = RayBundle(
        origins=origins.reshape(2 * m, 3).to(device=device, dtype=dtype),
        directions=directions.reshape(2 * m, 3).to(device=device, dtype=dtype),
        pixel_area=like.pixel_area[:1].expand(2 * m, 1).contiguous(),
        camera_indices=frames.repeat_interleave(2)[:, None].to(device),
    )
    scale = model.density_gradient_scale("event_loss")
    rendered = model.render(model.collider(bundle), routed=False, density_scale=scale, heads=("rgb",))
    return rendered["rgb"].reshape(m, 2, 3)


def pair_event_logs(model: AgriNeRFModel, like: RayBundle) -> Dict[str, Tensor]:
    """`event_rays_per_batch` EvDeblurNeRF event samples (`model/event_pairs.py`) rendered along the event camera's
    rays at both events' times: their log luma (after the learnt response, from its start step) and targets."""
    from agrinerf_ns.dataparsers.event_stream import event_rays
    from agrinerf_ns.model.event_crf import event_log_luma
    from agrinerf_ns.model.event_pairs import pair_targets, polarity_features

    assert model.event_pairs is not None and model.trajectory is not None and model.frame_times is not None
    assert model.event_camera_native is not None
    pixel, t0, t1, polarity = model.event_pairs.sample(model.config.event_rays_per_batch)
    m = int(pixel.shape[0])
    if m == 0:  # a stream without two events at any pixel: no sample, no loss
        return {}
    times = torch.stack([t0, t1], -1).double() * 1e-6
    origins, directions = event_rays(model.trajectory, model.event_camera_native, pixel, times)
    frames = (times[:, :1] - model.frame_times.double()[None, :]).abs().argmin(dim=-1)  # the nearest frame's camera
    rgb = _render_event_rays(model, like, origins, directions, frames)
    device = like.origins.device
    crf = model.event_crf if model.step >= model.config.event_crf_start_step else None
    features = polarity_features(polarity).to(device)
    logs = event_log_luma(colour.srgb_to_linear(rgb), model.config.event_log_eps, crf, features)
    return {"event_log_start": logs[:, 0], "event_log_end": logs[:, 1],
            "event_target": pair_targets(polarity, *event_thresholds(model)).to(device)}  # fmt: skip


def stream_event_logs(model: AgriNeRFModel, like: RayBundle) -> Dict[str, Tensor]:
    """`event_rays_per_batch` random event pixels in random sub-windows of random training frames' windows,
    rendered along the event camera's rays at both ends: their log luminance and their ON / OFF counts."""
    from agrinerf_ns.dataparsers.event_stream import event_rays, sample_windows

    assert model.event_stream is not None and model.event_windows is not None and model.trajectory is not None
    assert model.event_camera_native is not None
    m = model.config.event_rays_per_batch
    frames = torch.randint(0, model.event_windows.shape[0], (m,))  # cpu: the windows and the stream are on the CPU
    t0, t1 = sample_windows(model.event_windows, frames, model.config.event_window_min_fraction, None)
    pixel = torch.randint(0, model.event_stream.width * model.event_stream.height, (m,))  # cpu: as above
    on, off = model.event_stream.counts(pixel, t0, t1)
    origins, directions = event_rays(
        model.trajectory, model.event_camera_native, pixel, torch.stack([t0, t1], -1).double() * 1e-6
    )
    rgb = _render_event_rays(model, like, origins, directions, frames)
    device = like.origins.device
    logs = losses.log_luminance(rgb, model.config.event_log_eps)
    return {"event_log_start": logs[:, 0], "event_log_end": logs[:, 1], "event_on": on.to(device),
            "event_off": off.to(device)}  # fmt: skip


def event_window_logs(model: AgriNeRFModel, bundle: RayBundle) -> Tuple[Float[Tensor, "m 1"], Float[Tensor, "m 1"]]:
    """Log luminance of the first `event_rays_per_batch` pixels at the start and end of their event windows, seen
    from the event camera (its centre and the alignment plane from the dataset's calibration, where recorded)."""
    from agrinerf_ns.model.timed_rays import camera_rows

    assert model.event_windows is not None
    m = min(model.config.event_rays_per_batch, bundle.origins.shape[0])
    head = bundle[:m]
    renders = blur_renders.render_at(
        model, head, model.event_windows[camera_rows(head)].double(), "event_loss", **model.event_camera
    )
    logs = losses.log_luminance(renders, model.config.event_log_eps)  # [m, 2, 1]
    return logs[:, 0], logs[:, 1]


def event_thresholds(model: AgriNeRFModel) -> Tuple[Any, Any]:
    """C_on, C_off of the event loss: learnt (config `event_threshold_learnt`) or the configured one."""
    if model.log_event_threshold is None:
        return model.config.event_threshold, model.config.event_threshold
    c = model.log_event_threshold.exp()
    return c[0], c[1]


def event_noise_weight(model: AgriNeRFModel, raw: Dict[str, Tensor], outputs: Dict[str, Tensor]) -> float:
    """The `noise` weighting's factor (config `event_loss_weighting`), from running means of the RGB and event
    losses (updated in training; 0.99 per step)."""
    rgb, event = float(raw["rgb_loss"].detach()), float(raw["event_loss"].detach())
    if model.training and math.isfinite(rgb) and math.isfinite(event):
        old = model.loss_means or (rgb, event)
        model.loss_means = (0.99 * old[0] + 0.01 * rgb, 0.99 * old[1] + 0.01 * event)
    if model.loss_means is None:
        return 0.0
    mean_rgb, mean_event = model.loss_means
    samples = outputs["event_log_start"].shape[0] / outputs["rgb"].shape[0]
    model.event_weight = samples * min(mean_rgb / max(mean_event, 1e-12), 1.0)  # never above an RGB ray's
    return model.event_weight
