"""Detection scoring: box IoU, per-image matching, AP, mAP50, mAP50-95, precision/recall/F1.

Single class (fruit), boxes in pixel ``x1 y1 x2 y2``. The matching and the average precision follow the COCO
evaluation (pycocotools ``COCOeval``, no crowd boxes), with optional *ignored* true boxes (COCO's boxes outside the
area range; here: fruit with too few visible pixels):

- per image, detections are taken in descending score (at most ``max_dets``, default 100) and each is matched to the
  unmatched counted true box of highest IoU, provided that IoU >= the threshold; a detection that matches no counted
  box but an unmatched ignored one (IoU >= the threshold) takes that box and is left out (neither true nor false
  positive); ignored boxes do not count towards recall;
- AP is **COCO-style 101-point interpolation**: precision is made monotone (the running maximum from high recall
  down) and averaged at recall 0, 0.01, ..., 1 (0 where that recall is never reached). ``interpolation="all_point"``
  gives the VOC 2010+ area under the same monotone curve instead;
- mAP50 is AP at IoU 0.5, mAP50-95 the mean of AP at IoU 0.50, 0.55, ..., 0.95.

This module does not import Ultralytics (AGPL-3.0) or torch: it is the project's own implementation and is checked
against torchmetrics' ``MeanAveragePrecision`` in the tests.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Dict, List, Literal, Sequence, Tuple, Union

import numpy as np
from jaxtyping import Bool, Float, Int8

IOU_THRESHOLDS: Tuple[float, ...] = tuple(float(t) for t in np.linspace(0.5, 0.95, 10))
"""COCO IoU thresholds 0.50:0.05:0.95."""

RECALL_POINTS: Float[np.ndarray, "101"] = np.linspace(0.0, 1.0, 101)
"""COCO recall sampling points for 101-point interpolation."""

Interpolation = Literal["coco101", "all_point"]


@dataclass(frozen=True)
class ImageBoxes:
    """Detections and ground truth of one image (single class)."""

    pred_boxes: Float[np.ndarray, "n 4"]
    """Predicted boxes, pixel x1 y1 x2 y2."""
    scores: Float[np.ndarray, " n"]
    """Confidence of each predicted box."""
    true_boxes: Float[np.ndarray, "m 4"]
    """True boxes, pixel x1 y1 x2 y2."""
    ignore_boxes: Float[np.ndarray, "k 4"] = field(default_factory=lambda: np.zeros((0, 4)))
    """True boxes that neither count towards recall nor make a detection on them a false positive."""

    def __post_init__(self) -> None:
        pred = np.asarray(self.pred_boxes, dtype=np.float64).reshape(-1, 4)
        scores = np.asarray(self.scores, dtype=np.float64).reshape(-1)
        true = np.asarray(self.true_boxes, dtype=np.float64).reshape(-1, 4)
        ignore = np.asarray(self.ignore_boxes, dtype=np.float64).reshape(-1, 4)
        if len(pred) != len(scores):
            raise ValueError(f"{len(pred)} predicted boxes but {len(scores)} scores")
        for name, arr in (("pred_boxes", pred), ("scores", scores), ("true_boxes", true), ("ignore_boxes", ignore)):
            if not np.all(np.isfinite(arr)):
                raise ValueError(f"{name} contains NaN or Inf")
        object.__setattr__(self, "pred_boxes", pred)
        object.__setattr__(self, "scores", scores)
        object.__setattr__(self, "true_boxes", true)
        object.__setattr__(self, "ignore_boxes", ignore)


@dataclass(frozen=True)
class DetectionMetrics:
    """The paper's detection metrics. mAPs are fractions in [0, 1] (the paper prints them x100)."""

    map50: float
    map50_95: float
    precision: float
    recall: float
    f1: float
    conf_threshold: float
    num_images: int
    num_true: int
    num_pred: int

    def as_dict(self) -> Dict[str, float]:
        return asdict(self)


def box_iou(a: Float[np.ndarray, "n 4"], b: Float[np.ndarray, "m 4"]) -> Float[np.ndarray, "n m"]:
    """Pairwise IoU of x1 y1 x2 y2 boxes (0 where the union is empty)."""
    a = np.asarray(a, dtype=np.float64).reshape(-1, 4)
    b = np.asarray(b, dtype=np.float64).reshape(-1, 4)
    area_a = np.clip(a[:, 2] - a[:, 0], 0, None) * np.clip(a[:, 3] - a[:, 1], 0, None)
    area_b = np.clip(b[:, 2] - b[:, 0], 0, None) * np.clip(b[:, 3] - b[:, 1], 0, None)
    iw = np.clip(np.minimum(a[:, None, 2], b[None, :, 2]) - np.maximum(a[:, None, 0], b[None, :, 0]), 0, None)
    ih = np.clip(np.minimum(a[:, None, 3], b[None, :, 3]) - np.maximum(a[:, None, 1], b[None, :, 1]), 0, None)
    inter = iw * ih
    union = area_a[:, None] + area_b[None, :] - inter
    return np.where(union > 0, inter / np.where(union > 0, union, 1.0), 0.0)


def match_outcomes(
    image: ImageBoxes, iou_threshold: float, max_dets: int = 100, conf_threshold: float = 0.0
) -> Tuple[Float[np.ndarray, " k"], Int8[np.ndarray, " k"]]:
    """Greedy COCO matching in one image, every considered detection with its outcome.

    Returns the scores of the detections considered (descending; those >= ``conf_threshold``, at most ``max_dets``)
    and each one's outcome: 1 true positive, 0 false positive, -1 left out (it took an ignored box). Each true box is
    matched at most once.
    """
    keep = np.flatnonzero(image.scores >= conf_threshold)
    order = keep[np.argsort(-image.scores[keep], kind="mergesort")][:max_dets]
    scores = image.scores[order]
    outcome = np.zeros(len(order), dtype=np.int8)
    counted = len(image.true_boxes)
    if len(order) == 0 or counted + len(image.ignore_boxes) == 0:
        return scores, outcome
    ious = box_iou(image.pred_boxes[order], np.concatenate([image.true_boxes, image.ignore_boxes]))
    matched = np.zeros(ious.shape[1], dtype=bool)
    for d in range(len(order)):
        for candidates in (range(counted), range(counted, ious.shape[1])):  # counted boxes first, as COCOeval
            best, best_iou = -1, min(iou_threshold, 1 - 1e-10)
            for g in candidates:
                if matched[g] or ious[d, g] < best_iou:
                    continue
                best, best_iou = g, ious[d, g]
            if best >= 0:
                matched[best] = True
                outcome[d] = 1 if best < counted else -1
                break
    return scores, outcome


def match_image(
    image: ImageBoxes, iou_threshold: float, max_dets: int = 100, conf_threshold: float = 0.0
) -> Tuple[Float[np.ndarray, " k"], Bool[np.ndarray, " k"]]:
    """Greedy COCO matching in one image (:func:`match_outcomes`) without the detections left out on ignored boxes:
    the scores of the kept detections (descending) and whether each is a true positive."""
    scores, outcome = match_outcomes(image, iou_threshold, max_dets, conf_threshold)
    kept = outcome >= 0
    return scores[kept], outcome[kept] == 1


def average_precision(
    images: Sequence[ImageBoxes], iou_threshold: float, max_dets: int = 100, interpolation: Interpolation = "coco101"
) -> float:
    """AP over a set of images at one IoU threshold. NaN when there is no true box at all (AP undefined)."""
    num_true = sum(len(im.true_boxes) for im in images)
    if num_true == 0:
        return float("nan")
    per_image = [match_image(im, iou_threshold, max_dets) for im in images]
    scores = np.concatenate([s for s, _ in per_image]) if per_image else np.zeros(0)
    is_tp = np.concatenate([t for _, t in per_image]) if per_image else np.zeros(0, dtype=bool)
    if len(scores) == 0:
        return 0.0
    order = np.argsort(-scores, kind="mergesort")
    tp = np.cumsum(is_tp[order])
    fp = np.cumsum(~is_tp[order])
    recall = tp / num_true
    precision = tp / (tp + fp + np.spacing(1))
    return interpolated_precision(recall, np.maximum.accumulate(precision[::-1])[::-1], interpolation)


def interpolated_precision(
    recall: Float[np.ndarray, " dets"], envelope: Float[np.ndarray, " dets"], interpolation: Interpolation
) -> float:
    """AP from a recall curve (detections in rank order) and its monotone precision envelope: COCO's 101 recall
    points or the all-point area."""
    if len(recall) == 0:
        return 0.0
    if interpolation == "coco101":
        idx = np.searchsorted(recall, RECALL_POINTS, side="left")
        return float(np.where(idx < len(envelope), envelope[np.minimum(idx, len(envelope) - 1)], 0.0).mean())
    if interpolation == "all_point":
        return float(np.sum(np.diff(np.concatenate([[0.0], recall])) * envelope))
    raise ValueError(f"unknown interpolation {interpolation!r}: use 'coco101' or 'all_point'")


def mean_average_precision(
    images: Sequence[ImageBoxes], max_dets: int = 100, interpolation: Interpolation = "coco101"
) -> Tuple[float, float]:
    """(mAP50, mAP50-95). Single class, so mAP is the class's AP."""
    aps = [average_precision(images, t, max_dets, interpolation) for t in IOU_THRESHOLDS]
    return aps[0], float(np.mean(aps))


def precision_recall_f1(
    images: Sequence[ImageBoxes], conf_threshold: float, iou_threshold: float = 0.5, max_dets: int = 100
) -> Tuple[float, float, float]:
    """Precision, recall and F1 of the detections with score >= ``conf_threshold``, matched at ``iou_threshold``.

    Precision is 0 when nothing is detected; recall is NaN when there is no true box.
    """
    tp = fp = 0
    for im in images:
        _, is_tp = match_image(im, iou_threshold, max_dets, conf_threshold)
        tp += int(is_tp.sum())
        fp += int((~is_tp).sum())
    return rates(tp, fp, sum(len(im.true_boxes) for im in images))


def rates(tp: Union[int, float], fp: Union[int, float], num_true: Union[int, float]) -> Tuple[float, float, float]:
    """Precision, recall and F1 of ``tp`` true and ``fp`` false positives against ``num_true`` true boxes (precision
    0 when nothing is detected, recall NaN when there is no true box)."""
    precision = tp / (tp + fp) if tp + fp > 0 else 0.0
    recall = tp / num_true if num_true > 0 else float("nan")
    f1 = 2 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0
    return precision, recall, f1


def score_detections(
    images: Sequence[ImageBoxes],
    conf_threshold: float = 0.25,
    max_dets: int = 100,
    interpolation: Interpolation = "coco101",
) -> DetectionMetrics:
    """All metrics of the paper's Table III for one set of images.

    mAPs use every detection (sorted by score); precision, recall and F1 use those with score >= ``conf_threshold``
    at IoU 0.5.
    """
    images = list(images)
    if not images:
        raise ValueError("no images to score")
    map50, map50_95 = mean_average_precision(images, max_dets, interpolation)
    precision, recall, f1 = precision_recall_f1(images, conf_threshold, 0.5, max_dets)
    return DetectionMetrics(
        map50=map50,
        map50_95=map50_95,
        precision=precision,
        recall=recall,
        f1=f1,
        conf_threshold=conf_threshold,
        num_images=len(images),
        num_true=sum(len(im.true_boxes) for im in images),
        num_pred=sum(len(im.scores) for im in images),
    )


def metrics_table_row(metrics: DetectionMetrics) -> List[str]:
    """The five Table III numbers formatted as the paper prints them (mAPs x100, one decimal; P/R/F1 3 decimals)."""
    return [
        f"{100 * metrics.map50:.1f}",
        f"{100 * metrics.map50_95:.1f}",
        f"{metrics.precision:.3f}",
        f"{metrics.recall:.3f}",
        f"{metrics.f1:.3f}",
    ]
