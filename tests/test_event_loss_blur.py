"""The event loss and the blur model (issue 15): hand-made cases, rays at other times, K = 1, gradients, extremes."""

from __future__ import annotations

import math
from typing import Dict

import pytest
import torch
from helpers.small_model import SMALL_MODEL
from helpers.trajectory_rays import trajectory_rays, yawing_trajectory
from nerfstudio.cameras.rays import RayBundle
from nerfstudio.data.scene_box import SceneBox

from agrinerf_ns import colour
from agrinerf_ns.model import losses
from agrinerf_ns.model.gradients import parameter_groups, term_gradient_norms
from agrinerf_ns.model.model import AgriNeRFModel, AgriNeRFModelConfig
from agrinerf_ns.model.timed_rays import exposure_times, reposed_rays
from agrinerf_ns.trajectory import CameraTrajectory

C = 0.2

SMALL = {
    **SMALL_MODEL,
    "density_shift": 0.0,
    "event_threshold": C,
    "event_rays_per_batch": 16,
    "event_supervision": "frames",
}


# ----------------------------------------------------------------------------- the loss on hand-made cases
def _loss(log_start: float, log_end: float, on: float, off: float, mask: float = 1.0, bound: bool = False) -> float:
    t = lambda v: torch.tensor([[float(v)]])  # noqa: E731
    return float(losses.event_loss(t(log_start), t(log_end), t(on), t(off), C, C, t(mask), lower_bound=bound))


def test_a_log_step_of_two_thresholds_with_two_on_events_costs_nothing() -> None:
    assert _loss(math.log(0.1), math.log(0.1) + 2 * C, on=2, off=0) == pytest.approx(0.0, abs=1e-12)
    assert _loss(0.3, 0.3 - 3 * C, on=0, off=3) == pytest.approx(0.0, abs=1e-12)


def test_the_opposite_polarity_costs() -> None:
    loss = _loss(0.0, 2 * C, on=0, off=2)
    assert loss == pytest.approx((4 * C) ** 2, rel=1e-6)


def test_a_static_pixel_without_events_costs_nothing_and_one_that_changed_without_events_does() -> None:
    assert _loss(-1.0, -1.0, on=0, off=0) == 0.0
    assert _loss(-1.0, -0.5, on=0, off=0) == pytest.approx(0.25)
    assert _loss(-1.0, -0.5, on=0, off=0, mask=0.0) == 0.0  # outside the event camera's view


def test_a_count_as_lower_bound_forgives_only_a_larger_change_in_its_direction() -> None:
    # 3 ON events, the pixel rose by 5 thresholds: the sensor dropped events; squared loss pulls it down, bound not
    assert _loss(0.0, 5 * C, on=3, off=0) == pytest.approx((2 * C) ** 2, rel=1e-6)
    assert _loss(0.0, 5 * C, on=3, off=0, bound=True) == 0.0
    assert _loss(0.0, -5 * C, on=0, off=3, bound=True) == 0.0
    # a smaller change, the other sign, or a change without events still cost what the squared loss charges
    assert _loss(0.0, C, on=3, off=0, bound=True) == pytest.approx((2 * C) ** 2, rel=1e-6)
    assert _loss(0.0, -C, on=3, off=0, bound=True) == pytest.approx((4 * C) ** 2, rel=1e-6)
    assert _loss(-1.0, -0.5, on=0, off=0, bound=True) == pytest.approx(0.25)


def test_the_bounded_event_loss_still_sends_a_gradient_where_the_change_falls_short() -> None:
    start = torch.zeros(2, 1)
    end = torch.tensor([[0.1], [1.0]], requires_grad=True)
    on = torch.tensor([[2.0], [2.0]])
    losses.event_loss(start, end, on, torch.zeros(2, 1), C, C, lower_bound=True).backward()
    assert end.grad is not None
    assert float(end.grad[0, 0]) < 0.0  # short of 2C: pushed up
    assert float(end.grad[1, 0]) == 0.0  # beyond 2C in the ON direction: left alone


def test_log_luminance_is_finite_at_black_and_exposure_invariant_in_differences() -> None:
    black = losses.log_luminance(torch.zeros(2, 3), 1e-4)
    assert torch.isfinite(black).all()
    lin = torch.tensor([[0.02, 0.03, 0.01], [0.2, 0.1, 0.05]])
    a, b = (losses.log_luminance(colour.linear_to_srgb(lin * g), 1e-9) for g in (1.0, 4.0))
    assert torch.allclose((b - a), torch.full_like(a, math.log(4.0)), atol=1e-3)
    assert torch.allclose(colour.srgb_to_linear(colour.linear_to_srgb(lin)), lin, atol=1e-6)


# ------------------------------------------------------------------------------------ rays at other times
def _trajectory() -> CameraTrajectory:
    return yawing_trajectory()


def _rays(n: int = 48, cameras: int = 4) -> RayBundle:
    return trajectory_rays(_trajectory(), n, cameras)


def test_rays_at_the_frames_own_time_are_the_frames_rays() -> None:
    bundle, traj = _rays(), _trajectory()
    frame_times = torch.from_numpy(traj.times)[bundle.camera_indices[:, 0]]
    same = reposed_rays(bundle, traj, frame_times, frame_times[:, None])
    assert torch.allclose(same.origins, bundle.origins, atol=1e-6)
    assert torch.allclose(same.directions, bundle.directions, atol=1e-6)


def test_rays_at_another_time_come_from_the_trajectorys_pose_there() -> None:
    bundle, traj = _rays(), _trajectory()
    frame_times = torch.from_numpy(traj.times)[bundle.camera_indices[:, 0]]
    later = frame_times[:, None] + torch.tensor([[0.05]], dtype=torch.float64)
    moved = reposed_rays(bundle, traj, frame_times, later)
    pose = torch.from_numpy(traj.poses_at(later[:, 0].numpy())).float()
    frame = torch.from_numpy(traj.poses_at(frame_times.numpy())).float()
    local = (frame[:, :3, :3].transpose(-1, -2) @ bundle.directions[..., None])[..., 0]  # the pixel's camera ray
    assert torch.allclose(moved.origins, pose[:, :3, 3], atol=1e-6)
    assert torch.allclose(moved.directions, (pose[:, :3, :3] @ local[..., None])[..., 0], atol=1e-6)


def test_exposure_times_split_the_interval_and_a_zero_exposure_gives_its_instant() -> None:
    times = exposure_times(torch.tensor([[1.0, 1.04], [2.0, 2.0]], dtype=torch.float64), 4)
    assert torch.allclose(times[0], torch.tensor([1.005, 1.015, 1.025, 1.035], dtype=torch.float64))
    assert torch.equal(times[1], torch.full((4,), 2.0, dtype=torch.float64))


# ------------------------------------------------------------------------------------------------ the model
def _metadata(exposure_s: float = 0.04, flood: bool = False) -> Dict[str, object]:
    traj = _trajectory()
    times = torch.from_numpy(traj.times)
    return {
        "modalities": ("rgb", "events"),
        "times": times,
        "exposure": torch.stack([times - exposure_s / 2, times + exposure_s / 2], -1),
        "trajectory": traj,
        "event_windows": torch.stack([times - 0.1, times], -1),
    }


def _model(metadata: Dict[str, object], **kw) -> AgriNeRFModel:
    torch.manual_seed(0)
    cfg = AgriNeRFModelConfig(modalities=("rgb", "events"), **{**SMALL, **kw})
    box = SceneBox(aabb=torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]))
    model = cfg.setup(scene_box=box, num_train_data=4, metadata=metadata)
    model.train()
    return model


def _batch(n: int = 48, on: float = 1.0, off: float = 0.0) -> Dict[str, torch.Tensor]:
    gen = torch.Generator().manual_seed(2)
    return {
        "image": torch.rand(n, 3, generator=gen),
        "event": torch.full((n, 1), 0.5),
        "event_mask": torch.ones(n, 1),
        "event_on": torch.full((n, 1), on),
        "event_off": torch.full((n, 1), off),
    }


def _losses(model: AgriNeRFModel, batch: Dict[str, torch.Tensor], seed: int = 3) -> Dict[str, torch.Tensor]:
    torch.manual_seed(seed)
    outputs = model(_rays())
    return model.get_loss_dict(outputs, batch, model.get_metrics_dict(outputs, batch))


def test_one_blur_sample_is_the_sharp_path_bit_for_bit() -> None:
    sharp = _losses(_model({"modalities": ("rgb", "events")}), _batch())  # no timing metadata at all
    k1 = _model(_metadata(), blur_samples=1, event_supervision="off")
    assert not k1.plan.use_blur
    one = _losses(k1, _batch())
    assert set(one) == set(sharp)
    for key in sharp:
        assert torch.equal(one[key], sharp[key]), key


def test_the_blur_model_renders_across_the_exposure_and_zero_exposure_is_the_sharp_render() -> None:
    blurred = _model(_metadata(exposure_s=0.04), blur_samples=3, event_supervision="off")
    torch.manual_seed(3)
    out = blurred(_rays())
    assert "rgb_blurred" in out and out["rgb_blurred"].shape == out["rgb"].shape
    assert not torch.allclose(out["rgb_blurred"], out["rgb"], atol=1e-5)  # the camera moved during the exposure
    instant = _model(_metadata(exposure_s=0.0), blur_samples=3, event_supervision="off")
    torch.manual_seed(3)
    out = instant(_rays())
    assert torch.isfinite(out["rgb_blurred"]).all()
    # every sub-pose is the frame's pose: only the samplers' jitter differs between the renders
    assert (out["rgb_blurred"] - out["rgb"]).abs().mean() < 0.02
    blurred.eval()
    with torch.no_grad():
        assert "rgb_blurred" not in blurred(_rays())  # evaluation renders the sharp frame pose


@pytest.mark.parametrize(
    ("samples", "stamp", "rendered"),
    [(5, "centre", 4), (4, "centre", 4), (5, "start", 5)],
    ids=["odd", "even", "start"],
)
def test_the_blur_model_reuses_the_frames_render_at_mid_exposure(samples: int, stamp: str, rendered: int) -> None:
    """An odd number of blur samples puts the middle one at the exposure's centre: where frames are stamped there it
    is the frame's own render (`sharp_rgb`), blended as the other renders are, and not rendered again."""
    from agrinerf_ns.model.blur_term import render_at
    from agrinerf_ns.model.timed_rays import camera_rows, exposure_times

    metadata = _metadata(exposure_s=0.04)
    if stamp == "start":  # the frame's time stamp at the exposure's start: the middle pose is not the frame's
        times = metadata["times"]
        metadata["exposure"] = torch.stack([times, times + 0.04], -1)  # type: ignore[operator]
    model = _model(metadata, blur_samples=samples, event_supervision="off")
    bundle, n = _rays(), 48
    counts, render = [], model.render
    model.render = lambda rays, **kw: counts.append(len(rays)) or render(rays, **kw)  # type: ignore[method-assign]
    planted = torch.full((n, 3), 0.25)
    torch.manual_seed(7)
    assert model.blur is not None
    out = model.blur.blurred_rgb(model.render_rays, bundle, planted)
    assert counts == [rendered * n]
    if rendered == samples - 1:  # the expected blend of the other renders (same draws) and the planted frame render
        all_times = exposure_times(model.rig.exposure[camera_rows(bundle)], samples)  # type: ignore[index]
        middle = samples // 2
        torch.manual_seed(7)
        others_times = torch.cat([all_times[:, :middle], all_times[:, middle + 1 :]], 1)
        others = render_at(model.render_rays, model.rig, bundle, others_times, "rgb_loss")
        blend = torch.cat([others[:, :middle], planted[:, None], others[:, middle:]], 1)
        expected = colour.linear_to_srgb(colour.srgb_to_linear(blend).mean(dim=1))
        assert torch.allclose(out, expected, atol=1e-6)


def test_the_event_loss_reaches_the_density_and_the_rgb_appearance() -> None:
    model = _model(_metadata(), event_rays_per_batch=16)
    assert model.plan.use_event_loss
    loss_dict = _losses(model, _batch())
    assert "event_loss" in loss_dict
    norms = term_gradient_norms({"event_loss": loss_dict["event_loss"]}, parameter_groups(model))["event_loss"]
    assert norms["density"] > 0 and norms["rgb_volume"] > 0 and norms["rgb_mlp"] > 0
    assert norms["thermal_volume"] == 0.0 and norms["thermal_mlp"] == 0.0


@pytest.mark.parametrize("case", ["no events", "flood", "zero exposure", "zero-length window"])
def test_no_nan_or_inf_at_the_extremes(case: str) -> None:
    metadata = _metadata(exposure_s=0.0 if case == "zero exposure" else 0.04)
    if case == "zero-length window":
        times = metadata["times"]
        metadata["event_windows"] = torch.stack([times, times], -1)  # type: ignore[arg-type]
    model = _model(metadata, blur_samples=3, event_rays_per_batch=16)
    batch = _batch(on=0.0 if case == "no events" else (60000.0 if case == "flood" else 1.0),
                   off=60000.0 if case == "flood" else 0.0)  # fmt: skip
    loss_dict = _losses(model, batch)
    total = torch.stack(list(loss_dict.values())).sum()
    assert torch.isfinite(total)
    total.backward()
    for name, p in model.named_parameters():
        assert p.grad is None or torch.isfinite(p.grad).all(), name


def test_a_scene_without_event_sums_or_timing_has_no_event_loss() -> None:
    meta = _metadata()
    del meta["event_windows"]
    assert not _model(meta).plan.use_event_loss
    assert "event_loss" not in _losses(_model(meta), _batch())
    assert not _model({"modalities": ("rgb", "events")}, blur_samples=5).plan.use_blur


def test_the_evdeblurnerf_configuration_has_no_thermal_head() -> None:
    model = _model(_metadata(), cross_spectral_output=False)
    assert model.field.thermal_head is None and not any("thermal" in n for n, _ in model.named_parameters())
    assert set(_losses(model, _batch())) >= {"rgb_loss", "event_loss"}
    assert not any(k.startswith("reg_") for k in _losses(model, _batch()))


def test_event_camera_rays_start_at_its_centre_and_meet_the_rgb_ray_on_the_alignment_plane() -> None:
    bundle, traj = _rays(), _trajectory()
    frame_times = torch.from_numpy(traj.times)[bundle.camera_indices[:, 0]]
    centre = torch.tensor([-0.065, -0.02, 0.005], dtype=torch.float64)
    at_infinity = reposed_rays(bundle, traj, frame_times, frame_times[:, None], centre, math.inf)
    pose = torch.from_numpy(traj.poses_at(frame_times.numpy()))
    world_centre = (pose[:, :3, :3] @ centre[:, None])[..., 0] + pose[:, :3, 3]
    assert torch.allclose(at_infinity.origins.double(), world_centre, atol=1e-6)
    assert torch.allclose(at_infinity.directions, bundle.directions, atol=1e-6)  # a rotation-only homography
    depth = 2.5
    on_plane = reposed_rays(bundle, traj, frame_times, frame_times[:, None], centre, depth)
    forward = -pose[:, :3, 2]  # OpenGL: the camera looks along -z
    cos = (bundle.directions.double() * forward).sum(-1, keepdim=True)
    point = bundle.origins.double() + bundle.directions.double() * depth / cos
    to_point = torch.nn.functional.normalize(point - world_centre, dim=-1)
    assert torch.allclose(on_plane.directions.double(), to_point, atol=1e-5)


@pytest.mark.parametrize("term", ["rgb_loss", "event_loss"])
def test_the_blur_and_event_renders_follow_their_terms_density_scale(term: str) -> None:
    """`density_gradient_scales` of L_rgb (through the blur model's renders) and of the event term hold there too:
    at 0 the term trains the RGB appearance only."""
    metadata = _metadata(exposure_s=0.04)
    blur_events = {"blur_samples": 3, "event_rays_per_batch": 16, "event_supervision": "frames"}
    full = _model(metadata, **blur_events)
    off = _model(metadata, **blur_events, density_gradient_scales={term: 0.0})
    groups = [term_gradient_norms({term: _losses(m, _batch())[term]}, parameter_groups(m))[term] for m in (full, off)]
    assert groups[0]["density"] > 0 and groups[1]["density"] == 0.0
    assert groups[1]["rgb_volume"] == pytest.approx(groups[0]["rgb_volume"], rel=1e-5)


def test_the_blur_and_event_renders_leave_the_global_random_stream_as_it_was() -> None:
    """Common random numbers: a step with the blur model and the event loss draws the next batch's randomness exactly
    as a step without them does, so their ablation rows stay paired with the RGB-only row."""
    draws = []
    for kw in ({"blur_samples": 1, "event_supervision": "off"}, {"blur_samples": 3, "event_supervision": "frames"}):
        model = _model(_metadata(exposure_s=0.04), **kw)
        plan = model.plan
        assert plan.use_blur == (kw["blur_samples"] > 1) and plan.use_event_loss == (kw["event_supervision"] != "off")
        outputs = _losses(model, _batch(), seed=5)
        assert ("event_loss" in outputs) == model.plan.use_event_loss
        draws.append(torch.rand(4))
    assert torch.equal(draws[0], draws[1])


def test_the_event_loss_is_off_in_low_light_unless_kept() -> None:
    dark = {**_metadata(), "rgb_level": 0.012}
    assert not _model(dark, event_rays_per_batch=16).plan.use_event_loss
    assert _model(dark, event_rays_per_batch=16, low_light_event_loss=True).plan.use_event_loss
    assert _model({**_metadata(), "rgb_level": 0.3}, event_rays_per_batch=16).plan.use_event_loss
    assert _model(dark, event_rays_per_batch=16, low_light_level=0.0).plan.use_event_loss  # the rule switched off
