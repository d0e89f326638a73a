"""Optional extra: a ROS1 / ROS2 bag (read with ``rosbags``) -> a raw capture folder for ``agrinerf-process``.

    python -m agrinerf_ns.process.rosbag --bag run.bag --calib camchain.yaml --out RAW [--odometry odometry.txt]

Bags carry no Kalibr calibration, so the camchain YAML (with ``modality`` per camera) is given and copied.
Topics: ``sensor_msgs/Image`` for RGB (rgb8, bgr8, rgba8, bgra8, mono8) and thermal (mono16 / 16UC1 / mono8: a
Boson driver's raw 16-bit counts are kept as they are); events as ``event_camera_msgs/EventPacket`` (the current ROS
event-camera drivers; encodings ``evt3`` = Prophesee EVT 3.0 and ``libcaer_cmp``, decoded in order with the stream
state carried across packets, see :mod:`agrinerf_ns.process.event_codecs`) or a ``dvs_msgs/EventArray``-shaped
message (fields ``events[]`` with ``x``, ``y``, ``ts``, ``polarity``; the Prophesee driver's EventArray has the same
fields). Frame times are the message header stamps. Events go to ``events/events.h5`` in chunks, external-trigger
events to its ``triggers`` group. EVT 3.0 packets carry sensor time: ``event_clock="header"`` (default) shifts it
onto the header clock of the frames by the median offset between each packet's header stamp and its first event;
``"sensor"`` keeps sensor time (for ``agrinerf-process --sync trigger``). The output is written to a temporary
sibling and renamed into place.
"""

from __future__ import annotations

import shutil
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, Iterator, List, Literal, Optional, Tuple

import cv2
import numpy as np
import tyro

from agrinerf_ns.atomic import atomic_output_dir
from agrinerf_ns.process.errors import RawInputError
from agrinerf_ns.process.event_h5 import EventH5Writer
from agrinerf_ns.process.readers import read_calibration


@dataclass
class BagTopics:
    """Topic names of the sensors; a named topic must be in the bag (None: do not convert that sensor, e.g. events
    only, to be joined with frames recorded elsewhere)."""

    rgb: Optional[str] = "/rgb/image_raw"
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


EVENT_PACKET_MSG = (
    "std_msgs/Header header\nuint32 height\nuint32 width\nuint64 seq\nuint64 time_base\nstring encoding\n"
    "bool is_bigendian\nuint8[] events\n"
)
"""``event_camera_msgs/EventPacket`` (same fields in ROS1 and ROS2), registered when a bag's own definition is
absent or unreadable (rosbags cannot parse the IDL that rosbag2 writes into MCAP files for it)."""
DVS_MSGS = {
    "dvs_msgs/msg/Event": "uint16 x\nuint16 y\nbuiltin_interfaces/Time ts\nbool polarity\n",
    "dvs_msgs/msg/EventArray": "std_msgs/Header header\nuint32 height\nuint32 width\ndvs_msgs/Event[] events\n",
}
EVENT_ENCODINGS = ("evt3", "libcaer_cmp")


@contextmanager
def open_bag(bag: Path) -> Iterator[Tuple[list, object, object]]:
    """Open a ROS1 ``.bag``, a ROS2 bag folder or a single ``.db3`` / ``.mcap`` file; yield (connections, reader,
    deserialize(raw, msgtype)). Message types come from the bag where rosbags can parse them, else from the
    definitions above; a ROS2 folder whose metadata names no storage plugin is read through its one storage file."""
    from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore

    bag = Path(bag)
    if not bag.exists():
        raise RawInputError(f"{bag}: bag does not exist")
    ros1 = bag.is_file() and bag.suffix == ".bag"
    if ros1:
        from rosbags.rosbag1 import Reader

        target = bag
    else:
        from rosbags.rosbag2 import Reader

        target = bag
        if bag.is_dir():
            meta = bag / "metadata.yaml"
            import yaml

            info = yaml.safe_load(meta.read_text()).get("rosbag2_bagfile_information", {}) if meta.is_file() else {}
            if not meta.is_file() or not info.get("storage_identifier"):
                files = sorted(p for p in bag.iterdir() if p.suffix in (".db3", ".mcap"))
                if len(files) != 1:
                    raise RawInputError(f"{bag}: no usable metadata.yaml and not exactly one .db3/.mcap file in it")
                target = files[0]
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    try:
        reader = Reader(target)
        reader.open()
    except Exception as err:  # noqa: BLE001  rosbags raises several unrelated types
        raise RawInputError(f"{bag}: cannot open bag ({type(err).__name__}: {err})") from err
    try:
        types: Dict = {}
        for conn in reader.connections:
            msgdef = getattr(conn, "msgdef", None)
            data = getattr(msgdef, "data", msgdef)
            fmt = str(getattr(getattr(msgdef, "format", None), "name", "MSG"))
            if not data or conn.msgtype in store.types:
                continue
            try:
                types.update(get_types_from_idl(data) if fmt == "IDL" else get_types_from_msg(data, conn.msgtype))
            except Exception:  # noqa: BLE001  unparseable definitions fall back to the known ones below
                pass
        known = {"event_camera_msgs/msg/EventPacket": EVENT_PACKET_MSG, **DVS_MSGS}
        for name, text in known.items():
            if name not in types and name not in store.types:
                types.update(get_types_from_msg(text, name))
        store.register(types)
        deser = store.deserialize_ros1 if ros1 else store.deserialize_cdr
        yield list(reader.connections), reader, deser
    finally:
        reader.close()


def bag_to_raw(
    bag: Path,
    calib: Path,
    out: Path,
    topics: Optional[BagTopics] = None,
    odometry: Optional[Path] = None,
    event_chunk: int = 1_000_000,
    event_clock: Literal["header", "sensor"] = "header",
) -> Path:
    """Convert ``bag`` (file or ROS2 bag folder) into the raw capture folder ``out`` and return it.

    Checks before writing anything: the calibration, that the bag has every named topic (the error lists the
    topics found); unsupported image or packet encodings raise :class:`RawInputError` naming the
    topic and the encoding, and nothing is left at ``out``.
    """
    topics = topics or BagTopics()
    read_calibration(calib)  # fail early on a bad calibration
    if out.exists() and any(out.iterdir()):
        raise FileExistsError(f"{out}: folder exists and is not empty")
    with open_bag(bag) as (connections, reader, deserialize):
        wanted = {t: k for k, t in (("rgb", topics.rgb), ("thermal", topics.thermal), ("events", topics.events)) if t}
        conns = [c for c in connections if c.topic in wanted]
        found = {c.topic for c in conns}
        listing = ", ".join(sorted(f"{c.topic} ({c.msgtype})" for c in connections)) or "none"
        for kind, topic in (("RGB", topics.rgb), ("thermal", topics.thermal), ("event", topics.events)):
            if topic is not None and topic not in found:
                raise RawInputError(f"{bag}: no {kind} topic {topic!r}; topics in the bag: {listing}")
        with atomic_output_dir(out, overwrite=False) as tmp:
            _convert(bag, tmp, reader, deserialize, conns, wanted, calib, odometry, event_chunk, event_clock)
    return out


def _convert(bag, tmp, reader, deserialize, conns, wanted, calib, odometry, event_chunk, event_clock) -> None:
    from agrinerf_ns.process.event_codecs import Evt3Decoder, decode_libcaer_cmp

    shutil.copyfile(calib, tmp / "calib.yaml")
    if odometry is not None:
        shutil.copyfile(odometry, tmp / "odometry.txt")
    stamps: Dict[str, List[str]] = {"rgb": [], "thermal": []}
    sink = EventH5Writer(tmp / "events", event_chunk)
    evt3 = Evt3Decoder()
    offsets: List[int] = []  # header stamp - first event time, per EVT 3.0 packet (us)
    encodings = set()
    for conn, _, raw in reader.messages(connections=conns):
        kind = wanted[conn.topic]
        msg = deserialize(raw, conn.msgtype)
        where = f"{bag}:{conn.topic}"
        if kind in ("rgb", "thermal"):
            img = image_from_msg(msg, where)
            if kind == "thermal" and img.ndim == 3:
                raise RawInputError(f"{where}: thermal image must be single-channel")
            name = f"{len(stamps[kind]):06d}.png"
            (tmp / kind).mkdir(exist_ok=True)
            cv2.imwrite(str(tmp / kind / name), img[:, :, ::-1] if img.ndim == 3 else img)
            stamps[kind].append(f"{name} {_stamp_s(msg.header):.9f}")
        elif hasattr(msg, "encoding") and hasattr(msg, "time_base"):  # event_camera_msgs/EventPacket
            enc = str(msg.encoding)
            encodings.add(enc)
            data = np.asarray(msg.events, dtype=np.uint8)
            if enc == "evt3":
                d = evt3.decode(data[: data.size // 2 * 2].view("<u2"))
                first = [a[0] for a in (d.t, d.trig_t) if a.size]
                if first:
                    stamp_us = int(msg.header.stamp.sec) * 1_000_000 + int(msg.header.stamp.nanosec) // 1000
                    offsets.append(stamp_us - int(min(first)))
            elif enc == "libcaer_cmp":
                d = decode_libcaer_cmp(data.tobytes(), int(msg.time_base), int(msg.width), int(msg.height))
            else:
                raise RawInputError(
                    f"{where}: EventPacket encoding {enc!r} is not supported (supported: {', '.join(EVENT_ENCODINGS)})"
                )
            sink.add(d.x, d.y, d.t, d.p)
            if d.trig_t.size:
                sink.add_triggers(d.trig_t, d.trig_p, d.trig_id)
        else:  # dvs_msgs/EventArray-shaped
            evs = msg.events
            sink.add(
                np.fromiter((e.x for e in evs), np.uint16, len(evs)),
                np.fromiter((e.y for e in evs), np.uint16, len(evs)),
                np.fromiter((int(e.ts.sec) * 1_000_000 + int(e.ts.nanosec) // 1000 for e in evs), np.int64, len(evs)),
                np.fromiter((1 if e.polarity else 0 for e in evs), np.uint8, len(evs)),
            )
    offset = int(np.median(offsets)) if offsets and event_clock == "header" else 0
    clock = "header" if (offset or "evt3" not in encodings) else "sensor"
    sink.close(offset, {"clock": clock, "time_offset_us": offset, "encodings": ",".join(sorted(encodings))})
    for kind, lines in stamps.items():
        if lines:
            (tmp / kind / "timestamps.txt").write_text("\n".join(lines) + "\n")


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
    event_clock: Literal["header", "sensor"] = "header"
    """EVT 3.0 event times: shifted onto the frames' header clock, or kept in sensor time (for --sync trigger)."""


if __name__ == "__main__":
    a = tyro.cli(BagArgs)
    bag_to_raw(a.bag, a.calib, a.out, a.topics, a.odometry, event_clock=a.event_clock)
