"""Optional ROS bag input: a ROS2 bag written with rosbags from the hand-made capture converts back to the same raw
capture, and processing either gives the same dataset."""

from pathlib import Path

import cv2
import h5py
import numpy as np
import pytest
from helpers.process_raw_fixture import make_raw_capture

from agrinerf_ns.process import ProcessConfig, process_capture, readers

rosbags = pytest.importorskip("rosbags")

EVENT_MSG = "uint16 x\nuint16 y\nbuiltin_interfaces/Time ts\nbool polarity\n"
EVENT_ARRAY_MSG = "std_msgs/Header header\nuint32 height\nuint32 width\ndvs_msgs/Event[] events\n"


def _write_bag(raw: Path, bag: Path) -> None:
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    ts.register(
        {
            **get_types_from_msg(EVENT_MSG, "dvs_msgs/msg/Event"),
            **get_types_from_msg(EVENT_ARRAY_MSG, "dvs_msgs/msg/EventArray"),
        }
    )
    T = ts.types
    Time, Header, Image = T["builtin_interfaces/msg/Time"], T["std_msgs/msg/Header"], T["sensor_msgs/msg/Image"]
    Event, EventArray = T["dvs_msgs/msg/Event"], T["dvs_msgs/msg/EventArray"]

    def stamp(t: float):
        sec = int(np.floor(t))
        return Time(sec=sec, nanosec=int(round((t - sec) * 1e9)))

    with Writer(bag, version=9) as w:
        conns = {
            "rgb": w.add_connection("/rgb/image_raw", "sensor_msgs/msg/Image", typestore=ts),
            "thermal": w.add_connection("/thermal/image_raw", "sensor_msgs/msg/Image", typestore=ts),
            "events": w.add_connection("/dvs/events", "dvs_msgs/msg/EventArray", typestore=ts),
        }
        msgs = []
        for kind, enc in (("rgb", "rgb8"), ("thermal", "mono16")):
            frames = readers.read_timestamps(raw / kind)
            for path, t in zip(frames.paths, frames.times, strict=True):
                img = readers.read_rgb(path) if kind == "rgb" else readers.read_thermal(path)
                step = img.shape[1] * (3 if kind == "rgb" else 2)
                msg = Image(
                    header=Header(stamp=stamp(t), frame_id=kind),
                    height=img.shape[0],
                    width=img.shape[1],
                    encoding=enc,
                    is_bigendian=0,
                    step=step,
                    data=np.frombuffer(img.astype("<u2").tobytes() if kind == "thermal" else img.tobytes(), np.uint8),
                )
                msgs.append((t, kind, msg, "sensor_msgs/msg/Image"))
        with h5py.File(raw / "events" / "events.h5", "r") as f:
            x, y, t_us, p = (f["events"][k][:] for k in "xytp")
        for s in range(0, len(t_us), 5000):  # packets of 5000 events
            evs = [
                Event(
                    x=int(a),
                    y=int(b),
                    ts=Time(sec=int(c // 1_000_000), nanosec=int(c % 1_000_000) * 1000),
                    polarity=bool(d),
                )
                for a, b, c, d in zip(
                    x[s : s + 5000], y[s : s + 5000], t_us[s : s + 5000], p[s : s + 5000], strict=True
                )
            ]
            tt = t_us[min(s + 4999, len(t_us) - 1)] / 1e6
            msgs.append(
                (
                    tt,
                    "events",
                    EventArray(header=Header(stamp=stamp(tt), frame_id="ev"), height=42, width=56, events=evs),
                    "dvs_msgs/msg/EventArray",
                )
            )
        for t, kind, msg, typ in sorted(msgs, key=lambda m: m[0]):
            w.write(conns[kind], int(t * 1e9), ts.serialize_cdr(msg, typ))


def test_bag_round_trip_gives_the_same_dataset(tmp_path: Path):
    from agrinerf_ns.process.rosbag import bag_to_raw

    raw = make_raw_capture(tmp_path / "raw", n=4)
    _write_bag(raw, tmp_path / "bag")
    raw2 = bag_to_raw(tmp_path / "bag", raw / "calib.yaml", tmp_path / "raw2", odometry=raw / "odometry.txt")
    with h5py.File(raw / "events" / "events.h5") as a, h5py.File(raw2 / "events" / "events.h5") as b:
        for k in "xytp":
            np.testing.assert_array_equal(a["events"][k][:], b["events"][k][:])
    cfg = ProcessConfig(poses="given", show_progress=False)
    d1, d2 = process_capture(raw, tmp_path / "d1", cfg), process_capture(raw2, tmp_path / "d2", cfg)
    for sub in ("images", "thermal", "events"):
        for f in sorted((d1 / sub).glob("*.png")):
            np.testing.assert_array_equal(cv2.imread(str(f), -1), cv2.imread(str(d2 / sub / f.name), -1))
