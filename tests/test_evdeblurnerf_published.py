"""EvDeblurNeRF as published: event-to-event samples, its event response, the learnt rigid blur kernel, the EDI prior
(hand-made streams and rays, the model on a tiny scene, extremes)."""

from __future__ import annotations

from pathlib import Path
from typing import Dict, List

import h5py
import numpy as np
import pytest
import torch
from helpers.small_model import SMALL_MODEL
from helpers.trajectory_rays import trajectory_rays, yawing_trajectory
from nerfstudio.cameras.rays import RayBundle
from nerfstudio.data.scene_box import SceneBox
from scipy.spatial.transform import Rotation

from agrinerf_ns import colour
from agrinerf_ns.dataparsers import event_stream
from agrinerf_ns.dataparsers.event_stream import GL_FLIP, EventCamera, EventStream
from agrinerf_ns.model import edi_prior, losses
from agrinerf_ns.model.event_crf import EventCRF, event_log_luma
from agrinerf_ns.model.event_pairs import EventPairs, pair_targets, polarity_features
from agrinerf_ns.model.model import AgriNeRFModel, AgriNeRFModelConfig
from agrinerf_ns.model.rigid_blur import blend, se3_exp, warp_rays
from agrinerf_ns.trajectory import CameraTrajectory

C_ON, C_OFF = 0.2, 0.25
W, H = 6, 4


# --------------------------------------------------------------------------------------- the event samples
def _hand_stream() -> Dict[str, np.ndarray]:
    """Pixel (1, 0): ON at 100 us, OFF at 300, ON at 700; pixel (2, 3): one OFF event (no successor); pixel (0, 0): two
    events at the same time."""
    return {
        "x": np.array([1, 2, 1, 0, 0, 1]),
        "y": np.array([0, 3, 0, 0, 0, 0]),
        "t": np.array([100, 150, 300, 400, 400, 700]),
        "p": np.array([1, 0, 0, 1, 0, 1]),
    }


def test_each_event_with_a_successor_is_one_sample_with_both_times_and_the_successors_polarity() -> None:
    s = _hand_stream()
    pairs = EventPairs(s["x"], s["y"], s["t"], s["p"], W, H)
    got = sorted(zip(pairs.pixel.tolist(), pairs.t_start_us.tolist(), pairs.t_end_us.tolist(),
                     pairs.polarity.tolist(), strict=True))  # fmt: skip
    # pixel 1: 100 -> 300 (successor OFF), 300 -> 700 (ON); pixel 0: 400 -> 400 (the stream's second event, OFF)
    assert got == [(0, 400, 400, -1), (1, 100, 300, -1), (1, 300, 700, 1)]
    pixel, t0, t1, polarity = pairs.sample(3000, torch.Generator().manual_seed(0))
    assert set(zip(pixel.tolist(), t0.tolist(), t1.tolist(), polarity.tolist(), strict=True)) <= set(got)
    assert torch.bincount(t0 // 100, minlength=5)[[1, 3, 4]].min() > 900  # uniform over the three samples


def test_one_samples_target_and_loss_are_evdeblurnerfs() -> None:
    """The published egm_loss written out: bii = C_neg * neg_cumsum + C_pos * pos_cumsum of the successor, the renders'
    BT.601 luma at the two times, (log(l_end + 1e-5) - log(l_start + 1e-5) - bii)^2."""
    polarity = torch.tensor([-1, 1])  # (100 -> 300: OFF successor), (300 -> 700: ON successor)
    target = pair_targets(polarity, C_ON, C_OFF)
    assert target[:, 0].tolist() == pytest.approx([-C_OFF, C_ON])
    neg, pos = polarity_features(polarity).unbind(-1)
    assert (C_OFF * neg + C_ON * pos).tolist() == pytest.approx(target[:, 0].tolist())

    linear = torch.tensor([[[0.20, 0.10, 0.05], [0.15, 0.08, 0.04]], [[0.01, 0.02, 0.0], [0.03, 0.05, 0.01]]])
    logs = event_log_luma(linear, 1e-5)  # [2 samples, 2 times, 1]
    luma = 0.299 * linear[..., 0] + 0.587 * linear[..., 1] + 0.114 * linear[..., 2]
    want = ((torch.log(luma[:, 1] + 1e-5) - torch.log(luma[:, 0] + 1e-5)) - target[:, 0]) ** 2
    loss = losses.event_pair_loss(logs[:, 0], logs[:, 1], target)
    assert float(loss) == pytest.approx(float(want.mean()), rel=1e-6)


# ------------------------------------------------------------------------------------ a tiny scene, the model
def _trajectory() -> CameraTrajectory:
    return yawing_trajectory(dt=0.001, yaw_rate=30.0, speed=100.0)


def _camera(tmp_path: Path, stream: Dict[str, np.ndarray]) -> EventCamera:
    path = tmp_path / "stream.h5"
    with h5py.File(path, "w") as f:
        g = f.create_group("events")
        for k in "xytp":
            g.create_dataset(k, data=np.asarray(stream[k]))
    return EventCamera(path=path, width=W, height=H, intrinsics=(4.0, 4.0, 2.4, 1.6), distortion=(0.0, 0.0, 0.0, 0.0),
                       rotation=torch.from_numpy(GL_FLIP.copy()), centre=torch.zeros(3, dtype=torch.float64))  # fmt: skip


def _metadata(camera: EventCamera) -> Dict[str, object]:
    traj = _trajectory()
    times = torch.from_numpy(traj.times)
    return {
        "modalities": ("rgb", "events"),
        "times": times,
        "exposure": torch.stack([times - 0.0008, times + 0.0008], -1),
        "trajectory": traj,
        "event_windows": torch.stack([times - 0.001, times], -1),
        "event_stream": camera,
    }


PUBLISHED = dict(event_supervision="pairs", event_rays_per_batch=8, event_log_eps=1e-5, event_threshold=C_ON,
                 blur_kernel="learnt", blur_samples=10, blur_start_step=0, density_shift=0.0,
                 cross_spectral_output=False)  # fmt: skip


def _model(camera: EventCamera, **kw) -> AgriNeRFModel:
    torch.manual_seed(0)
    cfg = AgriNeRFModelConfig(modalities=("rgb", "events"), **{**SMALL_MODEL, **PUBLISHED, **kw})
    box = SceneBox(aabb=torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]))
    model = cfg.setup(scene_box=box, num_train_data=4, metadata=_metadata(camera))
    model.train()
    return model


def _rays(n: int = 32) -> RayBundle:
    return trajectory_rays(_trajectory(), n)


def _step(model: AgriNeRFModel, n: int = 32, black: bool = False):
    torch.manual_seed(3)
    outputs = model(_rays(n))
    batch = {"image": torch.zeros(n, 3) if black else torch.rand(n, 3, generator=torch.Generator().manual_seed(2))}
    metrics = model.get_metrics_dict(outputs, batch)
    return outputs, metrics, model.get_loss_dict(outputs, batch, metrics)


def test_the_model_renders_a_sample_at_the_events_two_times_and_weighs_its_loss_by_0_1(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # one pixel, two events: every sample is the same one (ON at 1.0 ms, then its OFF successor at 1.6 ms)
    camera = _camera(tmp_path, {"x": np.array([2, 2]), "y": np.array([1, 1]), "t": np.array([1000, 1600]),
                                "p": np.array([1, 0])})  # fmt: skip
    model = _model(camera, blur_samples=1, edi_prior=False)
    seen: List[torch.Tensor] = []
    real = event_stream.event_rays

    def spy(trajectory, cam, pixel, times_s):
        seen.append(times_s.clone())
        assert pixel.tolist() == [1 * W + 2] * pixel.shape[0]
        return real(trajectory, cam, pixel, times_s)

    monkeypatch.setattr(event_stream, "event_rays", spy)
    outputs, metrics, loss_dict = _step(model)
    assert len(seen) == 1 and seen[0].shape == (8, 2)
    assert torch.allclose(seen[0], torch.tensor([[1000e-6, 1600e-6]], dtype=torch.float64).expand(8, 2))
    assert torch.equal(outputs["event_target"], torch.full((8, 1), -C_ON))  # the successor's polarity: OFF
    change = outputs["event_log_end"] - outputs["event_log_start"]
    assert float(metrics["event_loss"]) == pytest.approx(float(((change + C_ON) ** 2).mean()), rel=1e-6)
    assert float(loss_dict["event_loss"]) == pytest.approx(0.1 * float(metrics["event_loss"]), rel=1e-6)


def test_the_learnt_kernel_starts_as_the_sharp_ray_and_its_parameters_learn(tmp_path: Path) -> None:
    camera = _camera(tmp_path, _hand_stream())
    model = _model(camera, event_supervision="off", edi_prior=False)
    assert model.blur_kernel is not None and model.blur_kernel.num_motions == 9
    bundle = _rays()
    rotation, translation, weights = model.blur_kernel(bundle.camera_indices[:, 0])
    origins, directions = warp_rays(bundle.origins, bundle.directions, rotation, translation)
    assert origins.shape == (32, 9, 3)
    assert torch.allclose(origins, bundle.origins[:, None].expand_as(origins), atol=1e-5)
    assert torch.allclose(directions, bundle.directions[:, None].expand_as(directions), atol=1e-5)
    assert torch.allclose(weights.sum(-1), torch.ones(32), atol=1e-6) and weights.shape == (32, 10)
    colour = torch.rand(32, 1, 3).expand(32, 10, 3)
    assert torch.allclose(blend(colour, weights), colour[:, 0], atol=1e-6)

    outputs, _, loss_dict = _step(model)
    # identical rays: the blended colour is the sharp render's, up to the renders' own sample jitter
    assert (outputs["rgb_blurred"] - outputs["rgb"]).abs().mean() < 0.02
    loss_dict["rgb_loss"].backward()
    grads = {name: p.grad for name, p in model.blur_kernel.named_parameters()}
    assert all(g is None or torch.isfinite(g).all() for g in grads.values())
    # the weights learn; the motions through the rays' directions (the RGB head is view dependent). The latent codes
    # start at zero (as published), so the first layers' weights learn from the second step on.
    for name in ("embedding", "weights.0.bias", "weights.2.weight", "rotation.0.bias", "rotation.2.weight"):
        assert grads[name] is not None and float(grads[name].abs().sum()) > 0, name
    assert "blur_kernel" in model.get_param_groups()


def test_the_kernels_translations_learn_through_the_sample_positions(tmp_path: Path) -> None:
    model = _model(_camera(tmp_path, _hand_stream()), event_supervision="off", edi_prior=False)
    assert model.blur_kernel is not None
    _, _, loss_dict = _step(model)
    loss_dict["rgb_loss"].backward()
    grad = model.blur_kernel.translation[2].weight.grad
    assert grad is not None and float(grad.abs().sum()) > 0


def test_se3_exp_is_rodrigues_and_the_twists_matrix_exponential() -> None:
    gen = torch.Generator().manual_seed(0)
    w = torch.randn(20, 3, generator=gen, dtype=torch.float64) * 0.5
    w[0] = 0.0
    w[1] = 1e-9
    v = torch.randn(20, 3, generator=gen, dtype=torch.float64)
    rot, trans = se3_exp(w, v)
    np.testing.assert_allclose(rot.numpy(), Rotation.from_rotvec(w.numpy()).as_matrix(), atol=1e-12)
    twist = torch.zeros(20, 4, 4, dtype=torch.float64)
    twist[:, :3, :3] = torch.tensor([[0.0, 0, 0], [0, 0, 0], [0, 0, 0]])
    twist[:, 0, 1], twist[:, 0, 2], twist[:, 1, 2] = -w[:, 2], w[:, 1], -w[:, 0]
    twist[:, 1, 0], twist[:, 2, 0], twist[:, 2, 1] = w[:, 2], -w[:, 1], w[:, 0]
    twist[:, :3, 3] = v
    exp = torch.linalg.matrix_exp(twist)
    assert torch.allclose(trans, exp[:, :3, 3], atol=1e-10) and torch.allclose(rot, exp[:, :3, :3], atol=1e-10)


def test_the_event_response_is_the_identity_before_its_start_and_learns_after(tmp_path: Path) -> None:
    crf = EventCRF()
    x = torch.linspace(0.05, 0.95, 19)[:, None, None].expand(19, 1, 3)
    error = (crf(x) - x).abs()
    assert float(error.mean()) < 0.03 and float(error.max()) < 0.06  # the identity fit, as published (not exact)
    camera = _camera(tmp_path, _hand_stream())
    model = _model(camera, blur_samples=1, edi_prior=False, event_crf=True, event_crf_start_step=5)
    assert model.events is not None and model.events.crf is not None and "event_crf" in model.get_param_groups()
    _, _, loss_dict = _step(model)
    loss_dict["event_loss"].backward()
    assert all(p.grad is None for p in model.events.crf.parameters())  # not used before its start step
    model.step = 5
    _, _, loss_dict = _step(model)
    loss_dict["event_loss"].backward()
    assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in model.events.crf.parameters())


# ------------------------------------------------------------------------------------------------- the EDI prior
def test_edi_factors_undo_the_exposure_mean_of_a_log_ramp_and_are_one_without_events() -> None:
    # pixel 3: one ON event in each of the 8 intervals of [0, 8 ms]; the sharp mid-exposure value is B / mean exp
    t = np.arange(8) * 1000 + 500
    stream = EventStream(np.full(8, 3), np.zeros(8, int), t, np.ones(8, int), W, H)
    exposure = torch.tensor([[0.0, 0.008], [0.0, 0.008]], dtype=torch.float64)
    factor = edi_prior.edi_factors(stream, torch.tensor([3, 4]), exposure, C_ON, C_OFF)
    want = np.mean(np.exp((np.arange(9) - 4) * C_ON))
    assert float(factor[0]) == pytest.approx(want, rel=1e-6) and float(factor[1]) == 1.0
    assert edi_prior.cosine_weight(0) == pytest.approx(0.01) and edi_prior.cosine_weight(10_000) == 1e-5
    assert edi_prior.cosine_weight(5000) == pytest.approx((0.01 + 1e-5) / 2)


def test_rgb_pixels_map_to_the_event_pixel_that_sees_the_same_point(tmp_path: Path) -> None:
    camera = _camera(tmp_path, _hand_stream())
    axis = torch.tensor([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]], dtype=torch.float64)  # forward, and behind the camera
    pixel, inside = edi_prior.event_pixels(camera, axis)
    assert inside.tolist() == [True, False] and int(pixel[0]) == 2 * W + 2  # the principal point (2.4, 1.6)


def test_the_edi_prior_trains_with_its_decayed_weight(tmp_path: Path) -> None:
    camera = _camera(tmp_path, _hand_stream())
    model = _model(camera, blur_samples=1, event_supervision="off", edi_prior=True)
    outputs, metrics, loss_dict = _step(model)
    assert "edi_factor" in outputs and "edi_prior_loss" in metrics
    assert float(loss_dict["edi_prior_loss"]) == pytest.approx(0.01 * float(metrics["edi_prior_loss"]), rel=1e-6)


# -------------------------------------------------------------------------------------------------- extremes
@pytest.mark.parametrize("case", ["empty stream", "no successor", "black frames", "flood"])
def test_no_nan_or_inf_at_the_extremes(tmp_path: Path, case: str) -> None:
    if case == "empty stream":
        stream = {k: np.zeros(0, np.int64) for k in "xytp"}
    elif case == "no successor":
        stream = {"x": np.array([0, 1]), "y": np.array([0, 0]), "t": np.array([100, 200]), "p": np.array([1, 0])}
    elif case == "flood":
        n = 20000
        stream = {"x": np.full(n, 2), "y": np.full(n, 1), "t": np.linspace(0, 3000, n).astype(np.int64),
                  "p": np.ones(n, np.int64)}  # fmt: skip
    else:
        stream = _hand_stream()
    model = _model(_camera(tmp_path, stream), edi_prior=True, event_crf=True, event_crf_start_step=0)
    _, _, loss_dict = _step(model, black=case == "black frames")
    assert ("event_loss" in loss_dict) == (case not in ("empty stream", "no successor"))
    total = torch.stack(list(loss_dict.values())).sum()
    assert torch.isfinite(total)
    total.backward()
    for name, p in model.named_parameters():
        assert p.grad is None or torch.isfinite(p.grad).all(), name


def test_all_black_renders_give_a_finite_loss_and_gradient() -> None:
    srgb = torch.zeros(4, 2, 3, requires_grad=True)
    for crf in (None, EventCRF()):
        logs = event_log_luma(colour.srgb_to_linear(srgb), 1e-5, crf, torch.zeros(4, 2))
        loss = losses.event_pair_loss(logs[:, 0], logs[:, 1], torch.full((4, 1), C_ON))
        assert float(loss) == pytest.approx(C_ON**2, rel=1e-5)  # no change rendered, one threshold reported
        (grad,) = torch.autograd.grad(loss, srgb)
        assert torch.isfinite(grad).all()
    empty = torch.zeros(0, 1)
    assert float(losses.event_pair_loss(empty, empty, empty)) == 0.0


# --------------------------------------------------------------------------------------------------- presets
def test_the_evdeblurnerf_presets_follow_the_published_recipe_and_the_port_keeps_another_name() -> None:
    from agrinerf_ns.method_configs import agrinerf_methods as m

    for spec in (m.evdeblurnerf, m.evdeblurnerf_lite):
        model = spec.config.pipeline.model
        assert (model.event_supervision, model.event_rays_per_batch, model.event_log_eps) == ("pairs", 4096, 1e-5)
        assert model.loss_coefficients["event_loss"] == 0.1 and model.event_loss_weighting == "fixed"
        assert (model.event_crf, model.event_crf_start_step, model.edi_prior) == (True, 1200, True)
        assert (model.blur_kernel, model.blur_samples, model.blur_start_step) == ("learnt", 10, 1200)
        assert model.modalities == ("rgb", "events") and not model.cross_spectral_output
        optimizers = spec.config.optimizers
        # the published 5e-3, but the grids at TensoRF's rate (the field they are; its help text says so)
        for group, rate in (("fields", 5e-3), ("encodings", 2e-2), ("blur_kernel", 5e-3), ("event_crf", 5e-3)):
            assert optimizers[group]["optimizer"].lr == rate
            scheduler = optimizers[group]["scheduler"].setup()
            steps = optimizers[group]["scheduler"].max_steps
            lr = scheduler.get_scheduler(torch.optim.Adam([torch.nn.Parameter(torch.zeros(1))], lr=rate), rate)
            factor = lr.lr_lambdas[0](steps // 2)
            assert factor == pytest.approx(0.1 ** (steps / 2 / 10_000), rel=1e-9)  # x0.1 every 10k steps
    assert all("PDRF" in d and "5e-3" in d for d in (m.evdeblurnerf.description, m.evdeblurnerf_lite.description))
    port = m.evdeblurnerf_windowed_lite.config.pipeline.model
    assert (port.event_supervision, port.blur_kernel, port.blur_samples) == ("stream", "trajectory", 3)
