"""The tri-modal dataparser and dataset on a real processed scene: agrinerf-synth -> agrinerf-process -> batches."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from helpers.dataset_fixtures import assert_batch_matches_dataset
from PIL import Image

from agrinerf_ns.dataparsers.agrinerf_dataparser import AgriNeRFDataParserConfig
from agrinerf_ns.dataparsers.agrinerf_dataset import agrinerf_datamanager_config
from agrinerf_ns.process import ProcessConfig, process_capture
from agrinerf_ns.synth import SynthConfig, generate_capture

EXTRA = ("thermal", "thermal_mask", "event", "event_mask")


@pytest.fixture(scope="module")
def processed_scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("processed_scene")
    raw = generate_capture(SynthConfig.tiny(seed=1), root / "raw")
    return process_capture(raw, root / "orchard", ProcessConfig(poses="given", show_progress=False))


def test_processed_scene_batches(processed_scene: Path) -> None:
    meta = json.loads((processed_scene / "transforms.json").read_text())
    torch.manual_seed(0)
    datamanager = agrinerf_datamanager_config(
        dataparser=AgriNeRFDataParserConfig(data=processed_scene), train_num_rays_per_batch=256
    ).setup(device="cpu")
    train, val = datamanager.train_dataset, datamanager.eval_dataset
    assert train.metadata["modalities"] == ("rgb", "thermal", "events")
    # the split is the one the processed dataset lists (as for `ns-train nerfacto` on the same folder)
    assert [f"images/{p.name}" for p in train.image_filenames] == meta["train_filenames"]
    assert [f"images/{p.name}" for p in val.image_filenames] == meta["val_filenames"]

    _, batch = datamanager.next_train(0)
    counts = ("event_on", "event_off")  # the event loss's ON/OFF counts per pixel of the frame's window
    temperature = ("temperature", "temperature_mask")  # the synthetic thermal camera is radiometric
    assert set(batch) == {"image", "indices", *EXTRA, *counts, *temperature}
    assert_batch_matches_dataset(batch, train, ("image", *EXTRA, *counts))
    for key in counts:
        assert batch[key].shape == (256, 1) and batch[key].min() >= 0 and torch.equal(batch[key], batch[key].round())
    assert float((batch["event_on"] + batch["event_off"]).sum()) > 0  # the scene moved: some pixels fired
    for key in EXTRA:
        assert batch[key].shape == (256, 1) and 0.0 <= batch[key].min() and batch[key].max() <= 1.0
    for key in ("thermal_mask", "event_mask"):
        assert set(torch.unique(batch[key]).tolist()) <= {0.0, 1.0}

    data = train[0]
    name = train.image_filenames[0].name
    thermal_png = np.asarray(Image.open(processed_scene / "thermal" / name), dtype=np.float32) / 255.0
    assert torch.equal(data["thermal"][..., 0], torch.from_numpy(thermal_png))
    assert data["thermal_mask"].mean() > 0.5  # the thermal camera sees most of the RGB view
    assert meta["agrinerf"]["events"]["representation"] == "signed"  # 0.5 = no change
    valid_events = data["event"][data["event_mask"] > 0]
    assert abs(valid_events.median().item() - 128 / 255) < 1e-6  # most valid pixels saw no change

    _, image_batch = datamanager.next_eval_image(0)
    for key in EXTRA:
        assert image_batch[key].shape == (meta["h"], meta["w"], 1)
