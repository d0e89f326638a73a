"""Temperature in degrees C end to end (issue 17, item 4): the synthetic camera's radiometric calibration, the
processed linear temperature images against the truth, the dataset's `temperature` batch key, the model's
`temperature` output and `temperature_mae`, no temperature parameters without a calibration, and the 16-bit limits."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Dict

import cv2
import numpy as np
import pytest
import torch
import yaml
from helpers.model_scene import tiny_trainer_config
from PIL import Image
from scipy.ndimage import maximum_filter, minimum_filter

from agrinerf_ns.dataparsers.agrinerf_dataparser import AgriNeRFDataParserConfig
from agrinerf_ns.dataparsers.agrinerf_dataset import agrinerf_datamanager_config
from agrinerf_ns.images import write_png
from agrinerf_ns.process import ProcessConfig, align, process_capture, readers
from agrinerf_ns.process.radiometric import parse_calibration
from agrinerf_ns.synth import SynthConfig, generate_capture
from agrinerf_ns.synth.sensors import RADIOMETRIC_CALIBRATION, THERMAL_GAIN, THERMAL_OFFSET
from agrinerf_ns.temperature import decode_celsius, encode_celsius

PROCESS = ProcessConfig(poses="given", show_progress=False)


@pytest.fixture(scope="module")
def raw(tmp_path_factory) -> Path:
    return generate_capture(SynthConfig.tiny(lighting="dark"), tmp_path_factory.mktemp("temperature") / "raw")


@pytest.fixture(scope="module")
def dataset(raw: Path) -> Path:
    return process_capture(raw, raw.parent / "dataset", PROCESS)


def _variant(raw: Path, name: str, radiometric) -> Path:
    """A copy of the capture whose thermal camera has the calibration `radiometric` (None: none)."""
    copy = raw.parent / name
    shutil.copytree(raw, copy)
    calib = yaml.safe_load((copy / "calib.yaml").read_text())
    calib["cam1"].pop("radiometric")
    if radiometric is not None:
        calib["cam1"]["radiometric"] = radiometric
    (copy / "calib.yaml").write_text(yaml.safe_dump(calib, sort_keys=False))
    return copy


def test_counts_to_celsius_round_trip_on_the_synthetic_calibration(raw: Path) -> None:
    calib = readers.read_calibration(raw / "calib.yaml")
    assert calib.thermal is not None and calib.thermal.radiometric is not None
    assert calib.thermal.radiometric.params == {"counts_at_0c": 3500.0, "counts_per_kelvin": 100.0}
    assert calib.rgb.radiometric is None and calib.event is not None and calib.event.radiometric is None
    celsius = np.linspace(-30.0, 80.0, 1001)
    counts = np.round(THERMAL_OFFSET + THERMAL_GAIN * celsius)  # the sensor's map without fixed pattern and noise
    back = calib.thermal.radiometric.celsius(counts)
    assert np.abs(back - celsius).max() <= 0.5 / THERMAL_GAIN + 1e-9  # the counts' rounding, 0.005 K
    decoded, valid = decode_celsius(encode_celsius(back))
    assert valid.all() and np.abs(decoded - back).max() <= 0.005 + 1e-6  # the PNG's 0.01 K steps
    assert parse_calibration(RADIOMETRIC_CALIBRATION, raw / "calib.yaml", "cam1") == calib.thermal.radiometric


@pytest.mark.parametrize(
    "entry, message",
    [
        ({"model": "linear", "counts_at_0c": 3500}, "lacks 'counts_per_kelvin'"),
        ({"counts_at_0c": 3500, "counts_per_kelvin": 0}, "must not be 0"),
        ({"model": "cubic"}, "must be linear or planck"),
        ({"counts_at_0c": "warm", "counts_per_kelvin": 100}, "must be a number"),
    ],
)
def test_a_bad_calibration_is_refused_naming_the_file(tmp_path: Path, entry, message) -> None:
    with pytest.raises(readers.RawInputError, match=message) as err:
        parse_calibration(entry, tmp_path / "calib.yaml", "cam1")
    assert "calib.yaml: cam1.radiometric" in str(err.value)


def test_process_writes_temperatures_that_match_the_truth_where_the_thermal_camera_sees(raw: Path, dataset: Path):
    meta = json.loads((dataset / "transforms.json").read_text())
    block = meta["agrinerf"]
    assert block["thermal_radiometric"]["model"] == "linear" and block["thermal_radiometric"]["counts_at_0c"] == 3500
    assert block["calibration"]["thermal"]["radiometric"]["counts_per_kelvin"] == 100
    errors, seen = [], 0
    undistort = align.undistort_maps(readers.read_calibration(raw / "calib.yaml").rgb)
    assert undistort is not None
    for frame in meta["frames"]:
        png = np.asarray(Image.open(dataset / frame["thermal_temperature_path"]))
        assert png.dtype == np.uint16
        celsius, valid = decode_celsius(png)
        mask = np.asarray(Image.open(dataset / frame["thermal_mask_path"])) > 127
        assert np.array_equal(valid, mask)  # a value exactly where the thermal camera sees
        truth = np.load(raw / "truth" / "temperature" / Path(frame["file_path"]).with_suffix(".npy").name)
        assert truth.shape == celsius.shape and truth.dtype == np.float32
        truth = cv2.remap(truth, *undistort, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)  # as the RGB frames
        # away from edges (parallax of the warp at infinity, the half-resolution camera's optics blur)
        flat = (maximum_filter(truth, 7) - minimum_filter(truth, 7)) < 0.5
        errors.append((celsius - truth)[valid & flat])
        seen += int(valid.sum())
    error = np.concatenate(errors)
    assert error.size > 50
    # what is left is the camera's own error, which the calibration does not know: fixed pattern (per-pixel 0.2 K,
    # per-column 0.12 K, radial 0 to -0.8 K) and 0.06 K of noise
    assert abs(float(np.median(error))) < 1.0 and float(np.abs(error - np.median(error)).mean()) < 0.4, error
    stats = block["thermal_temperature"]
    assert stats["pixels"] == seen and stats["min_c"] <= stats["mean_c"] <= stats["max_c"] and stats["std_c"] > 0


def _datamanager(data: Path):
    return agrinerf_datamanager_config(
        dataparser=AgriNeRFDataParserConfig(data=data), train_num_rays_per_batch=256
    ).setup(device="cpu")


def test_batches_carry_the_temperature_in_degrees_c_with_the_thermal_mask(dataset: Path) -> None:
    torch.manual_seed(0)
    datamanager = _datamanager(dataset)
    train = datamanager.train_dataset
    stats = train.metadata["temperature_stats"]
    _, batch = datamanager.next_train(0)
    assert batch["temperature"].shape == (256, 1) and batch["temperature"].dtype == torch.float32
    assert set(torch.unique(batch["temperature_mask"]).tolist()) <= {0.0, 1.0}
    assert torch.equal(batch["temperature_mask"], batch["thermal_mask"])  # every pixel it sees has a value
    seen = batch["temperature"][batch["temperature_mask"] > 0]
    assert stats["min_c"] - 0.01 <= float(seen.min()) and float(seen.max()) <= stats["max_c"] + 0.01


def _trainer(data: Path, root: Path, steps: int):
    config = tiny_trainer_config(data, root / "outputs", max_num_iterations=steps, rays=256)
    config.set_timestamp()
    torch.manual_seed(42)
    trainer = config.setup(local_rank=0, world_size=1)
    trainer.setup()
    return trainer


def _temperature_parameters(model) -> Dict[str, torch.Size]:
    return {name: p.shape for name, p in model.named_parameters() if "temperature" in name}


def test_a_trained_model_renders_finite_temperatures_and_reports_the_mae(dataset: Path, tmp_path: Path) -> None:
    trainer = _trainer(dataset, tmp_path, steps=40)
    model = trainer.pipeline.model
    assert model.plan.has_temperature and _temperature_parameters(model)
    assert all(name.startswith("field.temperature_head.") for name in _temperature_parameters(model))
    fields = {id(p) for p in trainer.optimizers.parameters["fields"]}
    assert all(id(p) in fields for p in model.field.temperature_head.parameters())  # the optimiser trains it

    # its loss moves neither the density (scale 0 by default) nor is any other term pulling on its head
    ray_bundle, batch = trainer.pipeline.datamanager.next_train(0)
    model.train()
    outputs = model(ray_bundle)
    terms = model.get_metrics_dict(outputs, batch)
    model.zero_grad()
    terms["temperature_loss"].backward(retain_graph=True)
    density = model.field.density_encoding
    assert all(p.grad is None or float(p.grad.abs().max()) == 0.0 for p in density.parameters())
    assert float(model.field.temperature_head.mlp.layers[-1].weight.grad.abs().max()) > 0
    model.zero_grad()
    sum(v for k, v in terms.items() if k.startswith("reg_")).backward()
    assert all(p.grad is None or float(p.grad.abs().max()) == 0.0 for p in model.field.temperature_head.parameters())
    model.zero_grad()

    before = float(terms["temperature_loss"].detach())
    trainer.train()
    trainer.pipeline.eval()
    metrics = trainer.pipeline.get_average_eval_image_metrics()
    assert np.isfinite(metrics["temperature_mae"]) and metrics["temperature_mae"] > 0
    camera_ray_bundle, batch = next(iter(trainer.pipeline.datamanager.fixed_indices_eval_dataloader))
    outputs = model.get_outputs_for_camera(camera_ray_bundle)
    assert outputs["temperature"].shape[-1] == 1 and bool(torch.isfinite(outputs["temperature"]).all())
    rgba = model.get_rgba_image(outputs, "temperature")  # exports colour it over the dataset's range, not [0, 1] C
    assert rgba.shape[-1] == 4 and float(rgba[..., :3].std()) > 0.01
    # 40 steps from a random head: it has learnt the scale (the start is several std away)
    stats = model.temperature_stats
    assert metrics["temperature_mae"] < 1.5 * stats["std_c"], (metrics, stats, before)


def test_a_capture_without_calibration_gets_no_temperature_outputs_or_parameters(raw: Path, tmp_path: Path) -> None:
    data = process_capture(_variant(raw, "no_calibration", None), raw.parent / "no_calibration_ds", PROCESS)
    meta = json.loads((data / "transforms.json").read_text())
    assert not any("thermal_temperature_path" in f for f in meta["frames"])
    assert "thermal_temperature" not in meta["agrinerf"] and "thermal_radiometric" not in meta["agrinerf"]
    assert not (data / "thermal_temperature").exists() and all("thermal_file_path" in f for f in meta["frames"])
    trainer = _trainer(data, tmp_path, steps=3)
    model = trainer.pipeline.model
    assert "temperature_stats" not in trainer.pipeline.datamanager.train_dataset.metadata
    assert model.plan.use_thermal and not model.plan.has_temperature and model.field.temperature_head is None
    trainer.train()
    assert _temperature_parameters(model) == {}
    assert not any("temperature" in key for key in model.state_dict())
    model.eval()
    camera_ray_bundle, _ = next(iter(trainer.pipeline.datamanager.fixed_indices_eval_dataloader))
    assert "temperature" not in model.get_outputs_for_camera(camera_ray_bundle)


def test_frames_at_the_16_bit_limits_give_no_nan(raw: Path, tmp_path: Path) -> None:
    """Counts 0 and 65535 through a Planck calibration (where 0 counts has no temperature) and the linear one (where
    65535 counts lies beyond the PNG's 382 C): no NaN reaches the images, the batches or the loss."""
    planck = {"model": "planck", "planck_r1": 17096.453, "planck_r2": 0.046642166, "planck_b": 1428.0,
              "planck_f": 1.0, "planck_o": -342.0}  # fmt: skip
    for name, radiometric in (("planck", planck), ("linear", RADIOMETRIC_CALIBRATION)):
        capture = _variant(raw, f"limits_{name}", radiometric)
        frame = np.asarray(Image.open(capture / "thermal" / "000000.png")).copy()
        frame[: frame.shape[0] // 3] = 0
        frame[-frame.shape[0] // 3 :] = 65535
        write_png(capture / "thermal" / "000000.png", frame)
        data = process_capture(capture, tmp_path / name, PROCESS)
        meta = json.loads((data / "transforms.json").read_text())
        png = np.asarray(Image.open(data / meta["frames"][0]["thermal_temperature_path"]))
        celsius, valid = decode_celsius(png)
        assert np.isfinite(celsius).all() and valid.any()
        stats = meta["agrinerf"]["thermal_temperature"]
        assert all(np.isfinite(stats[k]) for k in ("mean_c", "std_c", "min_c", "max_c"))
        if name == "planck":  # counts 0 + O < 0: no temperature there
            assert not valid[: valid.shape[0] // 4].any()
        else:  # -35 C and the range's top (382.2 C)
            assert abs(stats["min_c"] + 35.0) < 0.01 and abs(stats["max_c"] - 382.2) < 0.01
        trainer = _trainer(data, tmp_path / f"run_{name}", steps=2)
        model = trainer.pipeline.model
        ray_bundle, batch = trainer.pipeline.datamanager.next_train(0)
        assert bool(torch.isfinite(batch["temperature"]).all())
        model.train()
        outputs = model(ray_bundle)
        loss = model.get_loss_dict(outputs, batch, model.get_metrics_dict(outputs, batch))["temperature_loss"]
        # the temperature term's output: along the thermal camera's rays where training renders them (thermal_view.py)
        temperature = outputs.get("thermal_view/temperature", outputs.get("temperature"))
        assert temperature is not None and bool(torch.isfinite(loss)) and bool(torch.isfinite(temperature).all())
