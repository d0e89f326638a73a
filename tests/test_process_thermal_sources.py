"""Thermal as real rigs give it: FLIR radiometric JPEGs (raw counts + Planck constants, read with flyr) as thermal
frames, and 16-bit mono16 sensor_msgs/Image topics (a Boson driver's raw output, either byte order) through the bag
path. The FLIR files are written here in the FFF-in-APP1 layout FLIR cameras use (exiftool's FLIR tag docs)."""

import json
import struct
from pathlib import Path

import cv2
import numpy as np
import pytest
from helpers.process_raw_fixture import make_raw_capture

from agrinerf_ns.process import ProcessConfig, process_capture, readers
from agrinerf_ns.process.readers import RawInputError

META = {
    "emissivity": 1.0, "object_distance": 0.0, "reflected_apparent_temperature": 293.15,
    "atmospheric_temperature": 293.15, "ir_window_temperature": 293.15, "ir_window_transmission": 1.0,
    "relative_humidity": 0.0, "planck_r1": 17096.453, "planck_b": 1428.0, "planck_f": 1.0,
    "atmospheric_trans_alpha1": 0.006569, "atmospheric_trans_alpha2": 0.01262, "atmospheric_trans_beta1": -0.002276,
    "atmospheric_trans_beta2": -0.00667, "atmospheric_trans_x": 1.9, "planck_o": -6863, "planck_r2": 0.03924,
}  # fmt: skip
CAMERA_INFO_OFFSETS = {
    "emissivity": 32, "object_distance": 36, "reflected_apparent_temperature": 40, "atmospheric_temperature": 44,
    "ir_window_temperature": 48, "ir_window_transmission": 52, "relative_humidity": 60, "planck_r1": 88,
    "planck_b": 92, "planck_f": 96, "atmospheric_trans_alpha1": 112, "atmospheric_trans_alpha2": 116,
    "atmospheric_trans_beta1": 120, "atmospheric_trans_beta2": 124, "atmospheric_trans_x": 128, "planck_r2": 780,
}  # fmt: skip


def write_flir_jpeg(path: Path, counts: np.ndarray, meta=META, chunk: int = 60000) -> None:
    """A JPEG (grey preview) with an FFF container (raw-data + camera-info records) split over FLIR APP1 segments."""
    h, w = counts.shape
    raw = struct.pack("<HHH", 2, w, h).ljust(32, b"\0") + counts.astype("<u2").tobytes()
    info = bytearray(1024)
    for key, off in CAMERA_INFO_OFFSETS.items():
        info[off : off + 4] = struct.pack("<f", meta[key])
    info[776:780] = struct.pack("<i", int(meta["planck_o"]))
    records = [(1, bytes(raw)), (32, bytes(info))]
    # flyr reads directory entry k at 32 k from the FFF start (not from the directory offset); with the directory at
    # 64, entries 2 and 3 are where it looks: list 4 entries, the last two empty (type 0), which readers skip
    slots = len(records) + 2
    offset = 64 + 32 * slots
    directory, body = b"", b""
    for rtype, data in records:
        directory += struct.pack(">H", rtype) + b"\0" * 10 + struct.pack(">II", offset + len(body), len(data))
        directory += b"\0" * 12
        body += data
    directory += b"\0" * 32 * (slots - len(records))
    fff = b"FFF\0" + b"agrinerf-test".ljust(16, b"\0") + struct.pack(">III", 100, 64, slots) + b"\0" * 32
    fff += directory + body
    parts = [fff[i : i + chunk] for i in range(0, len(fff), chunk)]
    app1 = b"".join(
        b"\xff\xe1" + struct.pack(">H", len(p) + 10) + b"FLIR\0\x01" + bytes([k, len(parts) - 1]) + p
        for k, p in enumerate(parts)
    )
    preview = cv2.imencode(".jpg", (counts >> 8).astype(np.uint8))[1].tobytes()
    path.write_bytes(preview[:2] + app1 + preview[2:])


def _counts(h=24, w=32, seed=0):
    return np.random.default_rng(seed).integers(11000, 16000, (h, w)).astype(np.uint16)


def test_flir_jpeg_counts_and_temperature_map(tmp_path: Path):
    flyr = pytest.importorskip("flyr")
    from agrinerf_ns.process.flir import counts_to_kelvin, read_flir

    counts = _counts()
    path = tmp_path / "frame.jpg"
    write_flir_jpeg(path, counts, chunk=700)  # several APP1 segments
    got = read_flir(path)
    np.testing.assert_array_equal(got.counts, counts)
    np.testing.assert_array_equal(readers.read_thermal(path), counts)
    assert got.planck["planck_o"] == -6863 and got.planck["planck_r1"] == pytest.approx(17096.453)
    kelvin = counts_to_kelvin(counts, got.planck)
    assert 250 < kelvin.min() < kelvin.max() < 400
    # with emissivity 1 and no atmosphere flyr's full radiometric chain reduces to the same map
    np.testing.assert_allclose(flyr.unpack(str(path)).kelvin, kelvin, atol=1e-3)


def test_flir_jpeg_thermal_frames_run_through_agrinerf_process(tmp_path: Path):
    pytest.importorskip("flyr")
    raw = make_raw_capture(tmp_path / "raw", n=4, with_events=False)
    ref = process_capture(raw, tmp_path / "ref", ProcessConfig(poses="given", show_progress=False))
    lines = []
    for ln in (raw / "thermal" / "timestamps.txt").read_text().split("\n"):
        if ln.strip():
            name, t = ln.split()
            png = raw / "thermal" / name
            write_flir_jpeg(png.with_suffix(".jpg"), cv2.imread(str(png), cv2.IMREAD_UNCHANGED))
            png.unlink()
            lines.append(f"{Path(name).with_suffix('.jpg')} {t}")
    (raw / "thermal" / "timestamps.txt").write_text("\n".join(lines) + "\n")
    out = process_capture(raw, tmp_path / "ds", ProcessConfig(poses="given", show_progress=False))
    meta = json.loads((out / "transforms.json").read_text())["agrinerf"]
    assert meta["thermal_radiometric"]["planck_b"] == pytest.approx(1428.0)
    assert "planck_r1 / (planck_r2 * (counts + planck_o))" in meta["thermal_radiometric"]["counts_to_kelvin"]
    for f in sorted((ref / "thermal").glob("*.png")):  # same counts -> the same dataset frames
        np.testing.assert_array_equal(cv2.imread(str(f), -1), cv2.imread(str(out / "thermal" / f.name), -1))


def test_jpeg_without_flir_raw_data_is_refused(tmp_path: Path):
    pytest.importorskip("flyr")
    raw = make_raw_capture(tmp_path / "raw", n=3, with_events=False)
    plain = raw / "thermal" / "000001.jpg"
    cv2.imwrite(str(plain), np.full((32, 40), 128, np.uint8))
    with pytest.raises(RawInputError, match=r"000001\.jpg: no FLIR radiometric raw data"):
        readers.read_thermal(plain)
    ts = raw / "thermal" / "timestamps.txt"
    ts.write_text(ts.read_text().replace("000001.png", "000001.jpg"))
    with pytest.raises(RawInputError, match=r"000001\.jpg: no FLIR radiometric raw data"):
        process_capture(raw, tmp_path / "ds", ProcessConfig(poses="given", show_progress=False))
    assert not (tmp_path / "ds").exists()


@pytest.mark.parametrize("bigendian", [False, True])
def test_mono16_thermal_topic_keeps_the_raw_counts(bigendian: bool, tmp_path: Path):
    pytest.importorskip("rosbags")
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    from agrinerf_ns.process.rosbag import BagTopics, bag_to_raw

    raw = make_raw_capture(tmp_path / "raw", n=3, with_events=False)
    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    Image, Header, Time = T["sensor_msgs/msg/Image"], T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]
    counts = [_counts(32, 40, seed=i) | np.uint16(0x8001) for i in range(3)]  # both bytes non-trivial
    rgb = [readers.read_rgb(p) for p in readers.read_timestamps(raw / "rgb").paths]
    with Writer(tmp_path / "bag", version=9) as w:
        c_rgb = w.add_connection("/rgb/image_raw", "sensor_msgs/msg/Image", typestore=ts)
        c_th = w.add_connection("/boson/image_raw", "sensor_msgs/msg/Image", typestore=ts)
        for i in range(3):
            stamp = Time(sec=1, nanosec=i * 100_000_000)
            msg = Image(header=Header(stamp=stamp, frame_id="rgb"), height=48, width=64, encoding="rgb8",
                        is_bigendian=0, step=64 * 3, data=rgb[i].reshape(-1))  # fmt: skip
            w.write(c_rgb, 10 * i, ts.serialize_cdr(msg, "sensor_msgs/msg/Image"))
            data = np.frombuffer(counts[i].astype(">u2" if bigendian else "<u2").tobytes(), np.uint8)
            msg = Image(header=Header(stamp=stamp, frame_id="boson"), height=32, width=40, encoding="mono16",
                        is_bigendian=int(bigendian), step=80, data=data)  # fmt: skip
            w.write(c_th, 10 * i + 1, ts.serialize_cdr(msg, "sensor_msgs/msg/Image"))
    out = bag_to_raw(tmp_path / "bag", raw / "calib.yaml", tmp_path / "raw2",
                     BagTopics(thermal="/boson/image_raw", events=None))  # fmt: skip
    frames = readers.read_timestamps(out / "thermal")
    for i, p in enumerate(frames.paths):
        np.testing.assert_array_equal(readers.read_thermal(p), counts[i])
    np.testing.assert_allclose(frames.times, 1.0 + 0.1 * np.arange(3))
