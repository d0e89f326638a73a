"""process_capture end to end on the hand-made capture (--poses given): layout, metadata, stock Nerfstudio
dataparser and the plugin's dataparser, atomic output, raw folder untouched."""

import hashlib
import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from helpers.process_raw_fixture import make_raw_capture
from nerfstudio.data.dataparsers.nerfstudio_dataparser import NerfstudioDataParserConfig
from nerfstudio.data.datasets.base_dataset import InputDataset

from agrinerf_ns.process import ProcessConfig, process_capture
from agrinerf_ns.process.cli import ProcessArgs, main
from agrinerf_ns.process.dataset_writer import OutputExistsError


def _tree_hash(root: Path) -> str:
    h = hashlib.sha256()
    for p in sorted(root.rglob("*")):
        h.update(str(p.relative_to(root)).encode())
        if p.is_file():
            h.update(p.read_bytes())
    return h.hexdigest()


def _config(**kw) -> ProcessConfig:
    return ProcessConfig(poses="given", show_progress=False, **kw)


@pytest.fixture(scope="module")
def processed(tmp_path_factory):
    root = tmp_path_factory.mktemp("cap")
    raw = make_raw_capture(root / "raw", n=10)
    before = _tree_hash(raw)
    out = process_capture(raw, root / "orchard", _config())
    return raw, out, before


def test_layout_and_metadata(processed):
    raw, out, before = processed
    assert _tree_hash(raw) == before  # raw folder never written to
    assert not list(out.parent.glob(".orchard.tmp-*"))
    meta = json.loads((out / "transforms.json").read_text())
    assert meta["agrinerf"]["modalities"] == ["rgb", "thermal", "events"]
    assert meta["agrinerf"]["poses"]["source"] == "given" and meta["agrinerf"]["poses"]["dropped_frames"] == []
    assert meta["agrinerf"]["events"]["representation"] == "signed"
    assert meta["agrinerf"]["thermal_rescale"]["method"] == "fieldscale"
    assert meta["w"] == 64 and meta["h"] == 48 and meta["cx"] == 32.0
    assert len(meta["frames"]) == 10
    assert meta["val_filenames"] == ["images/000004.png"] and len(meta["train_filenames"]) == 9
    f = meta["frames"][3]
    for key in ("file_path", "thermal_file_path", "thermal_mask_path", "event_file_path", "event_mask_path"):
        img = cv2.imread(str(out / f[key]), cv2.IMREAD_UNCHANGED)
        assert img.shape[:2] == (48, 64) and img.dtype == np.uint8, key
    th = cv2.imread(str(out / f["thermal_file_path"]), cv2.IMREAD_UNCHANGED)
    assert th.ndim == 2
    sums = np.load(out / f["event_sums_path"])
    assert sums["pos"].shape == (48, 64) and sums["t_end"] - sums["t_start"] == pytest.approx(0.1)
    ev = cv2.imread(str(out / f["event_file_path"]), cv2.IMREAD_UNCHANGED)
    no_events = (sums["pos"] == 0) & (sums["neg"] == 0) & sums["mask"]
    assert np.all(ev[no_events] == 128)  # 0.5 = no change
    assert np.all(ev[sums["pos"] > sums["neg"]] > 128)
    # poses: OpenCV c2w of odometry, converted to OpenGL (y, z camera axes flipped)
    M = np.array(meta["frames"][2]["transform_matrix"])
    np.testing.assert_allclose(M[:3, 3], [0.1, 0, 0], atol=1e-9)
    np.testing.assert_allclose(M[:3, :3], np.diag([1.0, -1.0, -1.0]), atol=1e-9)


@pytest.mark.parametrize("json_name", ["transforms.json", "transforms_thermal.json"])
def test_stock_nerfstudio_dataparser_reads_both_files(processed, json_name):
    _, out, _ = processed
    data = out if json_name == "transforms.json" else out / json_name
    parser = NerfstudioDataParserConfig(data=data).setup()
    train = parser.get_dataparser_outputs("train")
    val = parser.get_dataparser_outputs("val")
    assert len(train.image_filenames) == 9 and len(val.image_filenames) == 1
    assert not set(train.image_filenames) & set(val.image_filenames)
    item = InputDataset(train)[0]
    assert item["image"].shape == (48, 64, 3)  # single-channel thermal PNG broadcast to 3 channels
    if json_name == "transforms_thermal.json":
        assert "mask" in item and item["mask"].float().mean() > 0.8
        assert "thermal" in str(train.image_filenames[0])


def test_plugin_dataparser_reads_dataset(processed):
    _, out, _ = processed
    from agrinerf_ns.dataparsers.agrinerf_dataparser import AgriNeRFDataParserConfig

    outputs = AgriNeRFDataParserConfig(data=out).setup().get_dataparser_outputs("train")
    assert len(outputs.metadata["thermal_filenames"]) == 9
    assert len(outputs.metadata["event_filenames"]) == 9


def test_existing_output_needs_overwrite_and_is_replaced_atomically(tmp_path: Path):
    raw = make_raw_capture(tmp_path / "raw", n=4, with_events=False)
    out = tmp_path / "ds"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    with pytest.raises(OutputExistsError, match="--overwrite"):
        process_capture(raw, out, _config())
    assert (out / "keep.txt").read_text() == "mine"
    process_capture(raw, out, _config(overwrite=True))
    assert not (out / "keep.txt").exists() and (out / "transforms.json").is_file()
    meta = json.loads((out / "transforms.json").read_text())
    assert meta["agrinerf"]["modalities"] == ["rgb", "thermal"]  # no events: allowed, recorded
    assert "event_file_path" not in meta["frames"][0]


def test_rgb_only_capture_and_cli(tmp_path: Path):
    raw = make_raw_capture(tmp_path / "raw", n=4, with_events=False, with_thermal=False)
    out = main(ProcessArgs(raw=raw, out=tmp_path / "ds", config=_config()))
    meta = json.loads((out / "transforms.json").read_text())
    assert meta["agrinerf"]["modalities"] == ["rgb"]
    assert not (out / "transforms_thermal.json").exists()


def test_thermal_at_a_different_rate_pairs_by_time_and_drops_unpaired(tmp_path: Path):
    # thermal clock 0.3 frame intervals late: still paired within half an interval
    raw = make_raw_capture(tmp_path / "raw", n=6, with_events=False, thermal_offset_s=0.03)
    meta = json.loads((process_capture(raw, tmp_path / "a", _config()) / "transforms.json").read_text())
    assert len(meta["frames"]) == 6
    # with a tighter tolerance nothing pairs -> clear error
    with pytest.raises(ValueError, match="do not overlap"):
        process_capture(raw, tmp_path / "b", _config(max_time_offset_s=0.01))
    assert not (tmp_path / "b").exists()


def test_frame_without_pose_is_dropped_from_every_modality(tmp_path: Path):
    raw = make_raw_capture(tmp_path / "raw", n=6)
    odo = raw / "odometry.txt"
    lines = odo.read_text().splitlines()
    odo.write_text("\n".join(lines[:2] + lines[3:]) + "\n")  # frame 2 has no pose
    out = process_capture(raw, tmp_path / "ds", _config())
    meta = json.loads((out / "transforms.json").read_text())
    assert [f["file_path"] for f in meta["frames"]] == [f"images/{i:06d}.png" for i in (0, 1, 3, 4, 5)]
    assert meta["agrinerf"]["poses"]["dropped_frames"] == [{"file": "rgb/000002.png", "reason": "no pose"}]
    for sub, ext in (
        ("images", "png"),
        ("thermal", "png"),
        ("thermal_masks", "png"),
        ("events", "png"),
        ("events", "npz"),
        ("event_masks", "png"),
    ):
        assert not (out / sub / f"000002.{ext}").exists(), sub
    th = json.loads((out / "transforms_thermal.json").read_text())
    assert len(th["frames"]) == 5 and all(n in [f["file_path"] for f in th["frames"]] for n in th["train_filenames"])


def test_cli_reports_bad_input_and_exits_2(tmp_path: Path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(ProcessArgs(raw=tmp_path / "missing", out=tmp_path / "ds", config=_config()))
    assert exc.value.code == 2
    assert f"{tmp_path / 'missing'}: raw capture folder does not exist\n" in capsys.readouterr().err  # one line


def test_rgb_and_events_without_thermal(tmp_path: Path):
    raw = make_raw_capture(tmp_path / "raw", n=4, with_thermal=False, event_format="npz")
    out = process_capture(raw, tmp_path / "ds", _config())
    meta = json.loads((out / "transforms.json").read_text())
    assert meta["agrinerf"]["modalities"] == ["rgb", "events"]
    assert meta["agrinerf"]["calibration"]["event"]["name"] == "cam1"
    assert all("event_file_path" in f and "thermal_file_path" not in f for f in meta["frames"])
    assert not (out / "transforms_thermal.json").exists()
