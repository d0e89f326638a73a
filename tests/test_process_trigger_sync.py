"""A raw capture assembled from a real bag's events (sensor clock, with its external-trigger edges) plus frames and
calibration: ``--sync trigger`` maps the frame times into event time through the edges, the capture runs through
agrinerf-process and ``ns-train agrinerf-lite``; and ``--sync trigger`` without trigger events is refused."""

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from helpers.process_raw_fixture import make_raw_capture

from agrinerf_ns.process import ProcessConfig, process_capture, readers
from agrinerf_ns.process.readers import RawInputError

BAG = Path(__file__).parent / "data" / "event-camera-bags" / "test_events_1.bag"
HOST_OFFSET_S, DRIFT, LATENCY_S, JITTER_S = 500.0, 20e-6, 2e-4, 3e-5


def _retime(path: Path, times: np.ndarray, column: int) -> None:
    rows = [ln.split() for ln in path.read_text().splitlines() if ln.strip() and not ln.startswith("#")]
    for r, t in zip(rows, times, strict=True):
        r[column] = f"{t:.9f}"
    path.write_text("\n".join(" ".join(r) for r in rows) + "\n")


@pytest.fixture(scope="module")
def bag_capture(tmp_path_factory):
    """12 frames triggered by every 100th rising edge of bag 1, stamped on a host clock 500 s ahead, drifting
    20 ppm, 0.2 ms late with 30 us jitter."""
    pytest.importorskip("rosbags")
    from agrinerf_ns.process.rosbag import BagTopics, bag_to_raw

    root = tmp_path_factory.mktemp("bagcap")
    n = 12
    raw = make_raw_capture(root / "raw", n=n)
    calib = yaml.safe_load((raw / "calib.yaml").read_text())
    calib["cam2"].update(resolution=[640, 480], intrinsics=[800.0, 800.0, 319.5, 239.5])
    (raw / "calib.yaml").write_text(yaml.safe_dump(calib, sort_keys=False))
    (raw / "events" / "events.h5").unlink()
    (raw / "events").rmdir()
    bag_to_raw(
        BAG,
        raw / "calib.yaml",
        root / "bagraw",
        BagTopics(rgb=None, thermal=None, events="/event_camera/events"),
        event_clock="sensor",
    )
    (root / "bagraw" / "events").rename(raw / "events")
    trig = readers.read_triggers(raw / "events" / "events.h5")
    edges = np.sort(trig.t[trig.p == 1]) / 1e6
    true_t = edges[50 : 50 + 100 * n : 100]
    rng = np.random.default_rng(0)
    host = true_t * (1 + DRIFT) + HOST_OFFSET_S + LATENCY_S + rng.normal(0, JITTER_S, n)
    _retime(raw / "rgb" / "timestamps.txt", host, 1)
    _retime(raw / "thermal" / "timestamps.txt", host, 1)
    _retime(raw / "odometry.txt", host, 0)
    return raw, true_t


def test_trigger_sync_maps_frames_onto_their_edges(bag_capture, tmp_path: Path):
    raw, true_t = bag_capture
    cfg = ProcessConfig(poses="given", sync="trigger", trigger_offset_s=-HOST_OFFSET_S, show_progress=False)
    out = process_capture(raw, tmp_path / "ds", cfg)
    meta = json.loads((out / "transforms.json").read_text())
    ev = meta["agrinerf"]["events"]
    sync = ev["sync"]
    assert sync["method"] == "trigger" and sync["matched"] == sync["frames"] == 12
    assert sync["residual_rms_us"] < 2 * JITTER_S * 1e6 and abs(sync["scale"] - 1 / (1 + DRIFT)) < 5e-5
    assert ev["events_in_windows"] > 0
    starts, ends = [], []
    for f in meta["frames"]:
        with np.load(out / f["event_sums_path"]) as z:
            starts.append(float(z["t_start"]))
            ends.append(float(z["t_end"]))
    # windows are in the frames' clock (anchor end: they end at the frames' stamps) ...
    np.testing.assert_allclose(ends, [f["timestamp"] for f in meta["frames"]])
    # ... which the fitted sync maps onto each frame's trigger edge in the event clock
    np.testing.assert_allclose(np.array(ends) * sync["scale"] + sync["offset_s"], true_t, atol=3 * JITTER_S)
    # the event stream holds the windows' events, moved into the frames' clock
    import h5py

    with h5py.File(out / ev["stream"]) as f:
        t = np.asarray(f["events"]["t"]) * 1e-6
    assert t.size > 0 and t.min() >= min(starts) - 1e-6 and t.max() <= max(ends) + 1e-6
    # the recorded stamps are 500 s away from event time: no event falls in a window
    with pytest.raises(RawInputError, match="event and RGB timestamps do not overlap"):
        process_capture(raw, tmp_path / "ds2", ProcessConfig(poses="given", show_progress=False))
    assert not (tmp_path / "ds2").exists()


@pytest.mark.slow
def test_bag_capture_trains_agrinerf_lite(bag_capture, tmp_path: Path):
    from agrinerf_ns.ns_commands import ns_train

    raw, _ = bag_capture
    cfg = ProcessConfig(poses="given", sync="trigger", trigger_offset_s=-HOST_OFFSET_S, show_progress=False)
    out = process_capture(raw, tmp_path / "ds", cfg)
    assert json.loads((out / "transforms.json").read_text())["agrinerf"]["modalities"] == ["rgb", "thermal", "events"]
    run = ns_train(
        "agrinerf-lite",
        out,
        tmp_path / "outputs",
        "bag",
        max_steps=3,
        rays_per_batch=128,
        extra_args=["--machine.device-type", "cpu"],
    )
    assert list((run.config.parent / "nerfstudio_models").glob("*.ckpt")), "ns-train wrote a checkpoint"


def test_sync_trigger_without_trigger_events_is_refused(tmp_path: Path):
    raw = make_raw_capture(tmp_path / "raw", n=4)
    with pytest.raises(
        RawInputError,
        match=r"events\.h5: --sync trigger needs external-trigger events, but the file "
        r"has none",
    ):
        process_capture(raw, tmp_path / "ds", ProcessConfig(poses="given", sync="trigger", show_progress=False))
    assert not (tmp_path / "ds").exists()


def test_sync_trigger_far_from_every_edge_asks_for_the_offset(bag_capture, tmp_path: Path):
    raw, _ = bag_capture
    with pytest.raises(RawInputError, match=r"only 0 of 12 frames lie within .* give --trigger-offset-s"):
        process_capture(raw, tmp_path / "ds", ProcessConfig(poses="given", sync="trigger", show_progress=False))
    assert not (tmp_path / "ds").exists()
