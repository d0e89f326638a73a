"""agrinerf-count: clustering, the lift to 3D, blob detection, scoring against the truth, the CLI and its errors."""

from __future__ import annotations

import csv
import json
from dataclasses import replace
from pathlib import Path
from typing import List, Tuple

import cv2
import numpy as np
import pytest
from helpers.tiny_scene import cast_sphere_view

from agrinerf_ns.count.cli import CountArgs, main
from agrinerf_ns.count.cluster import ClusterConfig, Fruit, cluster_fruit
from agrinerf_ns.count.detectors import DetectorConfig, fruit_in_view, view_source
from agrinerf_ns.count.fruit_score import (
    TruthFruit,
    align_to_capture,
    read_truth_fruit,
    score_fruit,
    visible_fruit,
)
from agrinerf_ns.count.lift import LiftedDetection, lift_detection
from agrinerf_ns.count.pipeline import CountConfig
from agrinerf_ns.count.render import (
    CountInputError,
    RenderedView,
    RenderSet,
    WorldFrame,
    load_renders,
    require_depth,
    save_renders,
)
from agrinerf_ns.count.support import keep_supported, views_showing
from agrinerf_ns.fruit.blobs import BlobConfig, surround_sides
from agrinerf_ns.lab.count_diagnose import diagnose
from agrinerf_ns.lab.count_oracle import oracle_renders, reproject_thermal, undistort_maps, with_true_depth
from agrinerf_ns.process.readers import CameraCalib, read_calibration
from agrinerf_ns.run_loading import dataset_folder

IDENTITY = WorldFrame(np.eye(4)[:3], 1.0)
FRUIT_D = 0.08
"""A fruit's diameter in the hand-made point sets (metres)."""


def _detections(centre, views: int, noise: float, rng: np.random.Generator, first_view: int = 0):
    return [
        LiftedDetection(first_view + v, np.asarray(centre) + rng.normal(0, noise, 3), FRUIT_D, 1.0, 20.0)
        for v in range(views)
    ]


def test_two_fruit_a_fruit_width_apart_are_two() -> None:
    rng = np.random.default_rng(0)
    points = _detections([0, 0, 1], 10, 0.05 * FRUIT_D, rng) + _detections([FRUIT_D, 0, 1], 10, 0.05 * FRUIT_D, rng)
    fruit = cluster_fruit(points)
    assert len(fruit) == 2
    assert sorted(f.views for f in fruit) == [10, 10]
    assert sorted(round(float(f.centre[0]) / FRUIT_D) for f in fruit) == [0, 1]


def test_one_fruit_seen_from_ten_views_is_one() -> None:
    rng = np.random.default_rng(1)
    points = _detections([1.0, 2.0, 0.5], 10, 0.1 * FRUIT_D, rng)
    fruit = cluster_fruit(points)
    assert len(fruit) == 1
    assert fruit[0].views == 10 and fruit[0].detections == 10
    assert np.linalg.norm(fruit[0].centre - [1.0, 2.0, 0.5]) < 0.1 * FRUIT_D
    assert fruit[0].temperature == pytest.approx(20.0)
    assert cluster_fruit(points, ClusterConfig(min_views=11)) == []
    assert cluster_fruit(points[:1]) == []  # one view is not enough by default


def _sphere_view(index: int, views: int = 10, width: int = 64, height: int = 48):
    """A view of the tiny scene's unit sphere with its truth depth (along the unit ray) as the rendered depth."""
    sphere = cast_sphere_view(index, views, width, height, 0.9 * width)
    origins = np.broadcast_to(sphere.c2w[:3, 3], sphere.points.shape).copy()
    depth = np.where(sphere.hit, np.linalg.norm(sphere.points - origins, axis=-1), 0.0)
    view = RenderedView(
        f"frame_{index:05d}", "train", f"images/frame_{index:05d}.png", np.zeros((height, width, 3)), depth,
        sphere.hit.astype(np.float64), origins, sphere.dirs, 0.9 * width,
    )  # fmt: skip
    return view, sphere.hit


def test_lift_from_depth_back_to_the_true_centre() -> None:
    """Each view's sphere pixels lift to within 0.15 radius of the true centre (the cap-median model assumes a
    far sphere; this one spans a third of the view), and the fused fruit to within 0.05 radius; diameter within 5%."""
    lifted: List[LiftedDetection] = []
    for i in range(10):
        view, hit = _sphere_view(i)
        point = lift_detection(view, hit, IDENTITY, i)
        assert point is not None
        assert np.linalg.norm(point.centre) < 0.15
        assert point.diameter == pytest.approx(2.0, rel=0.05)
        lifted.append(point)
    fruit = cluster_fruit(lifted, ClusterConfig(min_views=10))
    assert len(fruit) == 1 and np.linalg.norm(fruit[0].centre) < 0.05


def test_a_fruit_seen_well_in_one_view_counts_where_its_depth_is_confident() -> None:
    """One view of the sphere, at its true depth on an opaque surface: counted with --single-view-confidence (by
    default two views are needed); the same view with its depth smeared by the field, or its density faint, is not."""
    view, hit = _sphere_view(0)
    solid = lift_detection(view, hit, IDENTITY, 0)
    assert solid is not None and solid.depth_confidence > 0.95
    config = ClusterConfig(single_view_confidence=0.8)
    assert cluster_fruit([solid]) == [] and len(cluster_fruit([solid], config)) == 1
    rng = np.random.default_rng(0)
    smeared = replace(view, depth=view.depth + rng.uniform(-3.0, 3.0, view.depth.shape))  # +-3 fruit radii
    faint = replace(view, accumulation=0.5 * view.accumulation)
    for other in (smeared, faint):
        lifted = lift_detection(other, hit, IDENTITY, 0)
        assert lifted is not None and lifted.depth_confidence < 0.5
        assert cluster_fruit([lifted], config) == []


def test_lift_goes_through_the_dataparser_frame() -> None:
    """The same sphere in a scaled, rotated, shifted Nerfstudio frame lifts to the same dataset-frame centre."""
    angle = 0.3
    rot = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]])
    frame = WorldFrame(np.concatenate([rot, [[0.1], [-0.2], [0.3]]], axis=1), 0.25)
    view, hit = _sphere_view(3)
    view.origins = frame.to_ns(view.origins.reshape(-1, 3)).reshape(view.origins.shape)
    view.directions = (view.directions.reshape(-1, 3) @ rot.T).reshape(view.directions.shape)
    view.depth = view.depth * frame.scale
    point = lift_detection(view, hit, frame)
    reference = lift_detection(_sphere_view(3)[0], hit, IDENTITY)
    assert point is not None and reference is not None
    assert np.allclose(point.centre, reference.centre, atol=1e-5)
    assert point.diameter == pytest.approx(reference.diameter, rel=1e-5)


def _plane_view(thermal: np.ndarray, rgb: np.ndarray, depth: float, focal: float) -> RenderedView:
    height, width = thermal.shape
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    dirs = np.stack([(u - width / 2) / focal, -(v - height / 2) / focal, -np.ones_like(u)], -1)
    norm = np.linalg.norm(dirs, axis=-1, keepdims=True)
    return RenderedView(
        "000000", "train", "images/000000.png", rgb, depth * norm[..., 0], np.ones((height, width)),
        np.zeros((height, width, 3)), dirs / norm, focal, thermal=thermal,
    )  # fmt: skip


def test_blobs_find_warm_cool_and_coloured_fruit() -> None:
    """A leaf-coloured, leaf-temperature plane at 1.5 m with 6 cm fruit (8 px at focal 200): three warm, one cool,
    two red; and a large warm patch (a trunk-sized 40 cm blob) that is not fruit-sized."""
    rng = np.random.default_rng(0)
    height, width, focal = 96, 128, 200.0
    thermal = 0.4 + rng.normal(0, 0.01, (height, width))
    rgb = np.tile(np.array([0.10, 0.26, 0.06]), (height, width, 1)) + rng.normal(0, 0.01, (height, width, 3))
    for x, y, delta in ((20, 20, 0.1), (60, 25, 0.12), (100, 20, 0.1), (30, 70, -0.1)):
        cv2.circle(thermal, (x, y), 4, 0.4 + delta, -1)
    for x, y in ((70, 70), (105, 75)):
        cv2.circle(rgb, (x, y), 4, (0.7, 0.08, 0.05), -1)
    cv2.rectangle(thermal, (60, 45), (110, 95), 0.6, -1)  # 40 cm wide at 1.5 m: not a fruit
    view = _plane_view(thermal.astype(np.float32), np.clip(rgb, 0, 1).astype(np.float32), 1.5, focal)
    both = fruit_in_view(view, "thermal", 1.0, BlobConfig())
    warm = fruit_in_view(view, "thermal", 1.0, BlobConfig(polarity="warm"))
    red = fruit_in_view(view, "rgb", 1.0, BlobConfig())
    assert (len(both), len(warm), len(red)) == (4, 3, 2)
    # the same scene as a temperature render in degrees C (leaves 20 C, fruit +-3 C): the same fruit
    view.temperature = (20.0 + 30.0 * (thermal - 0.4)).astype(np.float32)
    assert len(fruit_in_view(view, "temperature", 1.0, BlobConfig())) == 4
    assert view_source(DetectorConfig(), view) == "temperature"  # auto: what the run renders
    assert view_source(DetectorConfig(detector="yolo"), view) == "thermal"
    assert view_source(DetectorConfig(source="rgb"), view) == "rgb"
    view.temperature = None
    assert view_source(DetectorConfig(), view) == "thermal"
    with pytest.raises(ValueError, match="no 'temperature' output"):
        fruit_in_view(view, "temperature", 1.0, BlobConfig())
    view.thermal = None
    assert view_source(DetectorConfig(), view) == "rgb"
    with pytest.raises(ValueError, match="no cross-spectral 'thermal' output"):
        fruit_in_view(view, "thermal", 1.0, BlobConfig())
    view.thermal = thermal.astype(np.float32)
    frame_points = [lift_detection(view, d.mask, IDENTITY) for d in warm]
    assert all(p is not None and p.diameter == pytest.approx(0.06, rel=0.3) for p in frame_points)
    view.rgb = None  # a run trained without RGB frames (Table IV "Thermal"): its thermal fruit, no colour ones
    assert len(fruit_in_view(view, "thermal", 1.0, BlobConfig())) == 4
    assert view_source(DetectorConfig(), view) == "thermal"
    with pytest.raises(ValueError, match="view 000000: the run renders no 'rgb' output"):
        fruit_in_view(view, "rgb", 1.0, BlobConfig())


def test_renders_of_a_run_without_rgb_round_trip(tmp_path: Path) -> None:
    """A view without an RGB output is saved and read back without one; its other outputs are kept."""
    thermal = np.full((8, 10), 0.5, np.float32)
    view = _plane_view(thermal, np.zeros((8, 10, 3), np.float32), 1.5, 20.0)
    view.rgb = None
    save_renders(RenderSet([view], IDENTITY, None, None, "agrinerf-lite"), tmp_path / "renders")
    (loaded,) = load_renders(tmp_path / "renders").views
    assert loaded.rgb is None and loaded.thermal is not None and np.allclose(loaded.thermal, thermal)
    assert np.allclose(loaded.depth, view.depth)


@pytest.mark.slow
def test_the_yolo_detector_gives_each_box_as_its_ellipse_where_rendered(tmp_path: Path) -> None:
    """``--detector yolo`` with a real Ultralytics model (untrained, from its YAML; nothing downloaded): each
    detection is the inscribed ellipse of one of the model's boxes on the view's 8-bit RGB, cut to rendered pixels."""
    pytest.importorskip("ultralytics", reason="optional [detect] extra: scripts/install_detect.sh")
    from agrinerf_ns.count.detectors import make_detector
    from agrinerf_ns.fruit.ellipse import inscribed_ellipse
    from agrinerf_ns.fruit.yolo import box_predictor, configure_offline

    configure_offline()
    from ultralytics import YOLO

    weights = tmp_path / "untrained.pt"
    YOLO("yolov8n.yaml").save(str(weights))
    rng = np.random.default_rng(0)
    view = _plane_view(rng.random((48, 64)).astype(np.float32), rng.random((48, 64, 3)).astype(np.float32), 1.5, 60.0)
    view.accumulation[:, :8] = 0.0  # nothing rendered there
    detections = make_detector(DetectorConfig(detector="yolo", source="rgb", weights=weights, confidence=1e-4))(
        view, 1.0
    )
    boxes, scores = box_predictor(weights, 1e-4)(
        np.ascontiguousarray((view.rgb[..., ::-1] * 255).round().astype(np.uint8))
    )
    assert len(detections) == len(boxes) > 0
    for detection, box, score in zip(detections, boxes, scores, strict=True):
        assert detection.score == pytest.approx(score)
        assert np.array_equal(detection.mask, inscribed_ellipse(48, 64, box) & (view.accumulation >= 0.5))
        assert not detection.mask[:, :8].any()


def _truth(n: int = 4) -> TruthFruit:
    centres = np.array([[0.2 * i, 0.0, 0.5] for i in range(n)])
    return TruthFruit(centres, np.full(n, 0.06), np.arange(n))


def test_scoring_is_one_on_the_truth_and_zero_in_empty_space() -> None:
    truth = _truth()
    perfect = score_fruit(truth.centres, truth, match_distance=0.05)
    assert (perfect.precision, perfect.recall, perfect.f1, perfect.count_error) == (1.0, 1.0, 1.0, 0.0)
    empty = score_fruit(truth.centres + [0.0, 5.0, 0.0], truth, match_distance=0.05)
    assert (empty.precision, empty.recall, empty.f1) == (0.0, 0.0, 0.0)
    assert empty.false_positives == 4 and empty.false_negatives == 4
    # one-to-one: two counted fruit at one true fruit are one hit and one false positive
    twice = score_fruit(np.array([[0.0, 0.0, 0.5], [0.01, 0.0, 0.5]]), truth, match_distance=0.05)
    assert (twice.true_positives, twice.false_positives, twice.false_negatives) == (1, 1, 3)
    # a fruit no training view shows is neither missed nor a false positive when counted
    hidden = score_fruit(truth.centres, truth, np.array([True, True, True, False]), match_distance=0.05)
    assert (hidden.visible, hidden.true_positives, hidden.false_positives, hidden.f1) == (3, 3, 0, 1.0)
    # the well-seen denominator: recall over fruit 0 and 1 only; a hit on fruit 2 (visible, not well seen) is no
    # false positive
    found = score_fruit(truth.centres[1:3], truth, well_seen=np.array([True, True, False, False]), match_distance=0.05)
    assert (found.well_seen, found.recall_well_seen, found.precision) == (2, 0.5, 1.0)
    assert found.f1_well_seen == pytest.approx(2 / 3) and found.count_error_well_seen == 0.0
    assert score_fruit(truth.centres, truth, match_distance=0.05).well_seen == -1  # not computed
    # the countable tier sits between them: fruit 0-2 countable, a count of fruit 1 and 2 finds two of three
    tiered = score_fruit(truth.centres[1:3], truth, well_seen=np.array([True, True, False, False]),
                         countable=np.array([True, True, True, False]), match_distance=0.05)  # fmt: skip
    assert (tiered.countable, tiered.recall_countable, tiered.count_error_countable) == (3, 2 / 3, -1 / 3)
    assert tiered.f1_countable == pytest.approx(0.8) and tiered.recall_well_seen == 0.5


def test_tier_scores_give_every_tier_at_every_match_distance() -> None:
    from agrinerf_ns.count.fruit_score import TIER_DISTANCES, tier_scores

    truth = _truth()
    # fruit 0 placed 0.08 m off, fruit 1 0.12 m off, fruit 2 exactly; fruit 3 never counted
    counted = truth.centres[:3] + np.array([[0.08, 0.0, 0.0], [0.0, 0.12, 0.0], [0.0, 0.0, 0.0]])
    tiers = {"visible": np.ones(4, bool), "countable": np.array([True, True, True, False]),
             "well_seen": np.array([False, True, True, False])}  # fmt: skip
    table = tier_scores(counted, truth, tiers)
    assert list(table) == ["visible", "countable", "well_seen"] and list(table["visible"]) == ["0.05", "0.1", "0.15"]
    assert TIER_DISTANCES == (0.05, 0.10, 0.15)
    hits = {"0.05": 1, "0.1": 2, "0.15": 3}  # a looser match takes the fruit placed farther off
    for d, n in hits.items():
        assert table["visible"][d]["precision"] == pytest.approx(n / 3)
        assert table["visible"][d]["recall"] == pytest.approx(n / 4)
        assert table["countable"][d]["recall"] == pytest.approx(n / 3)
    assert table["well_seen"]["0.05"]["recall"] == 0.5 and table["well_seen"]["0.15"]["recall"] == 1.0
    assert (table["visible"]["0.05"]["truth"], table["countable"]["0.05"]["truth"]) == (4, 3)
    assert table["countable"]["0.05"]["count_error"] == 0.0 and table["visible"]["0.1"]["count_error"] == -0.25


def _write_truth_capture(raw: Path, truth: TruthFruit) -> None:
    (raw / "truth" / "fruit_ids").mkdir(parents=True)
    fruits = [
        {"id": int(i), "center": c.tolist(), "radii": [0.03] * 3} for i, c in zip(truth.ids, truth.centres, strict=True)
    ]
    (raw / "truth" / "fruits.json").write_text(json.dumps(fruits))
    ids = np.zeros((20, 20), np.uint16)
    ids[0, :5] = 1  # fruit 0: 5 pixels
    ids[1, :2] = 2  # fruit 1: 2 pixels, below the 3 a fruit needs to be visible
    cv2.imwrite(str(raw / "truth" / "fruit_ids" / "000000.png"), ids)
    ids = np.zeros((20, 20), np.uint16)
    ids[5:8, 5:8] = 3  # fruit 2, in a frame that is not a training frame
    cv2.imwrite(str(raw / "truth" / "fruit_ids" / "000001.png"), ids)


def test_visible_fruit_and_the_alignment_to_the_capture(tmp_path: Path) -> None:
    truth = _truth()
    raw, data = tmp_path / "raw", tmp_path / "data"
    _write_truth_capture(raw, truth)
    assert read_truth_fruit(raw).centres.shape == (4, 3)
    assert visible_fruit(raw, ["000000"], truth).tolist() == [True, False, False, False]
    assert visible_fruit(raw, ["000000", "000001"], truth).tolist() == [True, False, True, False]
    # a dataset whose frame is the capture's rotated by 90 degrees about z, halved and shifted
    rng = np.random.default_rng(2)
    times = np.arange(6) * 0.1
    centres = rng.uniform(-1, 1, (6, 3))
    lines = [f"{t:.6f} {x} {y} {z} 0 0 0 1\n" for t, (x, y, z) in zip(times, centres, strict=True)]
    (raw / "truth" / "poses.txt").write_text("".join(lines))
    rot = np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])
    frames = []
    for k, (t, c) in enumerate(zip(times, centres, strict=True)):
        c2w = np.eye(4)
        c2w[:3, :3] = rot @ np.diag([1.0, -1.0, -1.0])  # the same camera (identity in the capture), OpenGL axes
        c2w[:3, 3] = 0.5 * rot @ c + [1.0, 2.0, 3.0]
        frames.append({"file_path": f"images/{k:06d}.png", "timestamp": float(t), "transform_matrix": c2w.tolist()})
    data.mkdir()
    (data / "transforms.json").write_text(json.dumps({"frames": frames}))
    align = align_to_capture(data, raw)
    assert align.scale == pytest.approx(2.0) and align.residual_rms < 1e-9
    assert np.allclose(align.apply(0.5 * centres @ rot.T + [1.0, 2.0, 3.0]), centres)


def test_a_capture_without_truth_fruit_is_named(tmp_path: Path) -> None:
    with pytest.raises(CountInputError, match=r"truth/fruits.json: missing"):
        read_truth_fruit(tmp_path)
    (tmp_path / "truth").mkdir()
    (tmp_path / "truth" / "fruits.json").write_text("[]")
    with pytest.raises(CountInputError, match=r"fruits.json: the scene has no true fruit"):
        read_truth_fruit(tmp_path)


def test_a_run_without_depth_and_an_empty_render_folder_are_named(tmp_path: Path, capsys) -> None:
    with pytest.raises(CountInputError, match=r"run/config.yml: the run's model renders no 'depth' output"):
        require_depth({"rgb": None, "accumulation": None}, Path("run/config.yml"))
    empty = tmp_path / "renders"
    empty.mkdir()
    with pytest.raises(CountInputError, match=r"renders: empty render folder"):
        load_renders(empty)
    with pytest.raises(SystemExit) as stop:
        main(CountArgs(out=tmp_path / "out", renders=empty))
    assert stop.value.code == 2 and "empty render folder" in capsys.readouterr().out
    # a render folder whose views lack depth
    np.savez(empty / "train_000000.npz", rgb=np.zeros((2, 2, 3)))
    (empty / "renders.json").write_text(json.dumps({
        "dataparser_transform": np.eye(4)[:3].tolist(), "dataparser_scale": 1.0,
        "views": [{"name": "000000", "split": "train", "file_path": "images/000000.png"}],
    }))  # fmt: skip
    with pytest.raises(CountInputError, match=r"train_000000.npz: no 'depth' array"):
        load_renders(empty)
    assert not (tmp_path / "out").exists()


def test_the_dataset_folder_of_a_run_trained_on_a_folder_or_on_its_transforms_file(tmp_path: Path) -> None:
    """`ns-train --data` takes either; `agrinerf-bench` passes the transforms file."""
    assert dataset_folder(tmp_path / "data") == tmp_path / "data"
    assert dataset_folder(tmp_path / "data" / "transforms.json") == tmp_path / "data"
    assert dataset_folder(tmp_path / "data" / "transforms_thermal.json") == tmp_path / "data"


def test_count_a_trained_run(tiny_run_config: Path, tmp_path: Path) -> None:
    """The tiny run's held-out view through the whole command: rays in the dataset's frame, files written, and a
    second count from the saved renders."""
    out = tmp_path / "count"
    main(
        CountArgs(
            out=out,
            config=tiny_run_config,
            path="views",
            splits=("eval",),
            count=CountConfig(cluster=ClusterConfig(min_views=1)),
        )
    )
    names = {p.name for p in out.iterdir()}
    assert {"fruits.csv", "fruits.ply", "fruit_map.png", "count.json", "renders"} <= names
    renders = load_renders(out / "renders")
    (view,) = renders.views
    assert renders.dataset is not None and renders.config == tiny_run_config
    assert np.allclose(np.linalg.norm(view.directions, axis=-1), 1.0, atol=1e-5)
    transforms = json.loads((renders.dataset / "transforms.json").read_text())
    c2w = {f["file_path"]: np.asarray(f["transform_matrix"]) for f in transforms["frames"]}[view.file_path]
    assert np.allclose(renders.frame.to_dataset(view.origins[0, :1])[0], c2w[:3, 3], atol=1e-4)
    assert view.depth.shape == view.rgb.shape[:2] and view.thermal is not None

    with open(out / "fruits.csv") as handle:
        header = next(csv.reader(handle))
    assert header[:4] == ["id", "x", "y", "z"] and "temperature_c" in header
    report = json.loads((out / "count.json").read_text())
    assert report["views"] == 1 and report["fruit"] == sum(1 for _ in open(out / "fruits.csv")) - 1
    ply = (out / "fruits.ply").read_bytes()
    assert ply.startswith(b"ply\nformat binary_little_endian 1.0\n") and b"element vertex" in ply
    with pytest.raises(SystemExit):
        main(CountArgs(out=out, renders=out / "renders"))  # exists: not replaced without --overwrite
    again = main(
        CountArgs(
            out=tmp_path / "again", renders=out / "renders", count=CountConfig(cluster=ClusterConfig(min_views=1))
        )
    )
    assert len(again.fruit) == report["fruit"]  # the same views give the same count without rendering


@pytest.fixture(scope="module")
def tiny_capture(tmp_path_factory) -> Tuple[Path, Path]:
    """The tiny agrinerf-synth orchard (8 views of 64x48) and its dataset (poses given, odometry drift included)."""
    from agrinerf_ns.process import ProcessConfig, process_capture
    from agrinerf_ns.synth import SynthConfig, generate_capture

    root = tmp_path_factory.mktemp("count_synth")
    generate_capture(SynthConfig.tiny(), root / "raw")
    process_capture(root / "raw", root / "data", ProcessConfig(poses="given", show_progress=False))
    return root / "raw", root / "data"


def test_lift_of_the_true_fruit_masks_lands_on_the_true_centres(tiny_capture: Tuple[Path, Path]) -> None:
    """Every fruit showing at least 3 pixels, lifted from its true mask and the true depth (as a perfect
    reconstruction would render them) and aligned to the capture: median 3D error under 3 cm (fruit are 8-11 cm)."""
    raw, data = tiny_capture
    renders = oracle_renders(raw, data)
    map_x, map_y = undistort_maps(
        read_calibration(raw / "calib.yaml").rgb, json.loads((data / "transforms.json").read_text())
    )
    truth, to_capture = read_truth_fruit(raw), align_to_capture(data, raw)
    errors = []
    for view in renders.views:
        ids = cv2.remap(cv2.imread(str(raw / "truth" / "fruit_ids" / f"{view.name}.png"), -1), map_x, map_y,
                        cv2.INTER_NEAREST)  # fmt: skip
        for fruit_id in np.unique(ids[ids > 0]):
            mask = ids == fruit_id
            if mask.sum() >= 3:
                point = lift_detection(view, mask, renders.frame)
                assert point is not None
                centre = to_capture.apply(point.centre[None])[0]
                errors.append(np.linalg.norm(centre - truth.centres[int(fruit_id) - 1]))
    assert len(errors) > 20 and np.median(errors) < 0.03


def test_count_scores_against_the_synthetic_truth(tiny_capture: Tuple[Path, Path], tmp_path: Path) -> None:
    raw, data = tiny_capture
    save_renders(oracle_renders(raw, data), tmp_path / "renders")
    result = main(CountArgs(out=tmp_path / "count", renders=tmp_path / "renders", truth=raw))
    assert result.score is not None and result.score.visible > 0 and result.to_capture is not None
    assert result.to_capture.residual_rms < 0.05  # the odometry's drift
    report = json.loads((tmp_path / "count" / "count.json").read_text())
    assert report["score"]["visible"] == result.score.visible and set(report["f1_at_distance"]) >= {"0.05", "0.1"}
    assert "| f1 |" in (tmp_path / "count" / "score.md").read_text()
    # the three tiers of truth, each at 0.05, 0.10 and 0.15 m, nested: well seen within countable within visible
    tiers = report["tiers"]
    assert list(tiers) == ["visible", "countable", "well_seen"] and list(tiers["countable"]) == ["0.05", "0.1", "0.15"]
    sizes = [tiers[t]["0.05"]["truth"] for t in tiers]
    assert sizes[0] == result.score.visible and sizes[0] >= sizes[1] >= sizes[2] and sizes[1] == result.score.countable
    assert tiers["countable"]["0.05"]["f1"] == pytest.approx(result.score.f1_countable)
    assert "| countable | " in (tmp_path / "count" / "score.md").read_text()
    with open(tmp_path / "count" / "fruits.csv") as handle:
        assert next(csv.reader(handle))[-4:] == ["x_capture", "y_capture", "z_capture", "truth_id"]


def test_max_range_counts_and_scores_within_the_range_only(tiny_capture: Tuple[Path, Path], tmp_path: Path) -> None:
    """``--max-range``: counted fruit farther than it from every camera are dropped, and so are the true fruit in
    scoring (checked against the capture's true camera path). The range is set to the median distance of the visible
    fruit, so that it splits them; fruit are counted from the truth's fruit pixels (``--source fruit``)."""
    from agrinerf_ns.count.row_range import camera_distance

    raw, data = tiny_capture
    save_renders(oracle_renders(raw, data, fruit_mode="true"), tmp_path / "renders")
    fruit = CountConfig(detect=DetectorConfig(source="fruit"))
    every = main(CountArgs(out=tmp_path / "all", renders=tmp_path / "renders", truth=raw, count=fruit))
    assert every.visible is not None and len(every.fruit) > 4
    truth = read_truth_fruit(raw)
    distance = camera_distance(truth.centres, np.loadtxt(raw / "truth" / "poses.txt")[:, 1:4])
    cut = float(np.median(distance[every.visible]))
    row = main(CountArgs(out=tmp_path / "row", renders=tmp_path / "renders", truth=raw,
                         count=replace(fruit, max_range=cut)))  # fmt: skip
    assert row.visible is not None and row.score is not None
    assert (distance[row.visible] <= cut + 0.05).all() and (distance[every.visible & ~row.visible] > cut - 0.05).all()
    assert 0 < row.visible.sum() < every.visible.sum() and row.score.visible == row.visible.sum()
    assert 0 < len(row.fruit) < len(every.fruit)
    renders = load_renders(tmp_path / "renders")
    cameras = renders.frame.to_dataset(np.stack([v.origins[0, 0] for v in renders.views]).astype(np.float64))
    assert all(camera_distance(f.centre[None], cameras)[0] <= cut for f in row.fruit)
    assert json.loads((tmp_path / "row" / "count.json").read_text())["max_range"] == cut
    with pytest.raises(SystemExit) as stopped:
        main(CountArgs(out=tmp_path / "bad", renders=tmp_path / "renders", count=replace(fruit, max_range=0.0)))
    assert stopped.value.code == 2 and not (tmp_path / "bad").exists()


def test_surround_sides_tell_a_fruit_from_an_edge() -> None:
    """A disc of contrast on a flat background stands out on all four sides; the same disc on the border of a
    region as strong as itself stands out on two only, and the default blob detector drops such a blob."""
    z = np.zeros((40, 40), np.float32)
    disc = np.zeros((40, 40), np.uint8)
    cv2.circle(disc, (20, 20), 3, 1, -1)
    z[disc > 0] = 5.0
    valid = np.ones_like(z, bool)
    assert surround_sides(disc > 0, z, valid) == 4
    z[:, :20] = 5.0
    assert surround_sides(disc > 0, z, valid) == 2
    assert surround_sides(disc > 0, z, valid & (np.arange(40) >= 20)[None, :]) == 2  # no ring on one side: fails


def test_reprojected_thermal_follows_the_baseline() -> None:
    """A thermal camera 10 cm to the right of the RGB camera, same intrinsics, sees a plane at 2 m shifted by
    f x 0.1 / 2 = 4 pixels: the reprojection puts each thermal pixel back on its RGB pixel, NaN off its view."""
    height, width, focal = 48, 64, 80.0
    meta = {"cx": width / 2, "cy": height / 2, "fl_x": focal, "fl_y": focal}
    k = np.array([[focal, 0, width / 2 - 0.5], [0, focal, height / 2 - 0.5], [0, 0, 1.0]])
    to_thermal = np.eye(4)
    to_thermal[0, 3] = -0.1
    camera = CameraCalib("cam1", "thermal", k, np.zeros(4), width, height, to_thermal)
    columns = np.tile(np.arange(width, dtype=np.float32), (height, 1))
    thermal_frame = columns + 4.0  # thermal column c sees the RGB column c + 4
    out = reproject_thermal(thermal_frame, np.full((height, width), 2.0, np.float32), meta, camera)
    inside = np.isfinite(out)
    assert inside[:, 4:].all() and not inside[:, :3].any()
    np.testing.assert_allclose(out[inside], columns[inside], atol=1e-3)
    assert np.isnan(reproject_thermal(thermal_frame, np.full((height, width), np.inf, np.float32), meta, camera)).all()


def test_views_showing_and_the_support_rule() -> None:
    """A wall 2 m in front of four identical cameras: a fruit 1 m in front shows in all four, one behind the wall
    and one outside the field of view in none; a fruit seen by one of four views stays at fraction 0.25, not 0.3."""
    height, width, focal = 48, 64, 80.0
    wall = _plane_view(np.zeros((height, width), np.float32), np.zeros((height, width, 3), np.float32), 2.0, focal)
    views = [wall] * 4
    centres = np.array([[0.1, 0.0, -1.0], [0.0, 0.0, -3.0], [5.0, 0.0, -1.0]])
    assert views_showing(centres, np.full(3, 0.06), views, IDENTITY).tolist() == [4, 0, 0]
    fruit = [Fruit(centres[0], 0.06, views=1, detections=1, temperature=None, score=1.0)]
    assert keep_supported(fruit, views, IDENTITY, 0.25) == fruit
    assert keep_supported(fruit, views, IDENTITY, 0.3) == []
    assert keep_supported(fruit, views, IDENTITY, 0.0) == fruit


def test_reprojected_thermal_and_the_diagnosis_on_the_tiny_capture(tiny_capture: Tuple[Path, Path]) -> None:
    """The raw thermal frames reprojected through the true depth agree with the true temperature (the thermal
    camera's blur and noise aside), and the diagnosis accounts for every detection and the visible fruit."""
    raw, data = tiny_capture
    reprojected, true = oracle_renders(raw, data, "reprojected"), oracle_renders(raw, data, "true")
    errors = []
    for a, b in zip(reprojected.views, true.views, strict=True):
        assert a.temperature is not None and b.temperature is not None
        both = np.isfinite(a.temperature) & np.isfinite(b.temperature) & (a.accumulation > 0)
        errors.append(np.abs(a.temperature[both] - b.temperature[both]))
    assert np.median(np.concatenate(errors)) < 1.0
    report = diagnose(true, raw, CountConfig())
    assert report["detections"] == sum(report["2d"][k] for k in ("hits", "duplicates", "false_blobs"))
    assert report["denominator"]["visible"] == report["score"]["visible"] > 0
    assert report["2d"]["recall"] > 0.3 and report["lift_error_m"]["median"] < 0.03


def test_the_true_depth_under_a_runs_colours_undoes_a_wrong_geometry(tiny_capture: Tuple[Path, Path]) -> None:
    """A render set whose geometry is 40% too far (a field's wrong depth) lifts its fruit off their centres; with the
    capture's true depth put under the same views the lift lands on them again, in the run's own units."""
    raw, data = tiny_capture
    true = oracle_renders(raw, data, "true")
    far = replace(true, views=[replace(v, depth=v.depth * 1.4) for v in true.views])
    wrong, mended = diagnose(far, raw, CountConfig()), diagnose(with_true_depth(far, raw), raw, CountConfig())
    assert wrong["lift_error_m"]["median"] > 0.1
    assert mended["lift_error_m"]["median"] < 0.03 and mended["score"]["f1"] > wrong["score"]["f1"]
    scaled = replace(far, frame=WorldFrame(np.eye(4)[:3], 2.5))  # Nerfstudio units: the dataparser's scale applied
    for got, want in zip(with_true_depth(scaled, raw).views, true.views, strict=True):
        np.testing.assert_allclose(got.depth, 2.5 * want.depth, rtol=1e-6)
    with pytest.raises(CountInputError, match="no frame for the rendered view images/none.png"):
        with_true_depth(replace(far, views=[replace(far.views[0], file_path="images/none.png")]), raw)


def test_the_oracle_fruit_channel_counts_and_the_misses_report_reads_it(
    tiny_capture: Tuple[Path, Path], tmp_path: Path
) -> None:
    """The oracle's fruit channel is the truth's fruit pixels; counted from it, every fruit pixel is found at its true
    depth (benchmarks/fruit_count_misses.py on the oracle itself)."""
    from helpers.bench_script import load_bench_script

    raw, data = tiny_capture
    renders = oracle_renders(raw, data, fruit_mode="true")
    assert all(view.fruit is not None and set(np.unique(view.fruit)) <= {0.0, 1.0} for view in renders.views)
    assert sum(float(view.fruit.sum()) for view in renders.views) > 20  # type: ignore[union-attr]
    save_renders(renders, tmp_path / "renders")
    settings = CountConfig(detect=DetectorConfig(source="fruit"))
    result = main(CountArgs(out=tmp_path / "count", renders=tmp_path / "renders", truth=raw, count=settings))
    # against the truth: measured F1 0.889 (16 of 17 counted fruit true, 3 of 19 visible missed; 2026-12-07, AMD EPYC
    # 2 cores); the truth's own fruit pixels must count most of the visible fruit and little else
    assert result.score is not None and result.score.f1 >= 0.7, result.score
    misses = load_bench_script("fruit_count_misses")
    report = misses.main(misses.MissArgs(tmp_path / "renders", tmp_path / "renders", raw, tmp_path / "count"))
    assert "median 0.000 m, within 5 cm 1.00" in str(report["depth error at found fruit pixels"])
    assert str(report["depth error at missed fruit pixels"]).startswith("0 px")


def test_table_iii_from_the_fruit_channel_scores_the_oracle_and_refuses_a_run_without_one(
    tiny_capture: Tuple[Path, Path], tmp_path: Path
) -> None:
    """`agrinerf-detect fruit`: the oracle's fruit channel (the truth's fruit pixels) boxed region by region finds the
    true boxes; the same views with the channel moved off the fruit find none; a render folder without a fruit
    channel is refused with its name."""
    from agrinerf_ns.detect.fruit_channel import score_fruit_channel

    raw, data = tiny_capture
    renders = oracle_renders(raw, data, fruit_mode="true")
    save_renders(renders, tmp_path / "true")
    scored = score_fruit_channel([(tmp_path / "true", raw)], split="train", min_box_pixels=3)
    assert scored.metrics.num_images == sum(v.split == "train" for v in renders.views)
    assert scored.metrics.num_true > 5
    assert scored.metrics.precision > 0.6 and scored.metrics.recall > 0.6 and scored.metrics.map50 > 0.4
    low, high = scored.intervals["f1"].low, scored.intervals["f1"].high
    assert low <= scored.metrics.f1 <= high
    for view in renders.views:  # the channel's fruit half a frame away from the true fruit
        assert view.fruit is not None
        view.fruit[:] = np.roll(view.fruit, view.fruit.shape[1] // 2, axis=1)
    save_renders(renders, tmp_path / "moved")
    moved = score_fruit_channel([(tmp_path / "moved", raw)], split="train", min_box_pixels=3)
    assert moved.metrics.recall < 0.5 * scored.metrics.recall
    for view in renders.views:
        view.fruit = None
    save_renders(renders, tmp_path / "none")
    with pytest.raises(ValueError, match="no 'fruit' channel"):
        score_fruit_channel([(tmp_path / "none", raw)], split="train")
