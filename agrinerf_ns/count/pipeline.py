"""The count from rendered views to files: detect per view, lift, cluster, score against the truth, write."""

from __future__ import annotations

import json
import shutil
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Dict, List, Optional, Sequence, Tuple

import numpy as np
import tyro
from jaxtyping import Float
from rich.console import Console
from rich.progress import Progress

from agrinerf_ns.atomic import atomic_output_dir
from agrinerf_ns.count.cluster import ClusterConfig, Fruit, cluster_fruit, merge_distance
from agrinerf_ns.count.detectors import DetectorConfig, make_detector, view_source
from agrinerf_ns.count.fruit_score import (
    TIER_DISTANCES,
    TRUE_DEPTH_DIR,
    Align,
    CountScore,
    Similarity,
    TruthFruit,
    align_to_capture,
    dataset_frames,
    disc_views,
    match_fruit,
    raw_stem,
    read_split,
    read_truth_fruit,
    score_fruit,
    tier_scores,
    visible_fruit,
)
from agrinerf_ns.count.lift import LiftedDetection, lift_detection
from agrinerf_ns.count.render import (
    CountInputError,
    RenderSet,
    WorldFrame,
    load_renders,
    render_loaded_run,
    render_run,
)
from agrinerf_ns.count.row_range import fruit_in_range, in_range
from agrinerf_ns.count.source_table import source_row
from agrinerf_ns.count.sources import resolve_source
from agrinerf_ns.count.support import keep_supported
from agrinerf_ns.count.write import draw_map, score_markdown, write_csv, write_ply
from agrinerf_ns.fruit.view import MIN_ACCUMULATION

if TYPE_CHECKING:
    from agrinerf_ns.run_loading import LoadedRun

CONSOLE = Console()
FLAT_DEPTH = 0.02
"""A relative depth spread (see :func:`depth_spread`) below which the count warns that the geometry is flat."""
SCORE_DISTANCES = (*TIER_DISTANCES, 0.2)
"""Match distances (capture units) of the F1 curve in count.json, beside the score at ``--match-distance``; the tiers
are given at ``TIER_DISTANCES`` of them."""
MAP_POINTS = 200_000
"""Rendered surface points drawn under the fruit map at most."""


@dataclass(frozen=True)
class CountConfig:
    """How fruit are found, fused and scored."""

    detect: Annotated[DetectorConfig, tyro.conf.arg(name="")] = field(default_factory=DetectorConfig)
    cluster: Annotated[ClusterConfig, tyro.conf.arg(name="")] = field(default_factory=ClusterConfig)
    match_distance: float = 0.05
    """Scoring: a counted fruit matches a true one within this 3D distance of its centre (capture units, metres)."""
    align: Align = "poses"
    """Scoring: fit the dataset's frame to the capture's on the cameras (``poses``) or take it as it is."""
    min_visible_pixels: int = 3
    """Scoring: a true fruit is visible when this many of its pixels show in a training view."""
    well_seen_share: float = 0.25
    """Scoring: a true fruit is also scored as *countable* (the ``*_countable`` scores) when this share of its disc
    shows in a training view, and as *well seen* (``*_well_seen``) when it shows in at least ``well_seen_views``
    training views (``fruit_score.disc_views``)."""
    well_seen_views: int = 2
    """Scoring: see ``well_seen_share`` (two: the views a 3D count needs; fixed apart from the counter's own
    ``--min-views``, so that changing the counter does not move the denominator)."""
    max_range: Optional[float] = None
    """Count only the row the rig drove: fruit farther than this from every camera (dataset units: metres with
    metric poses) are left out of the count and, in scoring, of the truth (``count/row_range.py``). The rig's standoff
    from the row plus half the row spacing cuts midway between rows; None: every fruit, the next row's too."""


@dataclass
class CountResult:
    """What a count found."""

    fruit: List[Fruit]
    detections: List[LiftedDetection]
    detections_per_view: List[int]
    merge_distance: float
    score: Optional[CountScore] = None
    to_capture: Optional[Similarity] = None
    truth: Optional[TruthFruit] = None
    visible: Optional[np.ndarray] = None
    """Which true fruit a training view shows."""
    tiers: Dict[str, np.ndarray] = field(default_factory=dict)
    """Each tier of truth scored (``fruit_score.TIERS``): which true fruit it holds."""
    depth_spread: float = float("nan")
    """:func:`depth_spread` of the renders."""


def count_fruit(renders: RenderSet, config: CountConfig, progress: Optional[Progress] = None) -> CountResult:
    """Detect fruit in every view, lift each detection to 3D and cluster them into fruit."""
    lifted, per_view = detect_and_lift(renders, config.detect, progress)
    return fused_result(lifted, per_view, renders, config.cluster)


def detect_and_lift(
    renders: RenderSet, config: DetectorConfig, progress: Optional[Progress] = None
) -> Tuple[List[LiftedDetection], List[int]]:
    """Every view's detections lifted to 3D (those with a rendered depth), and the detections per view."""
    detector = make_detector(config)
    lifted: List[LiftedDetection] = []
    per_view: List[int] = []
    task = progress.add_task("detecting fruit", total=len(renders.views)) if progress is not None else None
    for index, view in enumerate(renders.views):
        found = detector(view, renders.frame.scale)
        per_view.append(len(found))
        lift_by = source_row(view_source(config, view)).lift_depth if config.fruit_depth else None
        depth = view.output(lift_by) if lift_by is not None else None
        for detection in found:
            point = lift_detection(view, detection.mask, renders.frame, index, detection.score, depth)
            if point is not None:
                lifted.append(point)
        if progress is not None and task is not None:
            progress.advance(task)
    return lifted, per_view


def fused_result(
    lifted: List[LiftedDetection], per_view: List[int], renders: RenderSet, config: ClusterConfig
) -> CountResult:
    """The count of these lifted detections under one clustering (`fuse`): the same detections can be placed twice."""
    return CountResult(fuse(lifted, renders, config), lifted, per_view, merge_distance(lifted, config))


def fuse(lifted: Sequence[LiftedDetection], renders: RenderSet, config: ClusterConfig) -> List[Fruit]:
    """Detections to fruit: clustered (:func:`cluster_fruit`), then kept where enough of the views that show them
    detected them (:func:`keep_supported`)."""
    return keep_supported(cluster_fruit(lifted, config), renders.views, renders.frame, config.min_view_fraction)


def score_against_truth(renders: RenderSet, result: CountResult, raw: Path, config: CountConfig) -> None:
    """Fill ``result.score`` and ``result.to_capture`` against the synthetic capture ``raw``."""
    if renders.dataset is None:
        raise CountInputError(f"{raw}: the renders do not name their dataset folder, needed to score them")
    score_result(result, renders.dataset, training_frames(renders), raw, config, camera_centres(renders))


def camera_centres(renders: RenderSet) -> Float[np.ndarray, "n 3"]:
    """Every rendered view's camera centre, in the dataset's frame."""
    return renders.frame.to_dataset(np.stack([v.origins[0, 0] for v in renders.views]).astype(np.float64))


def score_result(
    result: CountResult,
    dataset: Path,
    train: Sequence[str],
    raw: Path,
    config: CountConfig,
    cameras: Optional[Float[np.ndarray, "c 3"]] = None,
) -> None:
    """Fill ``result.score``, ``result.to_capture``, ``result.truth`` and ``result.visible`` against the synthetic
    capture ``raw`` (``train``: the raw frame stems of the run's training views; ``dataset``: its dataset folder;
    ``cameras``: the run's camera centres in the dataset's frame, which ``config.max_range`` measures from)."""
    truth = read_truth_fruit(raw)
    result.truth = truth
    result.to_capture = align_to_capture(dataset, raw) if config.align == "poses" else Similarity.identity()
    near = np.ones(len(truth.ids), bool)
    if config.max_range is not None:
        if cameras is None:
            raise ValueError("scoring with --max-range needs the run's camera centres")
        capture_range = config.max_range * result.to_capture.scale
        near = in_range(truth.centres, result.to_capture.apply(np.asarray(cameras, np.float64)), capture_range)
    result.tiers = truth_tiers(raw, train, truth, config, near)
    result.visible = result.tiers["visible"]
    result.score = score_fruit(
        result.to_capture.apply(_centres(result.fruit)), truth, result.visible, config.match_distance,
        _temperatures(result.fruit), result.tiers.get("well_seen"), result.tiers.get("countable"),
    )  # fmt: skip


def truth_tiers(
    raw: Path, train: Sequence[str], truth: TruthFruit, config: CountConfig, near: np.ndarray
) -> Dict[str, np.ndarray]:
    """The true fruit of each scoring tier among those ``near`` the cameras (the row the rig drove): visible in the
    training frames ``train`` (raw stems), and where the capture has true depth countable and well seen."""
    visible = visible_fruit(raw, train, truth, config.min_visible_pixels) & near
    tiers = {"visible": visible}
    if (Path(raw) / TRUE_DEPTH_DIR).is_dir():
        views = disc_views(raw, train, truth, config.well_seen_share)
        tiers["countable"] = (views >= 1) & visible
        tiers["well_seen"] = (views >= config.well_seen_views) & visible
    return tiers


def _centres(fruit: Sequence[Fruit]) -> np.ndarray:
    return np.stack([f.centre for f in fruit]) if fruit else np.zeros((0, 3))


def _temperatures(fruit: Sequence[Fruit]) -> np.ndarray:
    return np.array([np.nan if f.temperature is None else f.temperature for f in fruit], np.float64)


def training_frames(renders: RenderSet) -> List[str]:
    """The raw capture's frame stems of the run's training views: the dataset's ``train_filenames`` where
    ``transforms.json`` lists them, else the rendered training views."""
    assert renders.dataset is not None
    return raw_training_frames(renders.dataset, [v.file_path for v in renders.views if v.split == "train"])


def raw_training_frames(dataset: Path, fallback: Sequence[str]) -> List[str]:
    """The raw capture's frame stems of a dataset's training frames: its ``train_filenames`` where
    ``transforms.json`` lists them, else ``fallback`` (dataset file paths)."""
    frames = dataset_frames(dataset)
    listed = read_split(dataset, "train_filenames")
    names = listed if listed else list(fallback)
    return [raw_stem(frames.get(name, {}), name) for name in names]


def depth_spread(renders: RenderSet) -> float:
    """Median over views of the rendered depth's interquartile range relative to its median (about 0 when the run
    put everything on one far shell, as an untrained or degenerate geometry does)."""
    spreads = []
    for view in renders.views:
        d = view.depth[view.accumulation >= MIN_ACCUMULATION]
        if d.size:
            q1, q2, q3 = np.percentile(d, [25, 50, 75])
            spreads.append((q3 - q1) / max(q2, 1e-9))
    return float(np.median(spreads)) if spreads else 0.0


def surface_points(renders: RenderSet, limit: int = MAP_POINTS) -> Float[np.ndarray, "n 3"]:
    """Rendered surface points of all views (accumulation >= 0.5) in the dataset's frame, at most ``limit``."""
    parts = [v.points()[v.accumulation >= MIN_ACCUMULATION] for v in renders.views]
    points = np.concatenate(parts) if parts else np.zeros((0, 3))
    if len(points) > limit:
        points = points[np.linspace(0, len(points) - 1, limit).astype(np.int64)]
    return renders.frame.to_dataset(points)


def run_count(
    out: Path,
    config: CountConfig,
    run_config: Optional[Path] = None,
    renders_dir: Optional[Path] = None,
    truth: Optional[Path] = None,
    overwrite: bool = False,
    save_renders: bool = True,
    splits: Sequence[str] = ("train", "eval"),
    loaded: Optional["LoadedRun"] = None,
) -> CountResult:
    """Render the run at ``run_config`` (or read ``renders_dir``), count its fruit and write ``out`` atomically:
    fruits.csv, fruits.ply, fruit_map.png, count.json, with ``truth`` also score.md; renders/ when ``save_renders``;
    ``loaded``: the run at ``run_config`` already loaded (``agrinerf_ns.run_loading.load_run``)."""
    if (run_config is None) == (renders_dir is None):
        raise ValueError("give exactly one of --config RUN/config.yml and --renders FOLDER")
    out = Path(out)
    if out.exists() and any(out.iterdir()) and not overwrite:
        raise FileExistsError(f"{out}: output folder exists and is not empty (pass --overwrite to replace it)")
    if truth is not None:
        read_truth_fruit(truth)  # fail before rendering
    with atomic_output_dir(out, overwrite) as tmp:
        if loaded is not None:
            renders = render_loaded_run(loaded, tmp / "renders" if save_renders else None, splits)
        elif run_config is not None:
            renders = render_run(run_config, tmp / "renders" if save_renders else None, splits)
        else:
            assert renders_dir is not None
            renders = load_renders(renders_dir)
            if save_renders:
                shutil.copytree(renders_dir, tmp / "renders")
        if not renders.views:
            raise CountInputError(f"{run_config or renders_dir}: no views to count fruit in")
        source, why = resolve_source(config.detect.source, "views", renders.outputs(), config.detect.detector)
        config = replace(config, detect=replace(config.detect, source=source))
        CONSOLE.print(f"Detecting fruit on '{source}' ({config.detect.detector}): {why}", soft_wrap=True)
        spread = depth_spread(renders)
        if spread < FLAT_DEPTH:
            CONSOLE.print(
                f"[yellow]Warning: the rendered depth is nearly flat (interquartile range {spread:.1%} of the median): "
                "the run's geometry is a far shell, so detections cannot be placed in 3D",
                soft_wrap=True,
            )
        with Progress(console=CONSOLE, transient=True) as progress:
            result = count_fruit(renders, config, progress)
        result.fruit = fruit_in_range(result.fruit, camera_centres(renders), config.max_range)
        result.depth_spread = spread
        if truth is not None:
            score_against_truth(renders, result, Path(truth), config)
        _write_outputs(tmp, renders, result, config, truth, run_config or renders_dir)
    print_summary(out, result, config.max_range)
    return result


def _write_outputs(
    tmp: Path, renders: RenderSet, result: CountResult, config: CountConfig, truth: Optional[Path], source: Any
) -> None:
    cameras = camera_centres(renders)
    title = (
        f"{len(result.fruit)} fruit counted on '{config.detect.source}' ({config.detect.detector}), "
        f"{len(renders.views)} views of {renders.method or 'the run'}"
    )
    settings = {
        "path": "views",
        "source": str(source),
        "method": renders.method,
        "views": len(renders.views),
        "detector": asdict(config.detect) | {"weights": str(config.detect.weights) if config.detect.weights else None},
        "cluster": asdict(config.cluster),
        "merge_distance": result.merge_distance,
        "depth_spread": result.depth_spread,
        "max_range": config.max_range,
        "poses": renders.poses,
        "detections": len(result.detections),
        "detections_per_view": result.detections_per_view,
    }
    write_count(tmp, result, renders.frame, surface_points(renders), cameras, title, settings, config, truth,
                f"{config.detect.detector} on {config.detect.source}")  # fmt: skip


def write_count(
    tmp: Path,
    result: CountResult,
    frame: WorldFrame,
    surface: np.ndarray,
    cameras: np.ndarray,
    title: str,
    settings: Dict[str, Any],
    config: CountConfig,
    truth: Optional[Path],
    detector: str,
) -> None:
    """fruits.csv, fruits.ply, fruit_map.png, count.json (``settings`` and, scored, the score) and, scored, score.md
    into ``tmp`` (``surface``, ``cameras``: dataset frame)."""
    fruit = result.fruit
    centres = _centres(fruit)
    capture, truth_ids = None, None
    if result.truth is not None and result.to_capture is not None:
        capture = result.to_capture.apply(centres)
        rows, cols = match_fruit(capture, result.truth.centres, config.match_distance)
        ids = np.full(len(fruit), -1, np.int64)
        ids[rows] = result.truth.ids[cols]
        truth_ids = ids.tolist()
    write_csv(tmp / "fruits.csv", fruit, frame.to_ns(centres), capture, truth_ids)
    write_ply(tmp / "fruits.ply", fruit)
    if result.score is not None:
        s = result.score
        title += f"; visible truth {s.visible}, F1 {s.f1:.2f} at {s.match_distance:g} m"
    draw_map(tmp / "fruit_map.png", fruit, surface, title, result.truth, result.visible, result.to_capture, cameras)
    report: Dict[str, Any] = dict(settings) | {"fruit": len(fruit)}
    if result.score is not None and result.to_capture is not None:
        report["truth"] = str(Path(truth).resolve()) if truth is not None else None
        report["score"] = result.score.as_dict()
        scored = (
            tier_scores(result.to_capture.apply(centres), result.truth, result.tiers, SCORE_DISTANCES)
            if result.truth is not None
            else {}
        )  # one scoring for the F1 curve and the tiers
        report["f1_at_distance"] = {d: by_distance["f1"] for d, by_distance in scored.get("visible", {}).items()}
        tiers = {tier: {d: v for d, v in by.items() if float(d) in TIER_DISTANCES} for tier, by in scored.items()}
        report["tiers"] = tiers
        report["alignment"] = {
            "mode": config.align,
            "scale": result.to_capture.scale,
            "camera_residual_rms": result.to_capture.residual_rms,
        }
        (tmp / "score.md").write_text(
            score_markdown(
                result.score,
                {
                    "run": str(settings.get("source")),
                    "truth": str(truth),
                    "detector": detector,
                    "min views per fruit": config.cluster.min_views,
                    "visible": f">= {config.min_visible_pixels} pixels in a training view"
                    + ("" if config.max_range is None else f", within {config.max_range:g} of a camera"),
                    "countable": f">= {config.well_seen_share:g} of its disc in >= 1 training view",
                    "well seen": f">= {config.well_seen_share:g} of its disc in >= {config.well_seen_views} "
                    "training views",
                    "alignment": f"{config.align} (camera residual RMS {result.to_capture.residual_rms:.3f})",
                },
                tiers,
            )
        )
    (tmp / "count.json").write_text(json.dumps(report, indent=1, default=str) + "\n")


def print_summary(out: Path, result: CountResult, max_range: Optional[float] = None) -> None:
    CONSOLE.print(
        f"[bold green]{len(result.fruit)} fruit[/bold green] from {len(result.detections)} detections in "
        f"{len(result.detections_per_view)} views -> {out}",
        soft_wrap=True,
    )
    if result.score is not None:
        s = result.score
        CONSOLE.print(
            f"against the visible truth ({s.visible} fruit{_within(max_range)}): count error {s.count_error:+.1%}, "
            f"precision {s.precision:.2f}, recall {s.recall:.2f}, F1 {s.f1:.2f} at {s.match_distance:g} m",
            soft_wrap=True,
        )
        for tier, n in (("countable", s.countable), ("well-seen", s.well_seen)):
            key = tier.replace("-", "_")
            if n >= 0:
                CONSOLE.print(
                    f"against the {tier} truth ({n} fruit{_within(max_range)}): count error "
                    f"{getattr(s, 'count_error_' + key):+.1%}, recall {getattr(s, 'recall_' + key):.2f}, "
                    f"F1 {getattr(s, 'f1_' + key):.2f}",
                    soft_wrap=True,
                )


def _within(max_range: Optional[float]) -> str:
    return "" if max_range is None else f" within {max_range:g} of a camera"
