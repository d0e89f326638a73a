"""Prophesee EVT 2.0 / 3.0 and ROS EventPacket decoding, checked against the shared real bags' reference counts
(upstream event_camera_py tests) and against a plain per-word reference decoder written here from the format
description. The tests that read the bags need the ``[ros]`` extra (rosbags) and are skipped without it; the decoders
of ``.raw`` files are tested on streams written here as well, without it."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from agrinerf_ns.process import readers
from agrinerf_ns.process.readers import RawInputError

needs_rosbags = pytest.mark.skipif(
    importlib.util.find_spec("rosbags") is None, reason="reading the shared ROS bags needs the [ros] extra (rosbags)"
)

BAGS = Path(__file__).parent / "data" / "event-camera-bags"  # real bags, Apache-2.0 (README there)
TOPIC = "/event_camera/events"
EVT3_HEADER = b"% camera_integrator_name Prophesee\n% evt 3.0\n% format EVT3;height=480;width=640\n% end\n"
EVT2_HEADER = b"% evt 2.0\n% geometry 640x480\n"


def _packets(bag: Path):
    from agrinerf_ns.process.rosbag import open_bag

    with open_bag(bag) as (conns, reader, deserialize):
        for conn, _, raw in reader.messages(connections=[c for c in conns if c.topic == TOPIC]):
            yield deserialize(raw, conn.msgtype)


@pytest.fixture(scope="module")
def evt3_raw(tmp_path_factory) -> Path:
    """A .raw file: the EVT 3.0 byte stream of bag 1's packets behind a Metavision-style header."""
    path = tmp_path_factory.mktemp("raw") / "events.raw"
    with open(path, "wb") as fh:
        fh.write(EVT3_HEADER)
        for msg in _packets(BAGS / "test_events_1.bag"):
            fh.write(np.asarray(msg.events, np.uint8).tobytes())
    return path


def reference_evt3(data: bytes):
    """Word-by-word EVT 3.0 decoder (no vectorisation, no chunking): CD (x, y, t, p) and triggers (t, p)."""
    words = np.frombuffer(data, "<u2").tolist()
    y = bx = bp = low = high = 0
    last_high12 = 0
    cd, trig = [], []
    for w in words:
        typ, v = w >> 12, w & 0xFFF
        t = (high << 12) | low
        if typ == 0x0:
            y = v & 0x7FF
        elif typ == 0x2:
            cd.append((v & 0x7FF, y, t, v >> 11))
        elif typ == 0x3:
            bx, bp = v & 0x7FF, v >> 11
        elif typ in (0x4, 0x5):
            n = 12 if typ == 0x4 else 8
            for k in range(n):
                if (v >> k) & 1:
                    cd.append((bx + k, y, t, bp))
            bx += n
        elif typ == 0x6:
            low = v
        elif typ == 0x8:
            if last_high12 - v > 2048:
                high += 4096
            high = (high & ~0xFFF) | v
            last_high12 = v
        elif typ == 0xA:
            trig.append((t, v & 1))
    return np.array(cd, np.int64).reshape(-1, 4), np.array(trig, np.int64).reshape(-1, 2)


def encode_evt2(cd: np.ndarray, trig: np.ndarray) -> bytes:
    """EVT 2.0 words for time-sorted CD events (x, y, t, p) and triggers (t, p): a TIME_HIGH word whenever time
    bits 6+ change, then CD_OFF / CD_ON / EXT_TRIGGER words with time bits 0-5."""
    rows = [(int(t), 0, (int(p) << 28) | ((int(t) & 0x3F) << 22) | (int(x) << 11) | int(y)) for x, y, t, p in cd]
    rows += [(int(t), 1, (0xA << 28) | ((int(t) & 0x3F) << 22) | (6 << 8) | int(p)) for t, p in trig]
    words, high = [], None
    for t, _, w in sorted(rows, key=lambda r: (r[0], r[1])):
        if t >> 6 != high:
            high = t >> 6
            words.append((0x8 << 28) | (high & 0x0FFF_FFFF))  # a 28-bit counter: wraps after 2^34 us
        words.append(w)
    return np.asarray(words, "<u4").tobytes()


def _read_all(path: Path, chunk: int):
    parts = list(readers.iter_event_chunks(path, chunk_size=chunk, sensor_wh=(640, 480)))
    assert all(len(c) <= chunk for c in parts)
    return np.stack([np.concatenate([getattr(c, k) for c in parts]).astype(np.int64) for k in "xytp"], 1)


@needs_rosbags
@pytest.mark.parametrize("bag", ["test_events_1.bag", "test_events_1", "test_events_2"])
def test_shared_bags_match_the_reference_counts(bag: str, tmp_path: Path):
    import h5py

    from agrinerf_ns.process.rosbag import BagTopics, bag_to_raw

    raw = bag_to_raw(
        BAGS / bag,
        _calib(tmp_path),
        tmp_path / "raw",
        BagTopics(rgb=None, thermal=None, events=TOPIC),
        event_clock="sensor",
    )
    with h5py.File(raw / "events" / "events.h5") as f:
        p, t = f["events/p"][:], f["events/t"][:]
        trig_p = f["triggers/p"][:] if "triggers" in f else np.zeros(0)
        trig_t = f["triggers/t"][:] if "triggers" in f else np.zeros(0, np.int64)
    assert np.all(np.diff(t) >= 0)
    if bag.startswith("test_events_1"):
        assert (int((p == 0).sum()), int((p == 1).sum())) == (218_291, 125_183)
        # edge bit 0 = falling, 1 = rising (Prophesee EVT 3.0). The upstream counter calls p == 0 "rise" and asserts
        # 2,078 of those only; it sums the times of all trigger events, which pins the 2,079 rising edges too.
        assert (int((trig_p == 0).sum()), int((trig_p == 1).sum())) == (2_078, 2_079)
        assert int(t.sum()) + int(trig_t.sum()) == 2_885_601_049_874  # upstream's sum of CD + trigger times (us)
    else:  # libcaer_cmp packets of a 346x260 sensor, no triggers
        assert (int((p == 0).sum()), int((p == 1).sum())) == (360_223, 211_043)
        assert trig_p.size == 0
    assert readers.count_events(raw / "events" / "events.h5") == p.size


def _calib(tmp_path: Path) -> Path:
    import yaml

    cam = {
        "camera_model": "pinhole",
        "intrinsics": [300.0, 300.0, 319.5, 239.5],
        "distortion_model": "radtan",
        "distortion_coeffs": [0.0, 0.0, 0.0, 0.0],
        "resolution": [640, 480],
    }
    path = tmp_path / "calib.yaml"
    path.write_text(
        yaml.safe_dump(
            {"cam0": {**cam, "modality": "rgb"}, "cam1": {**cam, "modality": "event", "T_cn_cnm1": np.eye(4).tolist()}}
        )
    )
    return path


@needs_rosbags
def test_evt3_raw_decodes_like_the_reference_decoder(evt3_raw: Path):
    header = readers_header(evt3_raw)
    assert (header.evt, header.width, header.height) == ("3.0", 640, 480)
    ref_cd, ref_trig = reference_evt3(evt3_raw.read_bytes()[header.data_offset :])
    assert len(ref_cd) == 218_291 + 125_183
    for chunk in (2_000_000, 4097):  # one chunk, and many (state carried across chunk boundaries)
        np.testing.assert_array_equal(_read_all(evt3_raw, chunk), ref_cd)
    assert readers.count_events(evt3_raw) == len(ref_cd)
    trig = readers.read_triggers(evt3_raw)
    np.testing.assert_array_equal(np.stack([trig.t, trig.p], 1), ref_trig)
    assert set(trig.id.tolist()) == {6}


def readers_header(path: Path):
    from agrinerf_ns.process.event_codecs import read_raw_header

    return read_raw_header(path)


@needs_rosbags
def test_evt2_raw_decodes_the_events_it_was_written_from(evt3_raw: Path, tmp_path: Path):
    cd, trig_ref = reference_evt3(evt3_raw.read_bytes()[readers_header(evt3_raw).data_offset :])
    cd = cd[::7]  # a subsample keeps the pure-Python encoder fast
    path = tmp_path / "events.raw"
    path.write_bytes(EVT2_HEADER + encode_evt2(cd, trig_ref))
    header = readers_header(path)
    assert (header.evt, header.width, header.height) == ("2.0", 640, 480)
    # the encoder orders events by time (stable), as a sensor emits them
    order = np.argsort(cd[:, 2], kind="stable")
    np.testing.assert_array_equal(_read_all(path, 5000), cd[order])
    assert readers.count_events(path) == len(cd)
    trig = readers.read_triggers(path)
    np.testing.assert_array_equal(np.stack([trig.t, trig.p], 1), trig_ref)


def test_evt2_time_high_rollover_is_unwrapped(tmp_path: Path):
    t = np.array([(1 << 34) - 3, (1 << 34) + 5])  # EVT 2.0 time wraps after 2^34 us
    cd = np.array([[1, 2, t[0], 1], [3, 4, t[1], 0]])
    path = tmp_path / "wrap.raw"
    path.write_bytes(EVT2_HEADER + encode_evt2(cd, np.zeros((0, 2), np.int64)))
    np.testing.assert_array_equal(_read_all(path, 10)[:, 2], t)


def _sorted_rows(events: np.ndarray) -> np.ndarray:
    return events[np.lexsort(events.T[::-1])]


def test_evt3_raw_of_synthetic_events_decodes_like_the_reference_decoder(tmp_path: Path):
    """Without the bags: random CD events, EVT 3.0-encoded, decode as the per-word reference decoder decodes them and
    as they were written, in one chunk and in many."""
    from agrinerf_ns.process.event_codecs import Evt3Encoder, evt3_header, read_raw_header

    rng = np.random.default_rng(0)
    n = 20_000
    t = np.sort(rng.integers(0, 3_000_000, n))
    x, y, p = rng.integers(0, 640, n), rng.integers(0, 480, n), rng.integers(0, 2, n)
    path = tmp_path / "events.raw"
    path.write_bytes(evt3_header(640, 480) + Evt3Encoder().encode(x, y, t, p).tobytes())
    header = read_raw_header(path)
    assert (header.evt, header.width, header.height) == ("3.0", 640, 480)
    ref_cd, ref_trig = reference_evt3(path.read_bytes()[header.data_offset :])
    assert len(ref_cd) == n and len(ref_trig) == 0
    for chunk in (1 << 20, 997):
        decoded = _read_all(path, chunk)
        np.testing.assert_array_equal(decoded, ref_cd)
        written = np.stack([x, y, t, p], 1)  # the encoder may group the events of one time by row: compare as sets
        np.testing.assert_array_equal(_sorted_rows(decoded), _sorted_rows(written))
    assert readers.count_events(path) == n


# ----------------------------------------------------------------------------------------------------------------
# bad input


@needs_rosbags
def test_truncated_raw_names_the_file(evt3_raw: Path, tmp_path: Path):
    cut = tmp_path / "cut.raw"
    cut.write_bytes(evt3_raw.read_bytes()[:-1])
    with pytest.raises(RawInputError, match=r"cut\.raw: event data is .*truncated"):
        readers.count_events(cut)
    with pytest.raises(RawInputError, match=r"cut\.raw.*truncated"):
        next(readers.iter_event_chunks(cut))
    head = tmp_path / "head.raw"
    head.write_bytes(b"% evt 3.0\n% format EVT3;wid")
    with pytest.raises(RawInputError, match=r"head\.raw: header line .* cut off"):
        readers.count_events(head)


@pytest.mark.parametrize("header", [b"% evt 2.1\n", b"% format EVT4;width=640;height=480\n", b"% date 2020\n"])
def test_unknown_evt_version_names_the_file_and_version(header: bytes, tmp_path: Path):
    path = tmp_path / "v.raw"
    path.write_bytes(header + b"\x00\x00\x00\x00")
    with pytest.raises(RawInputError, match=r"v\.raw: (EVT version '(2\.1|EVT4)' is not supported|no '% evt')"):
        next(readers.iter_event_chunks(path))


@needs_rosbags
def test_bag_without_the_event_topic_lists_the_topics(tmp_path: Path):
    from agrinerf_ns.process.rosbag import BagTopics, bag_to_raw

    with pytest.raises(
        RawInputError,
        match=r"no event topic '/dvs/events'; topics in the bag: /event_camera/events "
        r"\(event_camera_msgs/msg/EventPacket\)",
    ):
        bag_to_raw(
            BAGS / "test_events_1.bag",
            _calib(tmp_path),
            tmp_path / "raw",
            BagTopics(rgb=None, thermal=None, events="/dvs/events"),
        )
    assert not (tmp_path / "raw").exists()


@needs_rosbags
def test_unsupported_packet_encoding_is_named(tmp_path: Path):
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    from agrinerf_ns.process.rosbag import EVENT_PACKET_MSG, BagTopics, bag_to_raw

    ts = get_typestore(Stores.ROS2_HUMBLE)
    ts.register(get_types_from_msg(EVENT_PACKET_MSG, "event_camera_msgs/msg/EventPacket"))
    T = ts.types
    msg = T["event_camera_msgs/msg/EventPacket"](
        header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=1, nanosec=0), frame_id="ev"),
        height=480,
        width=640,
        seq=0,
        time_base=0,
        encoding="mono",
        is_bigendian=False,
        events=np.zeros(16, np.uint8),
    )
    with Writer(tmp_path / "bag", version=9) as w:
        conn = w.add_connection(TOPIC, "event_camera_msgs/msg/EventPacket", typestore=ts)
        w.write(conn, 1, ts.serialize_cdr(msg, "event_camera_msgs/msg/EventPacket"))
    with pytest.raises(RawInputError, match=r"/event_camera/events: EventPacket encoding 'mono' is not supported"):
        bag_to_raw(
            tmp_path / "bag", _calib(tmp_path), tmp_path / "raw", BagTopics(rgb=None, thermal=None, events=TOPIC)
        )
    assert not (tmp_path / "raw").exists() and not list(tmp_path.glob(".raw.tmp-*"))


@needs_rosbags
def test_evt3_encoder_round_trips_through_the_reader(evt3_raw: Path, tmp_path: Path):
    from agrinerf_ns.process.event_codecs import Evt3Encoder, evt3_header

    cd = _read_all(evt3_raw, 1 << 20)
    enc = Evt3Encoder()
    path = tmp_path / "enc.raw"
    with open(path, "wb") as fh:
        fh.write(evt3_header(640, 480))
        for s in range(0, len(cd), 50_000):  # chunked: state carried across calls
            c = cd[s : s + 50_000]
            fh.write(enc.encode(c[:, 0], c[:, 1], c[:, 2], c[:, 3]).tobytes())
    np.testing.assert_array_equal(_read_all(path, 30_000), cd)


def test_capture_with_events_raw_gives_the_dataset_of_events_h5(tmp_path: Path):
    import h5py
    from helpers.process_raw_fixture import make_raw_capture

    from agrinerf_ns.process import ProcessConfig, process_capture
    from agrinerf_ns.process.event_codecs import Evt3Encoder, evt3_header

    raw = make_raw_capture(tmp_path / "raw", n=4, with_thermal=False)
    cfg = ProcessConfig(poses="given", show_progress=False)
    ref = process_capture(raw, tmp_path / "ref", cfg)
    with h5py.File(raw / "events" / "events.h5") as f:
        x, y, t, p = (f["events"][k][:] for k in "xytp")
    (raw / "events" / "events.h5").unlink()
    (raw / "events" / "events.raw").write_bytes(evt3_header(56, 42) + Evt3Encoder().encode(x, y, t, p).tobytes())
    out = process_capture(raw, tmp_path / "ds", cfg)
    for f in sorted((ref / "events").glob("*.npz")):
        with np.load(f) as a, np.load(out / "events" / f.name) as b:
            np.testing.assert_array_equal(a["pos"], b["pos"])
            np.testing.assert_array_equal(a["neg"], b["neg"])
    # a header whose sensor size disagrees with the calibration is refused before any output
    (raw / "events" / "events.raw").write_bytes(evt3_header(640, 480) + Evt3Encoder().encode(x, y, t, p).tobytes())
    with pytest.raises(RawInputError, match=r"events\.raw: the header says a 640x480 sensor but .*calib\.yaml gives "
                                            r"the event camera 56x42"):  # fmt: skip
        process_capture(raw, tmp_path / "ds2", cfg)
    assert not (tmp_path / "ds2").exists()


@needs_rosbags
def test_the_event_loss_counts_a_real_recording_like_brute_force(tmp_path: Path):
    """The event loss's counting structure (agrinerf_ns.dataparsers.event_stream) on a real Prophesee recording: bursty,
    hot pixels, a 640x480 sensor, times in microseconds of the sensor clock. Totals match the upstream reference
    counts and every random window matches a brute-force count."""
    import h5py
    import torch

    from agrinerf_ns.dataparsers.event_stream import EventStream
    from agrinerf_ns.process.rosbag import BagTopics, bag_to_raw

    raw = bag_to_raw(BAGS / "test_events_1.bag", _calib(tmp_path), tmp_path / "raw",
                     BagTopics(rgb=None, thermal=None, events=TOPIC), event_clock="sensor")  # fmt: skip
    with h5py.File(raw / "events" / "events.h5") as f:
        x, y, t, p = (f[f"events/{k}"][:].astype(np.int64) for k in "xytp")
    stream = EventStream(x, y, t, p, 640, 480)
    pixel_all = torch.arange(640 * 480)
    on, off = stream.counts(
        pixel_all, torch.full_like(pixel_all, int(t.min())), torch.full_like(pixel_all, int(t.max()) + 1)
    )
    assert (int(off.sum()), int(on.sum())) == (218_291, 125_183)
    rng = np.random.default_rng(0)
    busiest = np.argsort(np.bincount(y * 640 + x, minlength=640 * 480))[-200:]  # the hot and busy pixels
    pixel = torch.from_numpy(np.concatenate([busiest, rng.integers(0, 640 * 480, 300)]))
    t0 = torch.from_numpy(rng.integers(int(t.min()) - 1000, int(t.max()), pixel.numel()))
    t1 = t0 + torch.from_numpy(rng.integers(0, 400_000, pixel.numel()))
    on, off = stream.counts(pixel, t0, t1)
    order = np.argsort(y * 640 + x, kind="stable")
    key_pixel, key_t, key_p = (y * 640 + x)[order], t[order], p[order]
    for k in range(pixel.numel()):
        lo, hi = np.searchsorted(key_pixel, [int(pixel[k]), int(pixel[k]) + 1])
        m = (key_t[lo:hi] >= int(t0[k])) & (key_t[lo:hi] < int(t1[k]))
        assert (int(on[k]), int(off[k])) == (int((key_p[lo:hi][m] == 1).sum()), int((key_p[lo:hi][m] == 0).sum()))
    assert int(on.sum() + off.sum()) > 500  # the windows hold real events, not only empty ones
