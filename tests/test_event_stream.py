"""The event loss's native supervision (issue 15): counts of the event stream over any window, random sub-windows, and
the rays of event pixels at any time, against brute force and the synthetic rig's truth."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
import torch

from agrinerf_ns.dataparsers.agrinerf_dataparser import AgriNeRFDataParserConfig
from agrinerf_ns.dataparsers.event_stream import EventStream, event_rays, pixel_directions, sample_windows
from agrinerf_ns.process import ProcessConfig, process_capture
from agrinerf_ns.synth import SynthConfig, generate_capture
from agrinerf_ns.synth.capture import make_scene


def _brute(x, y, t, p, width, pixel, t0, t1):
    on, off = [], []
    for q, a, b in zip(pixel.tolist(), t0.tolist(), t1.tolist(), strict=True):
        sel = (y * width + x == q) & (t >= a) & (t < b)
        on.append(int((sel & (p == 1)).sum()))
        off.append(int((sel & (p == 0)).sum()))
    return on, off


def test_counts_match_brute_force_for_any_window_including_empty_reversed_and_outside_the_stream() -> None:
    rng = np.random.default_rng(0)
    width, height, n = 7, 5, 4000
    x, y = rng.integers(0, width, n), rng.integers(0, height, n)
    t = np.sort(rng.integers(1_000, 50_000, n))
    t[100:300] = 20_000  # a flood: many events at one instant
    p = rng.integers(0, 2, n)
    stream = EventStream(x, y, t, p, width, height)
    m = 300
    pixel = torch.from_numpy(rng.integers(0, width * height, m))
    t0 = torch.from_numpy(rng.integers(-5_000, 60_000, m))
    t1 = t0 + torch.from_numpy(rng.integers(-2_000, 30_000, m))  # some reversed (empty), some past the end
    t0[:5], t1[:5] = -10, 100_000  # whole stream
    on, off = stream.counts(pixel, t0, t1)
    want_on, want_off = _brute(x, y, t, p, width, pixel.numpy(), t0.numpy(), t1.numpy())
    assert on[:, 0].long().tolist() == want_on and off[:, 0].long().tolist() == want_off
    assert sum(want_on) > 0 and min(want_on) == 0  # the cases exercised both


def test_an_empty_stream_counts_nothing() -> None:
    empty = np.zeros(0, np.int64)
    on, off = EventStream(empty, empty, empty, empty, 4, 3).counts(torch.tensor([0, 11]), torch.tensor([0, 0]),
                                                                   torch.tensor([10, 10]))  # fmt: skip
    assert on.sum() == 0 and off.sum() == 0 and on.shape == (2, 1)


def test_sub_windows_lie_inside_their_frames_window_with_the_configured_lengths() -> None:
    windows = torch.tensor([[0.1, 0.2], [0.2, 0.3], [0.3, 0.3]], dtype=torch.float64)
    frames = torch.randint(0, 3, (2000,), generator=torch.Generator().manual_seed(0))
    t0, t1 = sample_windows(windows, frames, 0.25, torch.Generator().manual_seed(1))
    start, end = (windows[frames] * 1e6).round().long().unbind(-1)
    assert bool((t0 >= start).all() and (t1 <= end).all() and (t1 >= t0).all())
    length = (t1 - t0).double() / (end - start).clamp(min=1).double()
    full = end > start
    assert float(length[full].min()) >= 0.25 - 1e-4 and float(length[full].max()) > 0.95
    assert bool((t0[~full] == t1[~full]).all())  # a zero-length window gives an empty sub-window
    t0, t1 = sample_windows(windows, frames, 1.0, None)
    assert bool((t0 == start).all() and (t1 == end).all())  # fraction 1: the whole frame windows


def test_pixel_directions_project_back_onto_the_pixel_centres() -> None:
    import cv2

    intrinsics, distortion = (52.9, 53.1, 38.4, 21.4), (-0.08, 0.015, -5e-4, 4e-4)
    d = pixel_directions(intrinsics, distortion, 77, 43).numpy()
    K = np.array([[52.9, 0, 38.4], [0, 53.1, 21.4], [0, 0, 1.0]])
    uv, _ = cv2.projectPoints(d, np.zeros(3), np.zeros(3), K, np.asarray(distortion))
    v, u = np.mgrid[0:43, 0:77]
    np.testing.assert_allclose(uv[:, 0], np.stack([u.ravel(), v.ravel()], -1), atol=1e-3)
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0, atol=1e-12)


@pytest.fixture(scope="module")
def dusk_capture(tmp_path_factory: pytest.TempPathFactory):
    root = tmp_path_factory.mktemp("event-stream")
    config = SynthConfig.tiny(seed=4, lighting="dusk")
    raw = generate_capture(config, root / "raw")
    data = process_capture(raw, root / "data", ProcessConfig(poses="given", show_progress=False))
    return config, raw, data


def test_the_dataset_stream_holds_the_raw_events_of_the_frame_windows_in_the_frame_clock(dusk_capture) -> None:
    _, raw, data = dusk_capture
    with h5py.File(raw / "events" / "events.h5") as f:
        raw_t = np.asarray(f["events"]["t"])
        raw_x = np.asarray(f["events"]["x"])
    outputs = AgriNeRFDataParserConfig(data=data).setup().get_dataparser_outputs("train")
    meta = outputs.metadata["event_stream"]
    with h5py.File(meta.path) as f:
        t, x = np.asarray(f["events"]["t"]), np.asarray(f["events"]["x"])
    windows = outputs.metadata["event_windows"].numpy()
    lo, hi = np.searchsorted(raw_t, [round(windows.min() * 1e6), round(windows.max() * 1e6)])
    # a recorded sync: the frame clock is the event clock; every event of the windows' span, nothing else
    np.testing.assert_array_equal(t, raw_t[lo:hi])
    np.testing.assert_array_equal(x, raw_x[lo:hi])
    assert 0 < t.size < raw_t.size


def test_event_pixel_rays_pass_through_what_the_synthetic_event_camera_saw(dusk_capture) -> None:
    config, _, data = dusk_capture
    outputs = AgriNeRFDataParserConfig(data=data).setup().get_dataparser_outputs("train")
    meta = outputs.metadata["event_stream"]
    _, rig = make_scene(config)
    cam = rig.cams["event"]
    rng = np.random.default_rng(1)
    pixel = rng.integers(0, cam.width * cam.height, 64)
    windows = outputs.metadata["event_windows"].numpy()
    times = rng.uniform(windows.min(), windows.max(), (64, 2))
    origins, directions = event_rays(outputs.metadata["trajectory"], meta, torch.from_numpy(pixel),
                                     torch.from_numpy(times))  # fmt: skip
    poses = outputs.metadata["trajectory"].poses_at_tensor(torch.from_numpy(times), dtype=torch.float64).numpy()
    scale = float(outputs.dataparser_scale)
    for i in range(64):
        for j in range(2):
            # a point 3 m along the event camera's truth ray, in the truth RGB camera's frame; then placed on the
            # dataset's trajectory (the capture's odometry, not the truth path: only the rig geometry is compared)
            T_ev, T_rgb = rig.pose(float(times[i, j]), "event"), rig.pose(float(times[i, j]), "rgb")
            world = T_ev[:3, 3] + 3.0 * (T_ev[:3, :3] @ cam.ray_dirs[pixel[i]])
            local = np.diag([1.0, -1.0, -1.0]) @ (T_rgb[:3, :3].T @ (world - T_rgb[:3, 3])) * scale
            point = poses[i, j, :, :3] @ local + poses[i, j, :, 3]
            o, d = origins[i, j].numpy(), directions[i, j].numpy()
            off_ray = np.linalg.norm(np.cross(point - o, d)) / np.linalg.norm(point - o)  # radians
            assert off_ray < 0.05 / cam.fx  # a twentieth of an event pixel


def _stream_model(outputs, **kw):
    from helpers.small_model import SMALL_MODEL

    from agrinerf_ns.model.model import AgriNeRFModelConfig

    torch.manual_seed(0)
    config = AgriNeRFModelConfig(modalities=("rgb", "events"), cross_spectral_output=False, event_supervision="stream",
                                 event_rays_per_batch=64,
                                 **{**SMALL_MODEL, **kw})  # fmt: skip
    model = config.setup(scene_box=outputs.scene_box, num_train_data=len(outputs.image_filenames),
                         metadata=outputs.metadata)  # fmt: skip
    model.train()
    return model


def _step(model, outputs):
    rays = outputs.cameras.generate_rays(camera_indices=0).flatten()[:128]
    out = model(rays)
    batch = {"image": torch.rand(128, 3, generator=torch.Generator().manual_seed(0))}
    metrics = model.get_metrics_dict(out, batch)
    return out, metrics, model.get_loss_dict(out, batch, metrics)


def test_the_stream_event_loss_renders_event_pixels_and_trains_density_and_rgb(dusk_capture) -> None:
    from agrinerf_ns.model.gradients import parameter_groups, term_gradient_norms

    outputs = AgriNeRFDataParserConfig(data=dusk_capture[2]).setup().get_dataparser_outputs("train")
    model = _stream_model(outputs)
    assert model.events is not None and model.events.stream is not None and model.events.stream.num_events > 0
    out, metrics, loss_dict = _step(model, outputs)
    assert out["event_on"].shape == out["event_log_start"].shape == (64, 1)
    assert float((out["event_on"] + out["event_off"]).sum()) > 0  # the dusk capture's events were found
    assert torch.isfinite(loss_dict["event_loss"]) and float(loss_dict["event_loss"]) > 0
    norms = term_gradient_norms({"event_loss": loss_dict["event_loss"]}, parameter_groups(model))["event_loss"]
    assert norms["density"] > 0 and norms["rgb_volume"] > 0 and norms["rgb_mlp"] > 0


def test_the_noise_weighting_balances_the_event_term_by_the_running_losses(dusk_capture) -> None:
    outputs = AgriNeRFDataParserConfig(data=dusk_capture[2]).setup().get_dataparser_outputs("train")
    model = _stream_model(outputs, event_loss_weighting="noise", loss_coefficients={"rgb_loss": 1.0, "event_loss": 1.0})
    _, metrics, loss_dict = _step(model, outputs)
    rgb, event = float(metrics["rgb_loss"]), float(metrics["event_loss"])
    # the first step's running means are its own losses: weight (64 event pixels / 128 rays) x rgb / event, at most 1
    want = event * 0.5 * min(rgb / event, 1.0)
    assert float(loss_dict["event_loss"]) == pytest.approx(want, rel=1e-5)
    first = float(model.events.weight)
    _, metrics2, _ = _step(model, outputs)
    assert metrics2["event_loss_weight"] == pytest.approx(first)  # logged: the weight of the step before
    assert 0 < float(model.events.weight) <= 0.5


def test_learnt_thresholds_are_trained_by_the_event_loss_and_absent_unless_asked(dusk_capture) -> None:
    outputs = AgriNeRFDataParserConfig(data=dusk_capture[2]).setup().get_dataparser_outputs("train")
    assert _stream_model(outputs).events.log_threshold is None
    model = _stream_model(outputs, event_threshold_learnt=True, event_threshold=0.25)
    threshold = model.events.log_threshold
    assert threshold is not None and any(p is threshold for p in model.get_param_groups()["fields"])
    _, metrics, loss_dict = _step(model, outputs)
    assert float(metrics["event_threshold_on"]) == pytest.approx(0.25)
    loss_dict["event_loss"].backward()
    assert (
        threshold.grad is not None
        and bool(torch.isfinite(threshold.grad).all())
        and float(threshold.grad.abs().sum()) > 0
    )
