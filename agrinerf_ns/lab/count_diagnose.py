"""Where a count loses fruit, measured against a synthetic capture's truth: ``python -m agrinerf_ns.lab.count_diagnose
--renders FOLDER --truth RAW [count options]`` prints (and with ``--out`` writes) a JSON report.

- **2D detection**, per view: the true fruit ids (``truth/fruit_ids``, undistorted onto the dataset's camera) under
  each detection's pixels. A detection is a hit when it covers a fruit no earlier detection of the view covered, a
  duplicate when it covers only fruit already hit, a false blob when it covers no fruit pixel. Recall is over the
  fruit showing at least ``min_visible_pixels`` in the view.
- **Lift**: the 3D distance of each hit's lifted centre (capture frame) from its fruit's true centre.
- **Fusion**: clusters holding hits on more than one true fruit (over-merged) and true fruit whose hits fall in more
  than one cluster (over-split), before and after ``min_views``.
- **Denominator**: the visible true fruit by the number of training views that show them, and how many of them any
  view's detector hits in at least ``min_views`` views (the recall a perfect fusion could reach).
"""

from __future__ import annotations

import json
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Dict, List, Optional, Set

import numpy as np
import tyro
from jaxtyping import Int

from agrinerf_ns.count.cluster import cluster_labels, merge_distance
from agrinerf_ns.count.detectors import make_detector
from agrinerf_ns.count.fruit_score import (
    Similarity,
    TruthFruit,
    align_to_capture,
    dataset_frames,
    raw_stem,
    read_truth_fruit,
    score_fruit,
    visible_fruit,
)
from agrinerf_ns.count.lift import LiftedDetection, lift_detection
from agrinerf_ns.count.pipeline import CountConfig, fuse, training_frames
from agrinerf_ns.count.render import RenderSet, load_renders
from agrinerf_ns.dataset_format import TRANSFORMS
from agrinerf_ns.lab.count_oracle import true_fruit_ids, undistort_maps, with_true_depth
from agrinerf_ns.process.readers import read_calibration


def view_fruit_ids(raw: Path, renders: RenderSet) -> List[Int[np.ndarray, "h w"]]:
    """Per view, the true fruit id of each pixel (-1 none), undistorted onto the dataset's pinhole camera."""
    assert renders.dataset is not None
    meta = json.loads((renders.dataset / TRANSFORMS).read_text())
    map_x, map_y = undistort_maps(read_calibration(raw / "calib.yaml").rgb, meta)
    frames = dataset_frames(renders.dataset)
    stems = [raw_stem(frames.get(view.file_path, {}), view.file_path) for view in renders.views]
    return [true_fruit_ids(raw, stem, (map_x, map_y)) for stem in stems]


@dataclass
class DetectionTally:
    """Every view's detections against the true fruit ids under them, and the lifted centres of the detections."""

    hits: int = 0
    duplicates: int = 0
    false_blobs: int = 0
    shown: int = 0
    """Fruit showing at least ``min_visible_pixels`` in a view, summed over the views."""
    lift_errors: List[float] = field(default_factory=list)
    """Per lifted hit, the distance of its centre from its true fruit's (capture frame)."""
    lifted: List[LiftedDetection] = field(default_factory=list)
    owners: List[int] = field(default_factory=list)
    """Per lifted detection: the true fruit index it hit (-1: none or duplicate)."""
    views_hitting: Dict[int, set] = field(default_factory=lambda: defaultdict(set))
    """True fruit index -> the views whose detections hit it."""
    train_views_showing: Counter = field(default_factory=Counter)
    """True fruit index -> the training views that show it."""


def _detection_owner(under: Int[np.ndarray, " k"], found_here: set) -> Optional[int]:
    """The true fruit a detection over the fruit ids ``under`` (>= 0) hits: the one of most pixels among those not
    yet hit in its view (``found_here``); -1 when it covers only fruit already hit, None when it covers none."""
    new = [int(i) for i in np.unique(under) if int(i) not in found_here]
    if under.size == 0:
        return None
    if not new:
        return -1
    return max(new, key=lambda i: int((under == i).sum()))


def tally_detections(
    renders: RenderSet, raw: Path, config: CountConfig, truth: TruthFruit, to_capture: Similarity, train_stems: Set[str]
) -> DetectionTally:
    """Run the detector of ``config`` on every view of ``renders`` and score each detection against the true fruit
    ids under its pixels (see the module docstring); ``train_stems``: the raw frames the run trained on."""
    assert renders.dataset is not None
    index = {int(fid): i for i, fid in enumerate(truth.ids)}
    detector = make_detector(config.detect)
    frames = dataset_frames(renders.dataset)
    tally = DetectionTally()
    for v, (view, ids) in enumerate(zip(renders.views, view_fruit_ids(raw, renders), strict=True)):
        values, counts = np.unique(ids[ids >= 0], return_counts=True)
        in_view = {int(i) for i, c in zip(values, counts, strict=True) if c >= config.min_visible_pixels}
        if raw_stem(frames.get(view.file_path, {}), view.file_path) in train_stems:
            tally.train_views_showing.update(index[i] for i in in_view if i in index)
        found_here: set = set()
        for det in detector(view, renders.frame.scale):
            under = ids[det.mask]
            owner = _detection_owner(under[under >= 0], found_here)
            if owner is None:
                tally.false_blobs += 1
                owner = -1
            elif owner < 0:
                tally.duplicates += 1
            else:
                found_here.add(owner)
            point = lift_detection(view, det.mask, renders.frame, v, det.score)
            if point is None:
                continue
            tally.lifted.append(point)
            tally.owners.append(index.get(owner, -1) if owner >= 0 else -1)
            if owner >= 0 and owner in index:
                tally.views_hitting[index[owner]].add(v)
                centre = to_capture.apply(point.centre[None])[0]
                tally.lift_errors.append(float(np.linalg.norm(centre - truth.centres[index[owner]])))
        tally.hits += len(found_here & in_view)
        tally.shown += len(in_view)
    return tally


def fusion_report(tally: DetectionTally, config: CountConfig, num_truth: int) -> Dict[str, int]:
    """How the lifted detections cluster: clusters kept by ``min_views``, those holding hits on more than one true
    fruit, true fruit whose hits fall in more than one kept cluster, and kept clusters with no hit."""
    lifted, owners_arr = tally.lifted, np.asarray(tally.owners)
    labels = cluster_labels(np.stack([d.centre for d in lifted]), merge_distance(lifted, config.cluster)) if lifted else np.zeros(0, int)  # fmt: skip
    kept = {
        int(lab) for lab in np.unique(labels)
        if len({lifted[k].view for k in np.nonzero(labels == lab)[0]}) >= config.cluster.min_views
    }  # fmt: skip
    merged = sum(len(set(owners_arr[(labels == lab) & (owners_arr >= 0)])) > 1 for lab in kept)
    split = sum(len(set(labels[owners_arr == i]) & kept) > 1 for i in range(num_truth))
    return {
        "clusters_kept": len(kept),
        "over_merged_clusters": int(merged),
        "over_split_fruit": int(split),
        "clusters_without_a_hit": int(sum(not (owners_arr[labels == lab] >= 0).any() for lab in kept)),
    }


def diagnose(renders: RenderSet, raw: Path, config: CountConfig) -> Dict[str, Any]:
    """The report described in the module docstring."""
    truth = read_truth_fruit(raw)
    assert renders.dataset is not None
    to_capture = align_to_capture(renders.dataset, raw)
    train_stems = set(training_frames(renders))
    tally = tally_detections(renders, raw, config, truth, to_capture, train_stems)
    visible = visible_fruit(raw, list(train_stems), truth, config.min_visible_pixels)
    seen_in = np.array([tally.train_views_showing[i] for i in range(len(truth.ids))])
    fruit = fuse(tally.lifted, renders, config.cluster)
    centres = to_capture.apply(np.stack([f.centre for f in fruit])) if fruit else np.zeros((0, 3))
    score = score_fruit(centres, truth, visible, config.match_distance)
    hit_views = np.array([len(tally.views_hitting.get(i, ())) for i in range(len(truth.ids))])
    errors = np.asarray(tally.lift_errors)
    hits, detections = tally.hits, tally.hits + tally.duplicates + tally.false_blobs
    return {
        "views": len(renders.views),
        "detections": detections,
        "2d": {
            "fruit_shown": tally.shown,
            "recall": hits / max(tally.shown, 1),
            "precision": hits / max(detections, 1),
            "hits": hits,
            "duplicates": tally.duplicates,
            "false_blobs": tally.false_blobs,
        },
        "lift_error_m": {
            "median": float(np.median(errors)) if errors.size else None,
            "p90": float(np.percentile(errors, 90)) if errors.size else None,
            "within_match_distance": float(np.mean(errors <= config.match_distance)) if errors.size else None,
        },
        "fusion": fusion_report(tally, config, len(truth.ids)),
        "denominator": {
            "visible": int(visible.sum()),
            "visible_in_1_training_view": int(((seen_in == 1) & visible).sum()),
            "visible_in_2plus_training_views": int(((seen_in >= 2) & visible).sum()),
            "visible_hit_in_min_views": int(((hit_views >= config.cluster.min_views) & visible).sum()),
        },
        "score": score.as_dict(),
    }


@dataclass
class DiagnoseArgs:
    """Measure where a count loses fruit, against a synthetic capture's truth."""

    renders: Path
    """A render folder (agrinerf-count OUT/renders, or python -m agrinerf_ns.lab.count_oracle)."""
    truth: Path
    """The synthetic raw capture."""
    out: Optional[Path] = None
    """Write the report here (JSON) as well."""
    true_depth: bool = False
    """Count the renders' colours on the capture's true depth instead of their rendered depth: the difference
    between the two reports is what the field's geometry costs the count."""
    count: Annotated[CountConfig, tyro.conf.arg(name="")] = field(default_factory=CountConfig)


def entrypoint() -> None:
    args = tyro.cli(DiagnoseArgs)
    renders = load_renders(args.renders)
    if args.true_depth:
        renders = with_true_depth(renders, args.truth)
    report = diagnose(renders, args.truth, args.count) | {"depth": "true" if args.true_depth else "rendered"}
    text = json.dumps(report, indent=1)
    print(text)
    if args.out is not None:
        args.out.write_text(text + "\n")


if __name__ == "__main__":
    entrypoint()
