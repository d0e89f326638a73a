"""The paper's Table III from the fruit head: the rendered fruit channel's regions as box detections.

Beside a detector on rendered images (YOLO, the AGPL extra), a run with a fruit head needs none: in each held-out
view the regions of its rendered ``fruit`` probability (`agrinerf_ns.fruit.regions`, the same regions the count
lifts into 3D) are the detections, each boxed by its pixels' extent and scored by its mean probability, and are
matched against the scene's true boxes as YOLO's are (`box_metrics`). The views come from `agrinerf-count`'s render
folder (``OUT/renders``), which holds the held-out cameras at the training resolution, so nothing is rendered again.
Runs are pooled by image, and the intervals resample images (`bootstrap`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Sequence, Tuple

import numpy as np
from jaxtyping import Float

from agrinerf_ns.count.render import RenderedView, load_renders
from agrinerf_ns.detect.bootstrap import (
    BOOTSTRAP_RESAMPLES,
    BOOTSTRAP_SEED,
    CONFIDENCE,
    Interval,
    MatchedImages,
    bootstrap_maps,
    percentile_interval,
    resample_counts,
)
from agrinerf_ns.detect.box_metrics import DetectionMetrics, ImageBoxes, rates, score_detections
from agrinerf_ns.detect.boxes import MIN_BOX_PIXELS, SceneTruth, yolo_to_xyxy
from agrinerf_ns.fruit.blobs import BlobConfig
from agrinerf_ns.fruit.regions import fruit_regions


def channel_boxes(
    view: RenderedView, scale: float, config: BlobConfig = BlobConfig()
) -> Tuple[Float[np.ndarray, "n 4"], Float[np.ndarray, " n"]]:
    """The fruit regions of ``view`` as pixel ``x1 y1 x2 y2`` boxes (pixel edges) and their mean probability."""
    boxes, scores = [], []
    for detection in fruit_regions(view, scale, config):
        ys, xs = np.nonzero(detection.mask)
        boxes.append([xs.min(), ys.min(), xs.max() + 1.0, ys.max() + 1.0])
        scores.append(detection.score)
    return np.asarray(boxes, np.float64).reshape(-1, 4), np.asarray(scores, np.float64)


@dataclass(frozen=True, eq=False)
class ChannelScore:
    """The Table III figures of the fruit channel on the pooled held-out views, with bootstrap intervals."""

    metrics: DetectionMetrics
    intervals: Dict[str, Interval]
    """``map50``, ``map50_95``, ``precision``, ``recall``, ``f1``."""
    frames: Tuple[str, ...]
    """``<run>/<frame>`` of each scored view."""

    def as_dict(self) -> Dict[str, object]:
        return {**self.metrics.as_dict(), "frames": list(self.frames),
                **{f"{k}_95ci": [i.low, i.high] for k, i in self.intervals.items()}}  # fmt: skip


def score_fruit_channel(
    runs: Sequence[Tuple[Path, Path]],
    split: str = "eval",
    min_box_pixels: int = MIN_BOX_PIXELS,
    config: BlobConfig = BlobConfig(),
) -> ChannelScore:
    """Score the fruit channel of each ``(render folder, raw capture)`` pair's ``split`` views, pooled over runs.

    Every region is a detection (P/R/F1 at score 0: the region threshold, ``config.fruit_probability``, already
    decides what is fruit); true boxes under ``min_box_pixels`` visible pixels are ignore regions, as for YOLO."""
    frames: List[str] = []
    images: List[ImageBoxes] = []
    for number, (renders, raw) in enumerate(runs):
        rendered = load_renders(renders)
        truth = SceneTruth(raw, min_box_pixels)
        views = [v for v in rendered.views if v.split == split]
        if not views:
            raise ValueError(f"{renders}: no '{split}' views to score (agrinerf-count renders every camera of a run)")
        for view in views:
            if view.fruit is None:
                raise ValueError(f"{renders}: view {view.name} has no 'fruit' channel (the run has no fruit head)")
            boxes, scores = channel_boxes(view, rendered.frame.scale, config)
            frame = truth.frame(view.name, renders / f"{view.split}_{view.name}.npz")
            height, width = view.depth.shape
            images.append(ImageBoxes(boxes, scores, yolo_to_xyxy(frame.counted, width, height),
                                     yolo_to_xyxy(frame.ignored, width, height)))  # fmt: skip
            frames.append(f"{number}:{Path(renders).parent.name}/{view.name}")
    metrics = score_detections(images, conf_threshold=0.0)
    matched = MatchedImages.from_images(frames, images)
    map50, map50_95 = bootstrap_maps(matched).intervals()
    return ChannelScore(metrics, {"map50": map50, "map50_95": map50_95, **_rate_intervals(matched)}, tuple(frames))


def _rate_intervals(matched: MatchedImages, confidence: float = CONFIDENCE) -> Dict[str, Interval]:
    """Precision, recall and F1 at IoU 0.5 (the matches' first threshold) with percentile intervals over image
    resamples (the mAPs' resamples)."""
    n = len(matched.frames)
    at_50 = matched.outcome[0]
    counts = np.stack([np.bincount(matched.image[at_50 == 1], minlength=n),  # true positives per image
                       np.bincount(matched.image[at_50 == 0], minlength=n),  # false positives
                       matched.num_true], axis=1).astype(np.float64)  # fmt: skip
    draws = resample_counts(matched.frames, BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED)
    values = np.array([rates(*(weights @ counts)) for weights in np.concatenate([np.ones((1, n), np.int64), draws])])
    return {name: percentile_interval(float(values[0, k]), values[1:, k], confidence)
            for k, name in enumerate(("precision", "recall", "f1"))}  # fmt: skip
