"""Readers of the raw capture: timestamps, calibration chain, thermal frames, chunked event streams."""

from pathlib import Path

import numpy as np
import pytest
import tifffile
import yaml
from helpers.process_raw_fixture import DATA, make_raw_capture, rig, write_events

from agrinerf_ns.process import readers
from agrinerf_ns.process.readers import RawInputError
from agrinerf_ns.trajectory import TrajectoryError, read_tum


def test_calibration_chain_maps_rgb_into_each_camera(tmp_path: Path):
    raw = make_raw_capture(tmp_path / "raw", n=3)
    calib = readers.read_calibration(raw / "calib.yaml")
    T = rig()
    assert calib.rgb.name == "cam0" and calib.thermal.name == "cam1" and calib.event.name == "cam2"
    np.testing.assert_allclose(calib.thermal.T_cam_rgb, T["thermal"], atol=1e-12)
    # cam2's T_cn_cnm1 is relative to cam1; the chain must recover T_event_rgb
    np.testing.assert_allclose(calib.event.T_cam_rgb, T["event"], atol=1e-12)
    assert calib.thermal.width == 40 and calib.thermal.height == 32
    np.testing.assert_allclose(calib.thermal.dist, [-0.15, 0.03, 0.002, -0.002])


def test_timestamps_and_frames(tmp_path: Path):
    raw = make_raw_capture(tmp_path / "raw", n=4, with_events=False)
    rgb = readers.read_timestamps(raw / "rgb")
    assert len(rgb) == 4 and np.allclose(np.diff(rgb.times), 0.1)
    img = readers.read_rgb(rgb.paths[0])
    assert img.shape == (48, 64, 3) and img.dtype == np.uint8
    th = readers.read_thermal(readers.read_timestamps(raw / "thermal").paths[0], (32, 40))
    assert th.dtype == np.uint16 and th.shape == (32, 40)


def test_real_fieldscale_frames_read_by_content_and_tiff(tmp_path: Path):
    # the Fieldscale files are PNG-encoded despite their .tiff name: decoded by content
    frame = readers.read_thermal(DATA / "0000.tiff")
    assert frame.dtype == np.uint16 and frame.shape == (512, 640) and frame.max() > 5000
    real_tiff = tmp_path / "frame.tif"
    tifffile.imwrite(real_tiff, frame)
    np.testing.assert_array_equal(readers.read_thermal(real_tiff), frame)


@pytest.mark.parametrize("fmt", ["h5", "npz", "txt"])
def test_event_formats_agree_and_stream_in_chunks(tmp_path: Path, fmt: str):
    rng = np.random.default_rng(1)
    n = 2503
    t = np.sort(rng.integers(0, 2_000_000, n)).astype(np.int64)
    x = rng.integers(0, 56, n).astype(np.uint16)
    y = rng.integers(0, 42, n).astype(np.uint16)
    p = rng.integers(0, 2, n).astype(np.uint8)
    path = write_events(tmp_path, x, y, t, p, fmt)
    assert readers.count_events(path) == n
    chunks = list(readers.iter_event_chunks(path, chunk_size=500, sensor_wh=(56, 42)))
    assert [len(c) for c in chunks] == [500] * 5 + [3]
    cat = {k: np.concatenate([getattr(c, k) for c in chunks]) for k in "xytp"}
    np.testing.assert_array_equal(cat["x"], x)
    np.testing.assert_array_equal(cat["y"], y)
    np.testing.assert_array_equal(cat["p"], p)
    np.testing.assert_array_equal(cat["t"], t)  # text stores seconds with 6 decimals: exact microseconds


def test_unsorted_across_chunk_boundary_is_caught(tmp_path: Path):
    t = np.array([0, 10, 20, 30, 25, 40], np.int64)
    z = np.zeros(6, np.uint16)
    path = write_events(tmp_path, z, z, t, z.astype(np.uint8), "h5")
    with pytest.raises(RawInputError, match=r"events.h5.*not sorted at event 4"):
        list(readers.iter_event_chunks(path, chunk_size=4))


def test_calibration_missing_keys(tmp_path: Path):
    raw = make_raw_capture(tmp_path / "raw", n=2, with_events=False)
    doc = yaml.safe_load((raw / "calib.yaml").read_text())
    del doc["cam1"]["T_cn_cnm1"]
    bad = tmp_path / "calib.yaml"
    bad.write_text(yaml.safe_dump(doc))
    with pytest.raises(RawInputError, match=r"calib.yaml: cam1 lacks T_cn_cnm1"):
        readers.read_calibration(bad)


def test_tum_reader_quaternion_convention(tmp_path: Path):
    # 90 degrees about z: (qx, qy, qz, qw) = (0, 0, sin45, cos45)
    s = np.sqrt(0.5)
    f = tmp_path / "odometry.txt"
    f.write_text(f"0.0 1 2 3 0 0 {s} {s}\n")
    t, c2w = read_tum(f)
    np.testing.assert_allclose(c2w[0, :3, :3], [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-12)
    np.testing.assert_allclose(c2w[0, :3, 3], [1, 2, 3])


@pytest.mark.parametrize(
    ("row", "message"),
    [
        ("2.0 1 2 3 0 0 0 NaN", r":4: value not finite \(qw\)"),
        ("inf 1 2 3 0 0 0 1", r":4: value not finite \(t\)"),
        ("2.0 1 2 3 0 0 0 0", r":4: zero quaternion"),
    ],
)
def test_tum_reader_names_the_file_line_of_a_bad_row(tmp_path: Path, row: str, message: str):
    # the line number counts the comment and the blank line too: it is the file's, not the row's index
    f = tmp_path / "odometry.txt"
    f.write_text(f"# t tx ty tz qx qy qz qw\n0.0 0 0 0 0 0 0 1\n\n{row}\n")
    with pytest.raises(TrajectoryError, match=rf"odometry.txt{message}"):
        read_tum(f)
