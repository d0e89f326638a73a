"""AgriNeRF dataparser on tiny tri-modal datasets written to tmp_path (tests/dataset_fixtures.py)."""

from __future__ import annotations

from importlib.metadata import entry_points
from pathlib import Path
from typing import Optional

import numpy as np
import pytest
import torch
from helpers.dataset_fixtures import edit_transforms, write_tridata
from nerfstudio.data.dataparsers.nerfstudio_dataparser import NerfstudioDataParserConfig
from nerfstudio.plugins.registry_dataparser import DataParserSpecification
from PIL import Image

from agrinerf_ns.dataparsers.agrinerf_dataparser import AgriNeRFDataError, AgriNeRFDataParserConfig

EXTRA_KEYS = ("thermal_filenames", "thermal_mask_filenames", "event_filenames", "event_mask_filenames")


def _outputs(root: Path, split: str = "train", **config):
    return AgriNeRFDataParserConfig(data=root, **config).setup().get_dataparser_outputs(split=split)


def test_all_modalities_metadata(tmp_path: Path) -> None:
    root = write_tridata(tmp_path)
    outputs = _outputs(root, train_split_fraction=0.75)
    assert outputs.metadata["modalities"] == ("rgb", "thermal", "events")
    assert outputs.metadata["agrinerf"]["events"]["window"] == 0.05
    folders = {
        "thermal_filenames": "thermal",
        "thermal_mask_filenames": "thermal_masks",
        "event_filenames": "events",
        "event_mask_filenames": "event_masks",
    }
    for key, folder in folders.items():
        paths = outputs.metadata[key]
        assert len(paths) == len(outputs.image_filenames) == 6
        # same frame, same order as image_filenames
        assert [p.name for p in paths] == [p.name for p in outputs.image_filenames]
        assert all(p == root / folder / p.name and p.is_file() for p in paths)


@pytest.mark.parametrize(
    "config",
    [{}, {"eval_mode": "interval", "eval_interval": 3}, {"train_split_fraction": 0.5}],
    ids=["default", "interval", "fraction"],
)
def test_split_matches_nerfstudio(tmp_path: Path, config: dict) -> None:
    """Same frames, order and poses per split as Nerfstudio's own parser (what `ns-train nerfacto` uses)."""
    root = write_tridata(tmp_path, num_frames=12)
    for split in ("train", "val"):
        ours = _outputs(root, split, **config)
        theirs = NerfstudioDataParserConfig(data=root, **config).setup().get_dataparser_outputs(split=split)
        assert ours.image_filenames == theirs.image_filenames
        assert torch.equal(ours.cameras.camera_to_worlds, theirs.cameras.camera_to_worlds)
        assert ours.dataparser_scale == theirs.dataparser_scale
        assert [p.name for p in ours.metadata["thermal_filenames"]] == [p.name for p in ours.image_filenames]
    train = set(_outputs(root, "train", **config).image_filenames)
    val = set(_outputs(root, "val", **config).image_filenames)
    assert train and val and not train & val


def test_explicit_split_lists(tmp_path: Path) -> None:
    """train_filenames / val_filenames in transforms.json decide the split, and the extra frames follow it."""
    root = write_tridata(tmp_path)
    val_names = ["images/frame_00001.png", "images/frame_00006.png"]

    def add_lists(meta: dict) -> None:
        names = [f["file_path"] for f in meta["frames"]]
        meta["train_filenames"] = [n for n in names if n not in val_names]
        meta["val_filenames"] = val_names
        meta["frames"] = meta["frames"][::-1]  # the parser sorts by file name

    edit_transforms(root, add_lists)
    val = _outputs(root, "val")
    assert [p.name for p in val.image_filenames] == ["frame_00001.png", "frame_00006.png"]
    assert [p.name for p in val.metadata["event_filenames"]] == ["frame_00001.png", "frame_00006.png"]
    train = _outputs(root, "train")
    assert [p.name for p in train.metadata["thermal_mask_filenames"]] == [p.name for p in train.image_filenames]
    assert len(train.image_filenames) == 6


def test_rgb_only_has_no_extra_keys(tmp_path: Path) -> None:
    root = write_tridata(tmp_path, modalities=("rgb",))
    edit_transforms(root, lambda meta: meta.pop("agrinerf"))  # a plain Nerfstudio dataset parses too
    outputs = _outputs(root)
    assert outputs.metadata["modalities"] == ("rgb",)
    assert outputs.metadata["agrinerf"] == {}
    assert not set(EXTRA_KEYS) & set(outputs.metadata)


def test_rgb_thermal_without_masks(tmp_path: Path) -> None:
    root = write_tridata(tmp_path, modalities=("rgb", "thermal"), masks=False)
    outputs = _outputs(root)
    assert outputs.metadata["modalities"] == ("rgb", "thermal")
    assert "thermal_filenames" in outputs.metadata
    assert not {"thermal_mask_filenames", "event_filenames", "event_mask_filenames"} & set(outputs.metadata)


@pytest.mark.parametrize(
    ("modalities", "expected"),
    [
        (("rgb", "events"), ("rgb", "events")),
        (("thermal",), ("thermal",)),
        (("thermal", "events"), ("thermal", "events")),
    ],
)
def test_modalities_config_selects(tmp_path: Path, modalities: tuple, expected: tuple) -> None:
    root = write_tridata(tmp_path)
    outputs = _outputs(root, modalities=modalities)
    assert outputs.metadata["modalities"] == expected
    assert ("thermal_filenames" in outputs.metadata) == ("thermal" in expected)
    assert ("event_filenames" in outputs.metadata) == ("events" in expected)


def test_json_file_as_data(tmp_path: Path) -> None:
    root = write_tridata(tmp_path)
    outputs = _outputs(root / "transforms.json")
    assert outputs.metadata["thermal_filenames"][0] == root / "thermal" / "frame_00000.png"


def test_all_or_none_error_names_key_and_frames(tmp_path: Path) -> None:
    root = write_tridata(tmp_path)
    edit_transforms(root, lambda meta: meta["frames"][3].pop("event_file_path"))
    with pytest.raises(AgriNeRFDataError, match=r"'event_file_path' is given in 7 of 8 frames.*frame_00003"):
        _outputs(root)


def test_mask_without_frames_is_an_error(tmp_path: Path) -> None:
    root = write_tridata(tmp_path, modalities=("rgb", "thermal"))
    edit_transforms(root, lambda meta: [f.pop("thermal_file_path") for f in meta["frames"]])
    with pytest.raises(AgriNeRFDataError, match="'thermal_mask_path' but no 'thermal_file_path'"):
        _outputs(root)


def test_wrong_size_thermal_names_the_file(tmp_path: Path) -> None:
    root = write_tridata(tmp_path)
    bad = root / "thermal" / "frame_00002.png"
    Image.fromarray(np.zeros((24, 32), dtype=np.uint8)).save(bad)
    with pytest.raises(AgriNeRFDataError, match=r"frame_00002\.png: image is 32x24 but its RGB frame .* is 64x48"):
        _outputs(root)
    with pytest.raises(AgriNeRFDataError, match=str(bad)):
        _outputs(root)


def test_variable_resolution_with_thermal_is_an_error(tmp_path: Path) -> None:
    root = write_tridata(tmp_path, modalities=("rgb", "thermal"))

    def per_frame_sizes(meta: dict) -> None:
        for frame in meta["frames"]:
            frame["w"], frame["h"] = meta["w"], meta["h"]
        meta["frames"][1]["w"] = 32
        del meta["w"], meta["h"]

    edit_transforms(root, per_frame_sizes)
    narrow = np.zeros((48, 32), dtype=np.uint8)
    for folder in ("thermal", "thermal_masks"):
        Image.fromarray(narrow).save(root / folder / "frame_00001.png")
    Image.fromarray(np.zeros((48, 32, 3), dtype=np.uint8)).save(root / "images" / "frame_00001.png")
    with pytest.raises(AgriNeRFDataError, match="frames have different sizes"):
        _outputs(root, eval_mode="all", modalities=("rgb", "thermal"))
    # RGB alone keeps Nerfstudio's variable-resolution support
    assert _outputs(root, eval_mode="all", modalities=("rgb",)).metadata["modalities"] == ("rgb",)


def test_missing_file_names_the_file(tmp_path: Path) -> None:
    root = write_tridata(tmp_path)
    (root / "event_masks" / "frame_00004.png").unlink()
    with pytest.raises(AgriNeRFDataError, match=r"event_masks/frame_00004\.png: file named by 'event_mask_path'"):
        _outputs(root)


def test_registered_as_entry_point() -> None:
    found = [ep for ep in entry_points(group="nerfstudio.dataparser_configs") if ep.name == "agrinerf-data"]
    assert len(found) == 1
    spec = found[0].load()
    assert isinstance(spec, DataParserSpecification)
    assert isinstance(spec.config, AgriNeRFDataParserConfig)
    assert spec.config.modalities == ("rgb", "thermal", "events")


def _timestamp_frames(meta: dict, exposure_s: Optional[float] = None) -> None:
    for i, frame in enumerate(meta["frames"]):
        frame["timestamp"] = 100.0 + 0.1 * i
        if exposure_s is not None:
            frame["exposure_start"], frame["exposure_end"] = frame["timestamp"] - exposure_s, frame["timestamp"]


@pytest.mark.parametrize("applied", [False, True], ids=["plain", "applied_transform"])
def test_times_exposure_and_trajectory_metadata(tmp_path: Path, applied: bool) -> None:
    root = write_tridata(tmp_path)
    edit_transforms(root, lambda meta: _timestamp_frames(meta, 0.03))
    if applied:  # poses saved after a known change of world frame (as ns-process-data records it)
        edit_transforms(root, lambda meta: meta.update(applied_transform=[[0, 1, 0, 0.5], [1, 0, 0, 0], [0, 0, -1, 1]]))
    for split in ("train", "val"):
        outputs = _outputs(root, split, train_split_fraction=0.75)
        md = outputs.metadata
        t = md["times"].numpy()
        assert md["times"].dtype == torch.float64 and len(t) == len(outputs.image_filenames) > 0
        np.testing.assert_allclose(t, [100.0 + 0.1 * int(p.stem.split("_")[-1]) for p in outputs.image_filenames])
        np.testing.assert_allclose(md["exposure"].numpy(), np.stack([t - 0.03, t], -1))
        c2w = outputs.cameras.camera_to_worlds.double().numpy()
        np.testing.assert_allclose(md["trajectory"].poses_at(t), c2w, atol=1e-5)
    empty = _outputs(root, "val")  # Nerfstudio's default fraction leaves 8 frames no val frame
    assert len(empty.image_filenames) == 0 and empty.metadata["exposure"].shape == (0, 2)
    # between two frames: between their camera centres
    train = _outputs(root)
    t = train.metadata["times"].numpy()
    mid = train.metadata["trajectory"].poses_at(np.array([(t[0] + t[1]) / 2]))[0, :, 3]
    c = train.cameras.camera_to_worlds[:2, :, 3].double().numpy()
    assert np.linalg.norm(mid - c.mean(0)) < 0.05 * np.linalg.norm(c[1] - c[0])


def test_timing_without_exposures_or_timestamps(tmp_path: Path) -> None:
    root = write_tridata(tmp_path)
    assert not {"times", "exposure", "trajectory"} & set(_outputs(root).metadata)  # no timestamps: no timing keys
    edit_transforms(root, _timestamp_frames)
    md = _outputs(root).metadata
    np.testing.assert_array_equal(md["exposure"][:, 0], md["times"])  # unknown exposure: an instantaneous frame
    np.testing.assert_array_equal(md["exposure"][:, 1], md["times"])
    edit_transforms(root, lambda meta: meta["frames"][2].update(exposure_start=1.0, exposure_end=1.1))
    with pytest.raises(AgriNeRFDataError, match="'exposure_start'/'exposure_end' are given in 1 of 8 frames"):
        _outputs(root)
    edit_transforms(root, lambda meta: [meta["frames"][2].pop(k) for k in ("exposure_start", "exposure_end",
                                                                            "timestamp")])  # fmt: skip
    with pytest.raises(AgriNeRFDataError, match="'timestamp' is given in some frames only"):
        _outputs(root)


@pytest.mark.parametrize("scale", [1.0, 0.02])
def test_rgb_level_is_the_mean_value_of_the_splits_frames(tmp_path: Path, scale: float) -> None:
    root = write_tridata(tmp_path)
    for path in sorted((root / "images").iterdir()):  # darken the frames, as a camera at night records them
        array = np.asarray(Image.open(path).convert("RGB")).astype(np.float64) * scale
        Image.fromarray(array.round().astype(np.uint8)).save(path)
    outputs = _outputs(root)
    means = [np.asarray(Image.open(p).convert("RGB")).mean() / 255.0 for p in outputs.image_filenames]
    assert len(outputs.image_filenames) <= 8  # every frame is read: the level is their exact mean
    assert outputs.metadata["rgb_level"] == pytest.approx(float(np.mean(means)), rel=1e-9)
    assert (outputs.metadata["rgb_level"] < 0.04) is (scale < 0.1)


def test_dark_rgb_frames_are_scaled_to_the_target_level(tmp_path: Path) -> None:
    """``dark_rgb_target``: frames of 3 DN are scaled (both splits alike) so that their mean is the target, and clipped
    at 1; the raw level that decides the model's low-light routing is kept; lit frames and the default stay as they
    are."""
    from agrinerf_ns.dataparsers.agrinerf_dataset import AgriNeRFDataset

    dark = write_tridata(tmp_path / "dark", fill={"rgb": 3})
    plain = AgriNeRFDataset(_outputs(dark))
    assert plain.metadata["rgb_gain"] == 1.0 and float(plain[0]["image"].mean()) == pytest.approx(3 / 255)
    for split in ("train", "val"):
        outputs = _outputs(dark, split=split, dark_rgb_target=0.2, train_split_fraction=0.75)
        assert outputs.metadata["rgb_level"] == pytest.approx(3 / 255)  # the routing still sees a dark capture
        assert outputs.metadata["rgb_gain"] == pytest.approx(0.2 * 255 / 3)
        assert float(AgriNeRFDataset(outputs)[0]["image"].mean()) == pytest.approx(0.2, abs=1e-4)
    clipped = AgriNeRFDataset(_outputs(dark, dark_rgb_target=1.0))[0]["image"]
    assert float(clipped.max()) == 1.0
    lit = write_tridata(tmp_path / "lit", fill={"rgb": 120})
    assert _outputs(lit, dark_rgb_target=0.2).metadata["rgb_gain"] == 1.0
    with pytest.raises(ValueError, match="dark_rgb_target must be in"):
        _outputs(dark, dark_rgb_target=1.5)
