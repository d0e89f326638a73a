"""The thermal frames' cold sky is kept out of the field (`agrinerf_ns/model/sky.py`): the mask, the term, and a real
training run through Nerfstudio's Trainer on a synthetic capture processed by `agrinerf-process`, whose sky rays
turn transparent with the term and stay opaque without it."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import pytest
import torch
from helpers.model_scene import tiny_trainer_config

from agrinerf_ns.model import sky
from agrinerf_ns.model.model_config import AgriNeRFModelConfig
from agrinerf_ns.process import ProcessConfig, process_capture
from agrinerf_ns.synth import SynthConfig, generate_capture


def _model(mean_c: float, min_c: float = -10.0, margin_c: float = 8.0, coefficient: float = 0.1) -> SimpleNamespace:
    config = AgriNeRFModelConfig(sky_temperature_margin_c=margin_c)
    config.loss_coefficients = {**config.loss_coefficients, "sky_loss": coefficient}
    stats = {"mean_c": mean_c, "std_c": 5.0, "min_c": min_c, "max_c": 30.0}
    return SimpleNamespace(config=config, temperature_stats=stats, has_temperature=True)


def test_the_mask_takes_valid_pixels_near_the_cold_end() -> None:
    model = _model(mean_c=18.0, min_c=-10.0)  # threshold -10 + 0.25 * 28 = -3
    temperature = torch.tensor([[-10.0], [-3.1], [-2.9], [5.0], [float("nan")], [-8.0]])
    valid = torch.tensor([[1.0], [1.0], [1.0], [1.0], [1.0], [0.0]])
    assert sky.sky_threshold_c(model) == pytest.approx(-3.0)
    assert sky.sky_mask(model, temperature, valid)[:, 0].tolist() == [True, True, False, False, False, False]
    assert sky.sky_mask(model, temperature, None)[:, 0].tolist() == [True, True, False, False, False, True]


def test_frames_whose_coldest_pixel_is_near_the_mean_have_no_sky() -> None:
    """A canopy-filled view without sky: the coldest pixels are fruit a few degrees under the leaves."""
    model = _model(mean_c=18.0, min_c=12.0)
    assert sky.sky_threshold_c(model) is None
    assert not bool(sky.sky_mask(model, torch.tensor([[12.0], [13.0]]), None).any())


def test_the_term_is_the_sky_rays_accumulation_plus_the_scene_rays_transparency() -> None:
    acc = torch.tensor([[1.0], [0.5], [0.25], [0.0], [0.6]], requires_grad=True)
    sky_rays = torch.tensor([[True], [True], [False], [False], [False]])
    scene_rays = torch.tensor([[False], [False], [False], [True], [True]])
    loss = sky.sky_loss(acc, sky_rays, scene_rays)
    assert float(loss) == pytest.approx(0.75 + 0.7)
    loss.backward()
    assert acc.grad is not None and acc.grad[:, 0].tolist() == pytest.approx([0.5, 0.5, 0.0, -0.5, -0.5])
    none = torch.zeros_like(sky_rays)
    assert float(sky.sky_loss(acc.detach(), none, none)) == 0.0


def test_scene_pixels_mirror_the_sky_threshold_at_the_warm_end() -> None:
    model = _model(mean_c=18.0, min_c=-10.0)  # sky below -3, scene from 18 - 7 = 11
    temperature = torch.tensor([[-5.0], [5.0], [10.9], [11.1], [25.0]])
    assert sky.sky_mask(model, temperature, None, scene=True)[:, 0].tolist() == [False, False, False, True, True]
    assert not bool(sky.sky_mask(_model(18.0, min_c=12.0), temperature, None, scene=True).any())


def test_only_a_model_with_temperatures_and_a_weight_uses_it() -> None:
    assert sky.uses_thermal_sky(_model(18.0))
    assert not sky.uses_thermal_sky(_model(18.0, coefficient=0.0))
    no_temperature = _model(18.0)
    no_temperature.has_temperature = False
    assert not sky.uses_thermal_sky(no_temperature)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    """A tiny synthetic orchard capture (its thermal camera radiometric, the sky in view), processed."""
    root = tmp_path_factory.mktemp("sky")
    raw = generate_capture(SynthConfig.tiny(lighting="bright", scene="orchard"), root / "raw")
    return process_capture(raw, root / "dataset", ProcessConfig(poses="given", show_progress=False))


def _accumulations(dataset: Path, root: Path, coefficient: float) -> tuple:
    """Train 60 steps with `sky_loss` at `coefficient`; the mean accumulation of the held-out pixels whose temperature
    is sky and of those whose temperature is the scene's, as the RGB camera renders them."""
    config = tiny_trainer_config(dataset, root / "outputs", max_num_iterations=60, rays=512)
    config.pipeline.model.loss_coefficients = {**config.pipeline.model.loss_coefficients, "sky_loss": coefficient}
    config.set_timestamp()
    torch.manual_seed(42)
    trainer = config.setup(local_rank=0, world_size=1)
    trainer.setup()
    model = trainer.pipeline.model
    assert model.has_temperature and (model.sky_field is not None) == (coefficient > 0)
    ray_bundle, batch = trainer.pipeline.datamanager.next_train(0)
    model.train()
    terms = model.get_metrics_dict(model(ray_bundle), batch)
    assert ("sky_loss" in terms) == (coefficient > 0)
    trainer.train()
    model.eval()
    sums = {"sky": [0.0, 0], "scene": [0.0, 0]}
    for camera, batch in trainer.pipeline.datamanager.fixed_indices_eval_dataloader:
        with torch.no_grad():
            acc = model.get_outputs_for_camera(camera)["accumulation"][..., 0]
        for name, total in sums.items():
            picked = sky.sky_mask(model, batch["temperature"], batch["temperature_mask"], scene=name == "scene")[..., 0]
            total[0] += float(acc[picked].sum())
            total[1] += int(picked.sum())
    assert sums["sky"][1] > 0, "the held-out views show no sky: the test scene does not test the term"
    metrics = trainer.pipeline.get_average_eval_image_metrics()  # what ns-eval reports: the mean over the views
    sky_acc, scene_acc = sums["sky"][0] / sums["sky"][1], sums["scene"][0] / sums["scene"][1]
    assert abs(metrics["sky_accumulation"] - sky_acc) < 0.25, (metrics["sky_accumulation"], sky_acc)
    return sky_acc, scene_acc


def test_training_with_the_term_makes_the_sky_transparent_and_keeps_the_scene(dataset: Path, tmp_path: Path) -> None:
    sky_without, scene_without = _accumulations(dataset, tmp_path / "off", 0.0)
    sky_with, scene_with = _accumulations(dataset, tmp_path / "on", 0.1)
    assert sky_without > 0.9, sky_without  # the far shell stops a sky ray in a contracted field
    assert sky_with < 0.5 and sky_with < sky_without - 0.4, (sky_with, sky_without)
    assert scene_with > 0.95 and scene_without > 0.95, (scene_with, scene_without)
