"""Bad raw input: a clear error naming the file and the problem, and no output (not even a temporary folder)."""

import json
from pathlib import Path

import h5py
import numpy as np
import pytest
import tyro
import yaml
from helpers.process_raw_fixture import make_raw_capture, write_events

from agrinerf_ns.process import ProcessConfig, RawInputError, process_capture
from agrinerf_ns.process.cli import ProcessArgs, main


def _run(raw: Path, out: Path):
    return process_capture(raw, out, ProcessConfig(poses="given", show_progress=False))


def _expect_error(raw: Path, tmp_path: Path, pattern: str):
    out = tmp_path / "out"
    with pytest.raises(RawInputError, match=pattern):
        _run(raw, out)
    assert not out.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".out.")]


@pytest.fixture()
def raw(tmp_path: Path) -> Path:
    return make_raw_capture(tmp_path / "raw", n=4)


def _events(raw: Path):
    with h5py.File(raw / "events" / "events.h5", "r") as f:
        return [f["events"][k][:] for k in "xytp"]


def _rewrite_events(raw: Path, x, y, t, p):
    (raw / "events" / "events.h5").unlink()
    write_events(raw / "events", x, y, t, p, "h5")


def test_missing_calibration_camera(raw, tmp_path):
    doc = yaml.safe_load((raw / "calib.yaml").read_text())
    del doc["cam2"]  # event camera gone, events/ still there
    (raw / "calib.yaml").write_text(yaml.safe_dump(doc))
    _expect_error(raw, tmp_path, r"calib.yaml: events in .*events.h5 but no camera with modality: event")


def test_missing_rgb_camera(raw, tmp_path):
    doc = yaml.safe_load((raw / "calib.yaml").read_text())
    doc = {"cam1": doc["cam1"]}
    (raw / "calib.yaml").write_text(yaml.safe_dump(doc))
    _expect_error(raw, tmp_path, r"calib.yaml: camera cam0 \(RGB\) missing")


def test_thermal_frame_of_wrong_size(raw, tmp_path):
    import cv2

    cv2.imwrite(str(raw / "thermal" / "000002.png"), np.zeros((30, 40), np.uint16))
    _expect_error(raw, tmp_path, r"thermal/000002.png: thermal frame is 40x30 .* calibration says 40x32")


def test_events_unsorted(raw, tmp_path):
    x, y, t, p = _events(raw)
    t[10], t[11] = t[11] + 5, t[10]
    _rewrite_events(raw, x, y, t, p)
    _expect_error(raw, tmp_path, r"events.h5: timestamps not sorted at event 11")


def test_events_negative_timestamp(raw, tmp_path):
    x, y, t, p = _events(raw)
    t[0] = -5
    _rewrite_events(raw, x, y, t, p)
    _expect_error(raw, tmp_path, r"events.h5: negative timestamp at event 0")


def test_event_outside_sensor(raw, tmp_path):
    x, y, t, p = _events(raw)
    x[7] = 56  # sensor is 56 wide
    _rewrite_events(raw, x, y, t, p)
    _expect_error(raw, tmp_path, r"events.h5: event 7 at \(x=56, y=\d+\) is outside the 56x42 sensor")


def test_empty_event_file_gives_dataset_without_events(raw, tmp_path):
    e = np.zeros(0, np.uint16)
    _rewrite_events(raw, e, e, np.zeros(0, np.int64), np.zeros(0, np.uint8))
    out = _run(raw, tmp_path / "out")
    meta = json.loads((out / "transforms.json").read_text())
    assert meta["agrinerf"]["modalities"] == ["rgb", "thermal"]
    assert any("events.h5: event file is empty" in w for w in meta["agrinerf"]["warnings"])
    assert not (out / "events").exists()


@pytest.mark.parametrize("sub", ["rgb", "thermal"])
def test_corrupt_png(raw, tmp_path, sub):
    path = raw / sub / "000001.png"
    path.write_bytes(path.read_bytes()[:40])
    _expect_error(raw, tmp_path, rf"{sub}/000001.png: cannot decode image")


def test_thermal_times_do_not_overlap(raw, tmp_path):
    ts = raw / "thermal" / "timestamps.txt"
    lines = [ln.split() for ln in ts.read_text().splitlines()]
    ts.write_text("".join(f"{a} {float(b) + 100:.6f}\n" for a, b in lines))
    _expect_error(raw, tmp_path, r"thermal/timestamps.txt: thermal times .* do not overlap the RGB times")


def test_event_times_do_not_overlap(raw, tmp_path):
    x, y, t, p = _events(raw)
    _rewrite_events(raw, x, y, t + 100_000_000, p)
    _expect_error(raw, tmp_path, r"events.h5: none of its \d+ events falls in a window .* do not overlap")


def test_odometry_does_not_overlap(raw, tmp_path):
    odo = raw / "odometry.txt"
    odo.write_text(
        "".join(f"{float(ln.split()[0]) + 50} {' '.join(ln.split()[1:])}\n" for ln in odo.read_text().splitlines())
    )
    _expect_error(raw, tmp_path, r"odometry.txt: no pose within .* timestamps do not overlap")


@pytest.mark.parametrize("value", ["nan", "inf", "-Infinity"])
def test_odometry_non_finite_value_is_refused_by_the_cli(raw, tmp_path, capsys, value):
    """A NaN / infinite odometry value stops ``agrinerf-process --poses given`` with the file and the 1-based line,
    instead of becoming a NaN pose in transforms.json; nothing is written and the raw folder is untouched."""
    odo = raw / "odometry.txt"
    lines = odo.read_text().splitlines()
    lines.insert(0, "# t tx ty tz qx qy qz qw")  # a comment line: the reported line number counts it
    parts = lines[3].split()
    parts[2] = value  # ty of the third pose, file line 4
    lines[3] = " ".join(parts)
    odo.write_text("\n".join(lines) + "\n")
    before = _snapshot(raw)
    out = tmp_path / "out"
    args = ["--raw", str(raw), "--out", str(out), "--poses", "given", "--no-show-progress"]
    with pytest.raises(SystemExit) as exit_info:
        main(tyro.cli(ProcessArgs, args=args))
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert f"{odo}:4: value not finite (ty)" in err
    assert not out.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".out.")]
    assert _snapshot(raw) == before
    with pytest.raises(RawInputError, match=r"odometry.txt:4: value not finite \(ty\)"):  # the library call too
        _run(raw, out)


def _snapshot(folder: Path) -> dict:
    """Every file under ``folder`` with its bytes and modification time."""
    return {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in sorted(folder.rglob("*")) if p.is_file()}


def test_missing_frame_file_and_bad_timestamp_line(raw, tmp_path):
    (raw / "rgb" / "000003.png").unlink()
    _expect_error(raw, tmp_path, r"rgb/timestamps.txt:4: frame file .*000003.png does not exist")


def test_output_inside_raw_is_refused(raw):
    with pytest.raises(ValueError, match="must not be inside the raw folder"):
        _run(raw, raw / "dataset")
    assert not (raw / "dataset").exists()


def test_negative_plane_depth_is_refused(raw, tmp_path):
    with pytest.raises(ValueError, match="plane depth must be positive"):
        process_capture(raw, tmp_path / "out", ProcessConfig(poses="given", plane_depth=-1.0, show_progress=False))
