"""The thermal terms rendered from the thermal camera (`model/thermal_view.py`): where the dataset puts that camera,
against the synthesiser's truth rig, and which rays and targets the model's thermal terms read."""

from __future__ import annotations

import math
from typing import Dict

import numpy as np
import pytest
import torch
from helpers.small_model import SMALL_MODEL
from helpers.trajectory_rays import trajectory_rays, yawing_trajectory
from nerfstudio.cameras.rays import RayBundle
from nerfstudio.data.scene_box import SceneBox

from agrinerf_ns.dataparsers.agrinerf_dataparser import AgriNeRFDataParserConfig
from agrinerf_ns.model import losses
from agrinerf_ns.model.model import AgriNeRFModel, AgriNeRFModelConfig
from agrinerf_ns.model.thermal_view import PREFIX
from agrinerf_ns.process import ProcessConfig, process_capture
from agrinerf_ns.synth import SynthConfig, generate_capture
from agrinerf_ns.synth.camera_rig import THERMAL_DELAY
from agrinerf_ns.synth.capture import make_scene
from agrinerf_ns.trajectory import CameraTrajectory

CENTRE = (0.07, -0.012, 0.004)
"""The thermal camera's centre in the RGB camera's frame (OpenGL axes), in scene units."""


@pytest.mark.parametrize("plane_depth", [math.inf, 1.8])
def test_the_thermal_camera_sits_where_the_synthetic_rig_put_it(tmp_path, plane_depth: float) -> None:
    """The dataset's thermal camera, placed on the dataset's trajectory at a frame's time, is the truth rig's thermal
    camera centre (in the truth RGB camera's frame, carried onto the dataset's poses, as the event test does)."""
    config = SynthConfig.tiny(seed=2, lighting="bright")
    raw = generate_capture(config, tmp_path / "raw")
    data = process_capture(raw, tmp_path / "data", ProcessConfig(poses="given", show_progress=False,
                                                                 plane_depth=plane_depth))  # fmt: skip
    outputs = AgriNeRFDataParserConfig(data=data).setup().get_dataparser_outputs("train")
    camera = outputs.metadata["thermal_camera"]
    scale = float(outputs.dataparser_scale)
    assert camera["plane_depth"] == pytest.approx(plane_depth * scale)
    _, rig = make_scene(config)
    trajectory, times = outputs.metadata["trajectory"], outputs.metadata["times"].numpy()
    # the synthetic thermal camera is triggered with the RGB one and exposed THERMAL_DELAY later, at its own pose
    thermal_times = outputs.metadata["thermal_times"].numpy()
    np.testing.assert_allclose(thermal_times, times + THERMAL_DELAY, atol=1e-9)
    poses = trajectory.poses_at_tensor(torch.from_numpy(times), dtype=torch.float64).numpy()
    thermal_poses = trajectory.poses_at_tensor(torch.from_numpy(thermal_times), dtype=torch.float64).numpy()
    centre = camera["camera_centre"].numpy()
    for i, t in enumerate(times):
        T_th, T_rgb = rig.pose(float(t) + THERMAL_DELAY, "thermal"), rig.pose(float(t), "rgb")
        local = np.diag([1.0, -1.0, -1.0]) @ (T_rgb[:3, :3].T @ (T_th[:3, 3] - T_rgb[:3, 3])) * scale
        truth = poses[i, :, :3] @ local + poses[i, :, 3]
        placed = thermal_poses[i, :, :3] @ centre + thermal_poses[i, :, 3]
        # between the frames the trajectory interpolates the truth's motion (0.2 mm off here); at the RGB frame's time
        # the thermal camera would be where the rig was 4 ms earlier (3 mm at the tiny rig's speed)
        assert np.linalg.norm(placed - truth) < 5e-4 * scale
        assert np.linalg.norm(local) > 0.05 * scale  # the rig's 7 cm baseline: the test could tell
        at_rgb_time = poses[i, :, :3] @ centre + poses[i, :, 3]
        assert np.linalg.norm(at_rgb_time - truth) > 2e-3 * scale  # the rig's motion in THERMAL_DELAY: it could tell


def _trajectory() -> CameraTrajectory:
    return yawing_trajectory()


def _metadata(**camera: object) -> Dict[str, object]:
    traj = _trajectory()
    meta: Dict[str, object] = {
        "modalities": ("rgb", "thermal"),
        "times": torch.from_numpy(traj.times),
        "trajectory": traj,
        "temperature_stats": {"mean_c": 20.0, "std_c": 4.0, "min_c": 5.0, "max_c": 35.0},
    }
    if camera:
        meta["thermal_camera"] = camera
    return meta


def _model(metadata: Dict[str, object], **kw) -> AgriNeRFModel:
    torch.manual_seed(0)
    cfg = AgriNeRFModelConfig(modalities=("rgb", "thermal"), **{**SMALL_MODEL, "density_shift": 0.0, **kw})
    box = SceneBox(aabb=torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]))
    model = cfg.setup(scene_box=box, num_train_data=4, metadata=metadata)
    model.train()
    return model


def _rays(n: int = 48) -> RayBundle:
    return trajectory_rays(_trajectory(), n)


def _batch(n: int = 48) -> Dict[str, torch.Tensor]:
    gen = torch.Generator().manual_seed(2)
    return {"image": torch.rand(n, 3, generator=gen), "thermal": torch.rand(n, 1, generator=gen),
            "thermal_mask": torch.ones(n, 1), "temperature": 20.0 + 4.0 * torch.randn(n, 1, generator=gen),
            "temperature_mask": (torch.arange(n) % 5 != 0).float()[:, None]}  # fmt: skip


def test_the_thermal_terms_read_the_thermal_cameras_rays_and_their_own_targets() -> None:
    camera = {"camera_centre": torch.tensor(CENTRE, dtype=torch.float64), "plane_depth": math.inf}
    model = _model(_metadata(**camera), thermal_rays_per_batch=32)
    rays, batch = _rays(), _batch()
    seen = []
    render = model.render
    model.render = lambda bundle, **kw: seen.append((bundle, kw)) or render(bundle, **kw)  # type: ignore[method-assign]
    torch.manual_seed(3)
    outputs = model(rays)
    terms = model.get_metrics_dict(outputs, batch)
    # the second render: the first 32 rays, from the thermal camera's centre, in their own directions (plane at inf)
    moved, kw = seen[1]
    assert kw == {"heads": ("thermal", "temperature")} and moved.origins.shape[0] == 32
    # the RGB rays' render skips the temperature head: no term reads it there
    assert seen[0][1] == {"heads": ("rgb", "thermal")} and "temperature" not in outputs and "thermal" in outputs
    frame = torch.from_numpy(_trajectory().poses_at(_trajectory().times[rays.camera_indices[:32, 0].numpy()]))
    centre = (frame[:, :3, :3] @ torch.tensor(CENTRE, dtype=torch.float64)[:, None])[..., 0] + frame[:, :3, 3]
    assert torch.allclose(moved.origins.double(), centre, atol=1e-5)
    assert torch.allclose(moved.directions, rays.directions[:32], atol=1e-6)
    # every thermal-frame term is that render against the batch's first 32 targets
    head = model.field.temperature_head
    assert head is not None
    expected = {
        "thermal_loss": losses.thermal_loss(
            outputs[PREFIX + "thermal"], batch["thermal"][:32], batch["thermal_mask"][:32]
        ),
        "thermal_camera_loss": losses.thermal_loss(
            outputs[PREFIX + "thermal_camera"], batch["thermal"][:32], batch["thermal_mask"][:32]
        ),
        "temperature_loss": losses.thermal_loss(
            head.normalise(outputs[PREFIX + "temperature"]),
            head.normalise(batch["temperature"][:32]),
            batch["temperature_mask"][:32],
        ),
    }
    for term, value in expected.items():
        assert torch.allclose(terms[term], value), term
    # ... and the temperature term trains the temperature head through it
    loss = model.get_loss_dict(outputs, batch, terms)["temperature_loss"]
    loss.backward()
    assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in head.parameters())


def test_the_thermal_rays_start_where_the_rig_was_when_the_thermal_frame_was_taken() -> None:
    """An unsynchronised thermal camera (dataset `thermal_timestamp`, metadata `thermal_times`): each thermal ray
    starts at the thermal camera's centre on the rig's pose at its own frame's time, and keeps its place on the
    alignment plane (at infinity: its direction in the rig's frame)."""
    camera = {"camera_centre": torch.tensor(CENTRE, dtype=torch.float64), "plane_depth": math.inf}
    metadata = _metadata(**camera)
    delay = 0.05  # half a frame interval of the trajectory
    metadata["thermal_times"] = metadata["times"] + delay  # type: ignore[operator]
    model = _model(metadata, thermal_rays_per_batch=32)
    rays = _rays()
    seen = []
    render = model.render
    model.render = lambda bundle, **kw: seen.append(bundle) or render(bundle, **kw)  # type: ignore[method-assign]
    model(rays)
    moved = seen[1]
    traj = _trajectory()
    at_rgb = torch.from_numpy(traj.poses_at(traj.times[rays.camera_indices[:32, 0].numpy()]))
    at_thermal = torch.from_numpy(traj.poses_at(traj.times[rays.camera_indices[:32, 0].numpy()] + delay))
    centre = torch.tensor(CENTRE, dtype=torch.float64)
    expected = (at_thermal[:, :3, :3] @ centre[:, None])[..., 0] + at_thermal[:, :3, 3]
    assert torch.allclose(moved.origins.double(), expected, atol=1e-5)
    local = (at_rgb[:, :3, :3].transpose(-1, -2) @ rays.directions[:32].double()[..., None])[..., 0]
    assert torch.allclose(moved.directions.double(), (at_thermal[:, :3, :3] @ local[..., None])[..., 0], atol=1e-5)
    # the test could tell: at the RGB frames' times the centre is elsewhere (the rig moves 5 cm in 50 ms)
    assert (expected - ((at_rgb[:, :3, :3] @ centre[:, None])[..., 0] + at_rgb[:, :3, 3])).norm(dim=-1).min() > 0.04


@pytest.mark.parametrize("case", ["rays off", "no thermal camera", "no trajectory"])
def test_without_the_thermal_camera_the_thermal_terms_stay_on_the_rgb_rays(case: str) -> None:
    camera = {"camera_centre": torch.tensor(CENTRE, dtype=torch.float64), "plane_depth": math.inf}
    metadata = _metadata() if case == "no thermal camera" else _metadata(**camera)
    if case == "no trajectory":
        del metadata["trajectory"]
    model = _model(metadata, thermal_rays_per_batch=0 if case == "rays off" else 32)
    torch.manual_seed(3)
    outputs = model(_rays())
    assert not any(k.startswith(PREFIX) for k in outputs)
    batch = _batch()
    terms = model.get_metrics_dict(outputs, batch)
    assert torch.allclose(terms["thermal_loss"], losses.thermal_loss(outputs["thermal"], batch["thermal"]))


def test_evaluation_renders_no_thermal_view() -> None:
    camera = {"camera_centre": torch.tensor(CENTRE, dtype=torch.float64), "plane_depth": math.inf}
    model = _model(_metadata(**camera), thermal_rays_per_batch=32)
    model.eval()
    with torch.no_grad():
        assert not any(k.startswith(PREFIX) for k in model(_rays()))


def test_the_held_out_thermal_metrics_render_the_thermal_cameras_view() -> None:
    """At a plane at infinity the thermal camera's view of a held-out camera is that camera moved to the thermal
    camera's centre: the thermal outputs the metrics read are that camera's render; the RGB stays the camera's own."""
    from nerfstudio.cameras.cameras import Cameras

    camera_centre = torch.tensor(CENTRE, dtype=torch.float64)
    model = _model(_metadata(camera_centre=camera_centre, plane_depth=math.inf), thermal_rays_per_batch=32)
    model.eval()
    torch.manual_seed(4)
    for volume in model.field.volumes().values():  # a field that varies within a few cm, as trained ones do
        volume.plane_table.data.normal_(0.0, 2.0)
        volume.line_table.data.normal_(0.0, 2.0)
    c2w = torch.from_numpy(_trajectory().poses_at(np.array([0.1]))).float()

    def camera(pose: torch.Tensor) -> Cameras:
        return Cameras(camera_to_worlds=pose, fx=12.0, fy=12.0, cx=8.0, cy=6.0, width=16, height=12)

    moved = c2w.clone()
    moved[0, :3, 3] += c2w[0, :3, :3] @ camera_centre.float()
    with torch.no_grad():
        from_thermal = model.get_outputs_for_camera(camera(moved))
        own = model.get_outputs_for_camera(camera(c2w))
        assert model.thermal_view is not None
        seen = model.thermal_view.eval_outputs(model.get_outputs_for_camera_ray_bundle, camera(c2w), own)
    assert torch.allclose(seen["thermal_camera"], from_thermal["thermal_camera"], atol=1e-5)
    assert torch.allclose(seen["temperature"], from_thermal["temperature"], atol=1e-4)
    assert not torch.allclose(own["thermal_camera"], from_thermal["thermal_camera"], atol=1e-3)  # the test can tell
    assert torch.equal(seen["rgb"], own["rgb"])
    batch = {"image": torch.rand(12, 16, 3), "thermal": from_thermal["thermal_camera"].clone(),
             "temperature": from_thermal["temperature"].clone()}  # fmt: skip
    model.eval_camera = camera(c2w)
    metrics, _ = model.get_image_metrics_and_images(own, batch)
    assert metrics["thermal_camera_psnr"] > 60.0 and metrics["temperature_mae"] < 1e-3


def test_fruit_masks_of_the_thermal_camera_are_supervised_along_its_rays() -> None:
    """A fruit mask made on the thermal frame (the thermal camera's view, a baseline from the RGB camera's) trains
    the fruit head on the thermal camera's rays of the batch's first rays, and not on the RGB rays; an RGB mask on
    the RGB rays. Without the thermal camera's rays the plan says the masks land a baseline off."""
    from agrinerf_ns.model.fruit_head import fruit_loss

    camera = {"camera_centre": torch.tensor(CENTRE, dtype=torch.float64), "plane_depth": math.inf}
    metadata = {**_metadata(**camera), "fruit_mask_filenames": ["m.png"] * 4, "fruit_mask_thermal": [True] * 4}
    model = _model(metadata, thermal_rays_per_batch=32)
    assert model.plan.fruit_thermal_view and "fruit_loss" in model.plan.terms
    rays, n = _rays(), 48
    gen = torch.Generator().manual_seed(5)
    fruit = (torch.rand(n, 1, generator=gen) > 0.5).float()
    batch = {**_batch(), "fruit": fruit, "fruit_known": torch.ones(n, 1), "fruit_thermal": torch.ones(n, 1)}
    torch.manual_seed(3)
    outputs = model(rays)
    assert outputs[PREFIX + "fruit"].shape == (32, 1) and outputs["fruit"].shape == (n, 1)
    terms = model.get_metrics_dict(outputs, batch)
    assert torch.allclose(terms["fruit_loss"], fruit_loss(outputs[PREFIX + "fruit"], fruit[:32], torch.ones(32, 1)))
    rgb_masks = {**batch, "fruit_thermal": torch.zeros(n, 1)}
    assert torch.allclose(model.get_metrics_dict(outputs, rgb_masks)["fruit_loss"],
                          fruit_loss(outputs["fruit"], fruit, torch.ones(n, 1)))  # fmt: skip
    terms["fruit_loss"].backward()
    assert model.fruit_head is not None and any(p.grad is not None for p in model.fruit_head.parameters())
    blind = _model(metadata, thermal_rays_per_batch=0)
    assert not blind.plan.fruit_thermal_view and any("thermal camera's view" in n for n in blind.plan.notes)
