"""Optional extra: a ROS1 / ROS2 bag (read with ``rosbags``) -> a raw capture folder for ``agrinerf-process``.

    python -m agrinerf_ns.process.rosbag --bag run.bag --calib camchain.yaml --out RAW [--odometry odometry.txt]

Bags carry no Kalibr calibration, so the camchain YAML (with ``modality`` per camera) is given and copied.
Topics: ``sensor_msgs/Image`` for RGB (rgb8, bgr8, rgba8, bgra8, mono8) and thermal (mono16 / 16UC1 / mono8), and a
``dvs_msgs/EventArray``-shaped message for events (fields ``events[]`` with ``x``, ``y``, ``ts``, ``polarity``; the
Prophesee driver's EventArray has the same fields). Frame times are the message header stamps; events go to
``events/events.h5`` in chunks. The output is written to a temporary sibling and renamed into place.
"""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional

import cv2
import numpy as np
import tyro

from agrinerf_ns.process.readers import RawInputError, read_calibration


@dataclass
class BagTopics:
    """Topic names of the sensors (None: not in the bag)."""

    rgb: str = "/rgb/image_raw"
    thermal: Optional[str] = "/thermal/image_raw"
    events: Optional[str] = "/dvs/events"


def _stamp_s(header) -> float:
    return float(header.stamp.sec) + 1e-9 * float(header.stamp.nanosec)


def image_from_msg(msg, where: str) -> np.ndarray:
    """sensor_msgs/Image -> numpy (RGB order for colour, uint16 for 16-bit)."""
    enc = msg.encoding.lower()
    h, w = int(msg.height), int(msg.width)
    data = np.frombuffer(bytes(msg.data), dtype=np.uint8)
    if enc in ("mono16", "16uc1"):
        dt = np.dtype(">u2" if msg.is_bigendian else "<u2")
        return data.view(dt).reshape(h, int(msg.step) // 2)[:, :w].astype(np.uint16)
    ch = {"mono8": 1, "8uc1": 1, "rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4}.get(enc)
    if ch is None:
        raise RawInputError(f"{where}: unsupported image encoding {msg.encoding!r}")
    img = data.reshape(h, int(msg.step))[:, : w * ch].reshape(h, w, ch) if ch > 1 else data.reshape(h, -1)[:, :w]
    if enc.startswith("bgr"):
        img = img[:, :, 2::-1]
    elif ch == 4:
        img = img[:, :, :3]
    return np.ascontiguousarray(img)


def bag_to_raw(
    bag: Path, calib: Path, out: Path, topics: Optional[BagTopics] = None, odometry: Optional[Path] = None,
    event_chunk: int = 1_000_000,
) -> Path:
    """Convert ``bag`` (file or ROS2 bag folder) into the raw capture folder ``out`` and return it."""
    topics = topics or BagTopics()
    import h5py
    from rosbags.highlevel import AnyReader

    read_calibration(calib)  # fail early on a bad calibration
    if out.exists() and any(out.iterdir()):
        raise FileExistsError(f"{out}: folder exists and is not empty")
    tmp = out.parent / f".{out.name}.tmp-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    try:
        shutil.copyfile(calib, tmp / "calib.yaml")
        if odometry is not None:
            shutil.copyfile(odometry, tmp / "odometry.txt")
        stamps: Dict[str, List[str]] = {"rgb": [], "thermal": []}
        ev_buf: Dict[str, List[np.ndarray]] = {k: [] for k in "xytp"}
        h5 = None
        with AnyReader([Path(bag)]) as reader:
            wanted = {t: k for k, t in (("rgb", topics.rgb), ("thermal", topics.thermal), ("events", topics.events))
                      if t}
            conns = [c for c in reader.connections if c.topic in wanted]
            found = {c.topic for c in conns}
            if topics.rgb not in found:
                raise RawInputError(f"{bag}: no messages on the RGB topic {topics.rgb!r}")
            for conn, _, raw in reader.messages(connections=conns):
                kind = wanted[conn.topic]
                msg = reader.deserialize(raw, conn.msgtype)
                where = f"{bag}:{conn.topic}"
                if kind in ("rgb", "thermal"):
                    img = image_from_msg(msg, where)
                    if kind == "thermal" and img.ndim == 3:
                        raise RawInputError(f"{where}: thermal image must be single-channel")
                    name = f"{len(stamps[kind]):06d}.png"
                    (tmp / kind).mkdir(exist_ok=True)
                    cv2.imwrite(str(tmp / kind / name), img[:, :, ::-1] if img.ndim == 3 else img)
                    stamps[kind].append(f"{name} {_stamp_s(msg.header):.9f}")
                else:
                    evs = msg.events
                    ev_buf["x"].append(np.fromiter((e.x for e in evs), np.uint16, len(evs)))
                    ev_buf["y"].append(np.fromiter((e.y for e in evs), np.uint16, len(evs)))
                    ev_buf["t"].append(np.fromiter(
                        (int(e.ts.sec) * 1_000_000 + int(e.ts.nanosec) // 1000 for e in evs), np.int64, len(evs)))
                    ev_buf["p"].append(np.fromiter((1 if e.polarity else 0 for e in evs), np.uint8, len(evs)))
                    if sum(len(a) for a in ev_buf["t"]) >= event_chunk:
                        h5 = _flush_events(h5, tmp, ev_buf, h5py)
        if ev_buf["t"]:
            h5 = _flush_events(h5, tmp, ev_buf, h5py)
        if h5 is not None:
            h5.close()
        for kind, lines in stamps.items():
            if lines:
                (tmp / kind / "timestamps.txt").write_text("\n".join(lines) + "\n")
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if out.exists():
        out.rmdir()
    tmp.rename(out)
    return out


def _flush_events(h5, tmp: Path, buf: Dict[str, List[np.ndarray]], h5py):
    if h5 is None:
        (tmp / "events").mkdir(exist_ok=True)
        h5 = h5py.File(tmp / "events" / "events.h5", "w")
        g = h5.create_group("events")
        for k, dt in (("x", np.uint16), ("y", np.uint16), ("t", np.int64), ("p", np.uint8)):
            g.create_dataset(k, shape=(0,), maxshape=(None,), dtype=dt, chunks=(1 << 16,))
    g = h5["events"]
    n0 = g["t"].shape[0]
    for k in "xytp":
        arr = np.concatenate(buf[k]) if buf[k] else np.zeros(0)
        g[k].resize((n0 + arr.shape[0],))
        g[k][n0:] = arr
        buf[k].clear()
    return h5


@dataclass
class BagArgs:
    """Convert a ROS1/ROS2 bag into a raw capture folder (then run agrinerf-process on it)."""

    bag: Path
    """Bag file (ROS1 .bag) or ROS2 bag folder."""
    calib: Path
    """Kalibr camchain YAML with ``modality`` per camera."""
    out: Path
    """Raw capture folder to write."""
    topics: BagTopics = field(default_factory=BagTopics)
    """Sensor topics."""
    odometry: Optional[Path] = None
    """Optional TUM odometry file to copy in."""


if __name__ == "__main__":
    a = tyro.cli(BagArgs)
    bag_to_raw(a.bag, a.calib, a.out, a.topics, a.odometry)
