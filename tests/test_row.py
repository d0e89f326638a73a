"""A whole row (issue #64): segments cut with their overlap in one world frame, fruit joined across borders, the yield
bins, a long synthetic row, and one tiny row from a raw capture through the jobs runner: in this process (and
resumed), and on a local Ray with a worker killed mid-training."""

from __future__ import annotations

import csv
import json
import threading
from pathlib import Path
from typing import TYPE_CHECKING, Dict, List, Tuple

import numpy as np
import pytest
from test_orchestrate_ray import local_ray  # noqa: F401  (the fixture: a local Ray of 2 CPUs)

from agrinerf_ns.count.cluster import Fruit
from agrinerf_ns.row.join import join_fruit
from agrinerf_ns.row.report import double_counts
from agrinerf_ns.row.segments import RowInputError, Segment, cut_segment, plan_segments
from agrinerf_ns.row.yield_map import along_row, correlation, yield_bins

if TYPE_CHECKING:
    from agrinerf_ns.row.cli import RowArgs


@pytest.fixture(scope="module")
def tiny_capture(tmp_path_factory) -> Path:
    """A tiny synthetic capture of 16 frames (1.1 m of row)."""
    from agrinerf_ns.synth import SynthConfig, generate_capture

    return generate_capture(SynthConfig.tiny(views=16), tmp_path_factory.mktemp("row") / "raw")


@pytest.fixture(scope="module")
def tiny_dataset(tiny_capture: Path) -> Path:
    """The tiny capture processed with its odometry (the capture's world frame)."""
    from agrinerf_ns.process import process_capture
    from agrinerf_ns.process.capture_to_dataset import ProcessConfig

    out = tiny_capture.parent / "data"
    process_capture(tiny_capture, out, ProcessConfig(poses="given", show_progress=False))
    return out


def test_segments_cover_the_capture_with_the_overlap_asked_for() -> None:
    for frames, size, overlap in ((24, 10, 4), (100, 48, 16), (48, 16, 8), (17, 10, 3), (101, 40, 20)):
        segments = plan_segments(frames, size, overlap)
        assert len(segments) >= 2
        assert segments[0].start == 0 and segments[-1].stop == frames
        assert all(s.stop - s.start == size for s in segments)
        shared = [a.stop - b.start for a, b in zip(segments, segments[1:], strict=False)]
        assert min(shared) >= overlap and max(shared) - min(shared) <= 1, (frames, size, overlap, shared)
        fewer = len(segments) - 1  # the fewest segments: one fewer could not keep the overlap
        assert fewer < 2 or (frames - size) / (fewer - 1) > size - overlap
    assert [(s.start, s.stop) for s in plan_segments(24, 10, 4)] == [(0, 10), (5, 15), (9, 19), (14, 24)]


@pytest.mark.parametrize(
    ("frames", "size", "overlap", "message"),
    [(15, 10, 4, "15 frames are too few for two segments of 10 frames overlapping by 4 (that needs 16)"),
     (40, 10, 0, "--overlap-frames must be at least 1"), (40, 10, 10, "below --segment-frames (10)"),
     (40, 1, 0, "--segment-frames must be at least 2")],
)  # fmt: skip
def test_bad_segment_settings_and_a_short_capture_are_refused(frames, size, overlap, message) -> None:
    with pytest.raises(RowInputError) as refused:
        plan_segments(frames, size, overlap)
    assert message in str(refused.value)
    assert len(plan_segments(16, 10, 4)) == 2  # just long enough


def test_a_segment_keeps_its_frames_poses_and_files_and_leaves_the_dataset_alone(tiny_dataset: Path) -> None:
    before = {p: p.stat().st_mtime_ns for p in tiny_dataset.rglob("*")}
    whole = json.loads((tiny_dataset / "transforms.json").read_text())
    segment = plan_segments(len(whole["frames"]), 10, 4)[1]
    out = tiny_dataset.parent / "segment"
    record = cut_segment(tiny_dataset, segment, out)
    meta = json.loads((out / "transforms.json").read_text())
    expected = sorted(whole["frames"], key=lambda f: f["timestamp"])[segment.start : segment.stop]
    assert [f["file_path"] for f in meta["frames"]] == [f["file_path"] for f in expected]
    for frame, original in zip(meta["frames"], expected, strict=True):  # the capture's world frame, untouched
        assert frame["transform_matrix"] == original["transform_matrix"]
        for key in ("file_path", "thermal_file_path", "event_sums_path"):
            assert (out / frame[key]).read_bytes() == (tiny_dataset / frame[key]).read_bytes()
    names = {f["file_path"] for f in meta["frames"]}
    assert set(meta["train_filenames"]) <= names and meta["val_filenames"] and set(meta["val_filenames"]) <= names
    assert set(meta["train_filenames"]) <= set(whole["train_filenames"])
    assert meta["agrinerf"]["segment"]["frames"] == [segment.start, segment.stop]
    thermal = json.loads((out / "transforms_thermal.json").read_text())
    assert [f["rgb_file_path"] for f in thermal["frames"]] == [f["file_path"] for f in expected]
    assert len(list((out / "images").iterdir())) == segment.stop - segment.start
    import h5py

    with h5py.File(out / "events" / "stream.h5") as f, h5py.File(tiny_dataset / "events" / "stream.h5") as g:
        t, all_t = np.asarray(f["events"]["t"]), np.asarray(g["events"]["t"])
    assert record["events"] == len(t) and 0 < len(t) < len(all_t)
    times = [f["timestamp"] for f in expected]
    assert t.min() >= (times[0] - 0.35) * 1e6 and t.max() <= (times[-1] + 0.25) * 1e6
    assert {p: p.stat().st_mtime_ns for p in tiny_dataset.rglob("*")} == before


def _fruit(x: float, views: int = 5, y: float = 0.0) -> Fruit:
    return Fruit(np.array([x, y, 1.0]), 0.08, views, views, 20.0, 1.0)


def _centres(fruit: List[Fruit]) -> List[float]:
    return sorted(round(float(f.centre[0]), 3) for f in fruit)


def test_fruit_in_an_overlap_are_counted_once_from_the_segment_that_saw_them_best() -> None:
    cameras = np.stack([np.arange(30) * 0.1, np.full(30, -2.8), np.full(30, 1.4)], axis=1)  # frame k at x = 0.1 k
    segments = [Segment(0, 0, 20), Segment(1, 10, 30)]  # share frames 10-19, x 1.0 to 1.9
    first = [_fruit(0.3), _fruit(1.20, views=3), _fruit(1.50, views=6), _fruit(1.56, views=6), _fruit(1.8, views=4)]
    second = [_fruit(1.23, views=7), _fruit(1.52, views=2), _fruit(1.58, views=2), _fruit(1.79, views=4),
              _fruit(2.6)]  # fmt: skip
    joined = join_fruit([first, second], segments, cameras, distance=0.1)
    kept = [r.fruit for r in joined.fruit]
    # one fruit per true fruit: 0.3 and 2.6 pass through, four pairs joined, the two close fruit kept apart
    assert _centres(kept) == [0.3, 1.23, 1.5, 1.56, 1.79, 2.6]
    assert joined.pairs == {(0, 1): 4} and sorted(joined.copies) == [1, 1, 2, 2, 2, 2]
    by_x = {round(float(r.fruit.centre[0]), 2): r for r in joined.fruit}
    assert by_x[1.23].segment == 1, "the copy with more views is kept"
    assert by_x[1.5].segment == 0 and by_x[1.56].segment == 0
    assert by_x[1.79].segment == 1, "equal views: the copy nearer its segment's middle (frame 19.5, not 9.5)"
    # outside the overlap two segments' fruit are not joined, however close (nor are one segment's own)
    lone = join_fruit([[_fruit(0.30), _fruit(0.33)], [_fruit(0.32)]], segments, cameras, distance=0.1)
    assert len(lone.fruit) == 3 and not lone.pairs
    # farther apart than the join distance: two fruit
    apart = join_fruit([[_fruit(1.4)], [_fruit(1.4, y=0.15)]], segments, cameras, distance=0.1)
    assert len(apart.fruit) == 2


def test_double_counts_are_second_copies_of_one_true_fruit() -> None:
    truth = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [2.0, 0.0, 1.0]])
    visible = np.array([True, True, False])
    predicted = np.array([[0.01, 0, 1], [0.03, 0, 1], [1.0, 0.02, 1], [1.5, 0, 1], [2.0, 0, 1], [2.02, 0, 1]])
    assert double_counts(predicted, truth, visible, 0.05) == 1  # the second copy at 0; 2.02 is of a hidden fruit
    assert double_counts(predicted[[0, 2, 3]], truth, visible, 0.05) == 0


def test_yield_bins_along_the_driven_path() -> None:
    cameras = np.stack([np.linspace(0, 5.0, 51), np.full(51, -2.8), np.full(51, 1.4)], axis=1)
    fruit = np.array([[0.2, 0.1, 1.0], [0.7, 0.3, 1.2], [1.45, -0.1, 0.9], [4.5, 0.0, 1.0], [4.95, 0.0, 1.0]])
    along = along_row(fruit, cameras)
    assert np.allclose(along, fruit[:, 0], atol=1e-9)
    bins = yield_bins(along, 5.0, 1.5, truth_positions=np.array([0.1, 1.6, 1.7, 4.9]))
    assert np.allclose(bins.edges, [0, 1.5, 3.0, 4.5, 5.0])
    assert bins.counts.tolist() == [3, 0, 0, 2] and bins.truth is not None and bins.truth.tolist() == [1, 2, 0, 1]
    assert np.allclose(bins.per_metre, [2.0, 0.0, 0.0, 4.0])  # the last bin is 0.5 m long
    r, lo, hi = correlation(np.arange(1, 7), np.array([1.1, 2.2, 2.9, 4.2, 5.0, 6.1]))
    assert 0.99 < r <= 1 and lo < r < hi
    with pytest.raises(ValueError, match="--bin-m must be positive"):
        yield_bins(along, 5.0, 0.0)


def test_a_long_synthetic_row_has_the_same_plants_where_the_rows_overlap() -> None:
    from agrinerf_ns.synth import SynthConfig
    from agrinerf_ns.synth.capture import make_scene
    from agrinerf_ns.synth.config import SynthConfigError, views_for_row

    assert views_for_row(30.0, 0.75, 10.0) == 401 and views_for_row(3.6, 0.75, 10.0) == 49
    with pytest.raises(SynthConfigError, match="under one frame step"):
        views_for_row(0.01, 0.75, 10.0)
    short, _ = make_scene(SynthConfig.tiny(views=49))
    long, _ = make_scene(SynthConfig.tiny(views=views_for_row(12.0, 0.75, 10.0)))

    def plants(fruits: List[dict]) -> List[dict]:  # ids and plant numbers count from the row's start: they move
        return [{k: v for k, v in f.items() if k not in ("id", "plant")} for f in fruits if -5 < f["center"][0] < 8]

    inside = plants(short.fruits)
    assert inside and inside == plants(long.fruits)
    assert len(long.fruits) > len(short.fruits)


def _rows(path: Path) -> List[dict]:
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


def _row_args(capture: Path, out: Path, **changes) -> "RowArgs":
    from agrinerf_ns.row.cli import RowArgs

    settings = dict(segment_frames=10, overlap_frames=4, steps=30, rays_per_batch=256, bin_m=0.5) | changes
    return RowArgs(out=out, raw=capture, **settings)  # type: ignore[arg-type]


@pytest.fixture(scope="module")
def tiny_row(tiny_capture: Path) -> Tuple[Path, dict]:
    """The tiny capture's row in this process: processed once, two segments cut, trained (30 steps) and counted,
    joined. Its folder and summary."""
    from agrinerf_ns.row.cli import main

    out = tiny_capture.parent / "row"
    summary = main(_row_args(tiny_capture, out))
    assert summary is not None
    return out, summary


@pytest.mark.slow
def test_a_tiny_row_from_a_raw_capture_through_the_jobs_and_resumed(
    tiny_capture: Path, tiny_row: Tuple[Path, dict], tmp_path: Path
) -> None:
    """Its plan, files and tables agree; run again, no step is redone and the row is the same; a row cut otherwise,
    a row folder inside the capture and a capture too short are refused before any work."""
    from agrinerf_ns.row.cli import main

    out, summary = tiny_row
    plan = json.loads((out / "plan.json").read_text())
    assert plan["segments"] == [[0, 10], [6, 16]] and plan["frames"] == 16
    for name in ("fruits.csv", "fruits.ply", "row_yield.csv", "row_map.png", "row.md", "row.json"):
        assert (out / "row" / name).stat().st_size > 0, name
    fruit = _rows(out / "row" / "fruits.csv")
    alone = sum(len(_rows(out / "segments" / s / "count" / "fruits.csv")) for s in ("seg00", "seg01"))
    assert len(fruit) == summary["fruit"] <= alone == summary["segments_alone"]
    assert alone - len(fruit) == sum(int(f["copies"]) - 1 for f in fruit)
    assert sum(int(b["fruit"]) for b in _rows(out / "row" / "row_yield.csv")) == len(fruit)
    truth = summary["truth"]  # the raw capture's truth, scored by the count's scorer
    assert truth["row"]["fruit"] == len(fruit) and truth["alone"]["fruit"] == alone and truth["row"]["visible"] > 0
    assert truth["segments_own"]["segments"] == 2
    report = (out / "row" / "row.md").read_text()
    assert "the row, joined" in report and "seg01" in report and "train (sum)" in report
    assert {s["segment"] for s in summary["segments"]} == {"seg00", "seg01"}
    steps = [out / "capture" / "process.json", *sorted(out.glob("segments/*/*.json"))]
    assert len(steps) == 1 + 3 * 2  # process, and cut, train, count of each segment
    records = {p: p.stat().st_mtime_ns for p in steps}
    rows = (out / "row" / "fruits.csv").read_text()
    again = main(_row_args(tiny_capture, out))
    assert again is not None and again["fruit"] == summary["fruit"]
    assert {p: p.stat().st_mtime_ns for p in records} == records, "finished steps were redone"
    assert (out / "row" / "fruits.csv").read_text() == rows
    with pytest.raises(RowInputError, match="cut differently"):
        main(_row_args(tiny_capture, out, segment_frames=9, overlap_frames=3))
    with pytest.raises(RowInputError, match="inside the input"):
        main(_row_args(tiny_capture, tiny_capture / "row"))
    with pytest.raises(RowInputError, match="16 frames are too few"):
        main(_row_args(tiny_capture, tmp_path / "short", segment_frames=12))
    assert not (tmp_path / "short").exists() and not (tiny_capture / "row").exists()


@pytest.mark.slow
@pytest.mark.usefixtures("local_ray")
def test_the_row_on_ray_with_a_worker_killed_mid_training_is_the_same_row(
    tiny_capture: Path, tiny_row: Tuple[Path, dict], tmp_path: Path
) -> None:
    """The same row as Ray tasks on a local Ray of 2 CPUs; the worker training the second segment is killed once
    ns-train runs: the training is retried, the row finishes, and its fruits.csv is the one made in this process."""
    import ray
    from test_orchestrate_ray import _alive, _kill_worker_once_training

    from agrinerf_ns.orchestrate.jobs import attempts
    from agrinerf_ns.row.cli import main

    out = tmp_path / "row"
    victim = out / "segments" / "seg01"
    killed: Dict[str, int] = {}
    stop = threading.Event()
    killer = threading.Thread(target=_kill_worker_once_training, args=(victim, killed, stop), daemon=True)
    killer.start()
    try:
        address = ray.get_runtime_context().gcs_address  # the local Ray of the fixture
        summary = main(_row_args(tiny_capture, out, ray=address, cpus_per_task=1))
    finally:
        stop.set()
    assert killed, "the worker was not killed: the training finished before ns-train started?"
    assert summary is not None and not (out / "failures.md").exists()
    assert len(attempts(victim)) == 4, "cut, train killed, train again, count"
    assert not _alive(killed["trainer"]), "the killed worker's ns-train is still running"
    assert (out / "row" / "fruits.csv").read_text() == (tiny_row[0] / "row" / "fruits.csv").read_text()


def test_a_lit_row_counted_from_its_fruit_bodies_without_training(tmp_path: Path, tiny_dataset: Path) -> None:
    """``--count-from bodies``: the segments are cut and their fruit bodies counted, no run trained; the row joins
    them and scores them against the truth; a dataset without bodies is refused before any work."""
    from agrinerf_ns.count.pipeline import CountConfig
    from agrinerf_ns.process.capture_to_dataset import ProcessConfig
    from agrinerf_ns.row.cli import RowArgs, main
    from agrinerf_ns.synth import SynthConfig, generate_capture

    raw = generate_capture(SynthConfig(scene="garden", lighting="bright", views=24, width=160, height=120, heldout=0,
                                       rgb_hfov_deg=22.0, thermal_hfov_deg=20.0, event_substeps=1,
                                       event_supersample=1), tmp_path / "raw")  # fmt: skip
    out = tmp_path / "row"
    settings = dict(segment_frames=12, overlap_frames=4, bin_m=0.5, count=CountConfig(max_range=2.4),
                    process=ProcessConfig(poses="given", show_progress=False))  # fmt: skip
    summary = main(RowArgs(out=out, raw=raw, count_from="bodies", **settings))  # type: ignore[arg-type]
    assert summary is not None
    plan = json.loads((out / "plan.json").read_text())
    assert plan["count_from"] == "bodies" and len(plan["segments"]) >= 2
    records = sorted(p.name for p in out.glob("segments/*/*.json"))
    assert records == sorted(["count.json", "cut.json"] * len(plan["segments"]))  # no training
    assert not list(out.glob("segments/*/runs"))
    fruit = _rows(out / "row" / "fruits.csv")
    assert 0 < len(fruit) == summary["fruit"] <= summary["segments_alone"]
    assert "counted from its fruit bodies with no training" in (out / "row" / "row.md").read_text()
    truth = summary["truth"]["row"]
    assert truth["precision"] * truth["fruit"] >= 5 and truth["precision"] >= 0.4 and truth["f1_countable"] > 0.3
    framed = summary["truth"]["row_in_segment_frames"]  # the same fruit and truth, each fruit aligned as its segment
    assert framed["fruit"] == truth["fruit"] and framed["visible"] == truth["visible"] and framed["f1"] > 0.3
    assert "each fruit aligned as its segment" in (out / "row" / "row.md").read_text()
    again = main(RowArgs(out=out, raw=raw, count_from="bodies", **settings))  # type: ignore[arg-type]
    assert again is not None and _rows(out / "row" / "fruits.csv") == fruit
    with pytest.raises(RowInputError, match="cut differently"):
        main(RowArgs(out=out, raw=raw, **settings))  # type: ignore[arg-type]  # the same cut, counted otherwise
    with pytest.raises(RowInputError, match="fruit_bodies.json: missing"):
        main(RowArgs(out=tmp_path / "none", data=tiny_dataset, count_from="bodies", segment_frames=10,
                     overlap_frames=4))  # fmt: skip
    assert not (tmp_path / "none").exists()
