"""Bootstrap 95% intervals of mAP50 and mAP50-95 over the held-out images, and of the paired difference of two rows.

The images are the unit that is resampled (with replacement, ``BOOTSTRAP_RESAMPLES`` times, from a generator seeded
with ``BOOTSTRAP_SEED``): a resample is a multiset of frames, and its mAPs are those of the detections of those frames
counted as often as the frame was drawn. Every detection is matched once per image and IoU threshold
(:func:`~agrinerf_ns.detect.box_metrics.match_outcomes`); a resample only re-weights the matched detections, so the mAP of
the resample that draws every image once equals :func:`~agrinerf_ns.detect.box_metrics.mean_average_precision`. The draws
depend only on the sorted frame names, the seed and the number of resamples: two rows scored on the same frames see
the same resamples, so their difference is a paired bootstrap (a row minus itself is exactly 0 in every resample).
Intervals are percentile intervals (2.5th and 97.5th percentiles of the resampled values); resamples whose mAP is
undefined (no counted true box drawn) are left out.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Dict, FrozenSet, List, Sequence, Tuple

import numpy as np
from jaxtyping import Float, Int, Int8, Real

from agrinerf_ns.detect.box_metrics import (
    IOU_THRESHOLDS,
    ImageBoxes,
    Interpolation,
    interpolated_precision,
    match_outcomes,
)

BOOTSTRAP_RESAMPLES = 1000
BOOTSTRAP_SEED = 0
CONFIDENCE = 0.95


@dataclass(frozen=True, eq=False)
class MatchedImages:
    """One row's detections, matched per image at each COCO IoU threshold, in the order AP ranks them."""

    frames: Tuple[str, ...]
    """Frame stem of each image (unique)."""
    num_true: Int[np.ndarray, " images"]
    """Counted true boxes per image."""
    image: Int[np.ndarray, " dets"]
    """The image of each detection; detections sorted by descending score (ties: image order, then score order)."""
    scores: Float[np.ndarray, " dets"]
    """Each detection's score."""
    outcome: Int8[np.ndarray, "thresholds dets"]
    """Per IoU threshold: 1 true positive, 0 false positive, -1 left out (took an ignored box)."""

    @staticmethod
    def from_images(frames: Sequence[str], images: Sequence[ImageBoxes], max_dets: int = 100) -> "MatchedImages":
        """Match every image's detections (all scores, at most ``max_dets``) at every threshold."""
        if len(frames) != len(images) or len(set(frames)) != len(frames):
            raise ValueError(f"need one unique frame name per image; got {len(frames)} names for {len(images)} images")
        per_image = []
        for im in images:
            matches = [match_outcomes(im, t, max_dets) for t in IOU_THRESHOLDS]
            per_image.append((matches[0][0], np.stack([outcome for _, outcome in matches])))
        return MatchedImages._build(frames, [len(im.true_boxes) for im in images], per_image)

    @staticmethod
    def _build(
        frames: Sequence[str],
        num_true: Sequence[int],
        per_image: Sequence[Tuple[np.ndarray, np.ndarray]],
    ) -> "MatchedImages":
        """From each image's (scores (k,), outcomes (thresholds, k)), k differing between images."""
        scores = np.concatenate([np.zeros(0)] + [s for s, _ in per_image])
        outcome = np.concatenate([np.zeros((len(IOU_THRESHOLDS), 0), np.int8)] + [o for _, o in per_image], axis=1)
        image = np.concatenate([np.zeros(0, np.int64)] + [np.full(len(s), i) for i, (s, _) in enumerate(per_image)])
        order = np.argsort(-scores, kind="mergesort")  # the ranking of scoring.average_precision
        return MatchedImages(
            tuple(frames), np.asarray(num_true, np.int64), image[order], scores[order], outcome[:, order]
        )

    def average_precisions(
        self, counts: Real[np.ndarray, "resamples images"], interpolation: Interpolation = "coco101"
    ) -> Float[np.ndarray, "resamples thresholds"]:
        """AP at every IoU threshold of each resample, given how often it draws each image (NaN: no true box).

        Only the true positives are visited: recall rises only there, and a false positive's precision is at most
        that of the true positive before it, so the monotone envelope at the true positives is the full curve's. The
        true and false positives ranked up to each true positive are counted per image once, so a resample's counts
        are one matrix product with its draws (integer-valued, hence exact in float64).
        """
        counts = np.asarray(counts, np.float64).reshape(-1, len(self.frames))
        out = np.zeros((len(counts), len(IOU_THRESHOLDS)))
        num_true = counts @ self.num_true
        for t in range(len(IOU_THRESHOLDS)):
            tp_before, fp_before = self._counts_at_true_positives(t)
            tp, fp = tp_before @ counts.T, fp_before @ counts.T  # (true positives, resamples)
            with np.errstate(invalid="ignore", divide="ignore"):
                recall = tp / num_true
            precision = tp / (tp + fp + np.spacing(1))
            envelope = np.maximum.accumulate(precision[::-1], axis=0)[::-1]
            for b in range(len(counts)):
                out[b, t] = interpolated_precision(recall[:, b], envelope[:, b], interpolation)
        out[num_true == 0] = np.nan
        return out

    def _counts_at_true_positives(
        self, t: int
    ) -> Tuple[Float[np.ndarray, "positives images"], Float[np.ndarray, "positives images"]]:
        """Per true positive at threshold ``t`` (in rank order) and image: that image's true positives ranked up to
        it (inclusive) and its false positives ranked before it."""
        positives = np.flatnonzero(self.outcome[t] == 1)
        tp_before = np.zeros((len(positives), len(self.frames)))
        fp_before = np.zeros((len(positives), len(self.frames)))
        for i in range(len(self.frames)):
            mine = self.image == i
            tp_before[:, i] = np.searchsorted(np.flatnonzero(mine & (self.outcome[t] == 1)), positives, side="right")
            fp_before[:, i] = np.searchsorted(np.flatnonzero(mine & (self.outcome[t] == 0)), positives, side="left")
        return tp_before, fp_before

    def to_json(self) -> List[Dict[str, Any]]:
        """Per image: frame, counted true boxes, detection scores (descending) and the outcomes at each threshold as a
        string of "T" (true positive), "F" (false positive) and "-" (left out)."""
        codes = np.array(["-", "F", "T"])
        records = []
        for i, frame in enumerate(self.frames):
            mine = np.flatnonzero(self.image == i)
            records.append({
                "frame": frame,
                "num_true": int(self.num_true[i]),
                "scores": [float(s) for s in self.scores[mine]],
                "outcomes": ["".join(codes[row + 1]) for row in self.outcome[:, mine]],
            })  # fmt: skip
        return records

    @staticmethod
    def from_json(records: Sequence[Dict[str, Any]]) -> "MatchedImages":
        """Inverse of :meth:`to_json`."""
        code = {"-": -1, "F": 0, "T": 1}
        per_image = []
        for r in records:
            outcome = np.array([[code[c] for c in row] for row in r["outcomes"]], np.int8)
            per_image.append((np.asarray(r["scores"], np.float64), outcome.reshape(len(IOU_THRESHOLDS), -1)))
        return MatchedImages._build([r["frame"] for r in records], [r["num_true"] for r in records], per_image)


def resample_counts(
    frames: Sequence[str], resamples: int = BOOTSTRAP_RESAMPLES, seed: int = BOOTSTRAP_SEED
) -> Int[np.ndarray, "resamples images"]:
    """How often each frame (in the given order) is drawn in each resample; the draws are made over the sorted frame
    names, so any order of the same frames gets the same resamples."""
    names = sorted(frames)
    draws = np.random.default_rng(seed).integers(0, len(names), size=(resamples, len(names)))
    counts = np.zeros((resamples, len(names)), np.int64)
    np.add.at(counts, (np.arange(resamples)[:, None], draws), 1)
    position = {name: i for i, name in enumerate(names)}
    return counts[:, [position[f] for f in frames]]


@dataclass(frozen=True)
class Interval:
    """A point estimate and its bootstrap interval."""

    value: float
    low: float
    high: float

    def significant(self) -> bool:
        """Whether the interval excludes 0 (for a difference: significant at its confidence)."""
        return bool(self.low > 0 or self.high < 0)

    def format(self, scale: float = 100.0, signed: bool = False) -> str:
        """E.g. "17.3 [12.1, 22.0]" (mAPs x100, one decimal)."""
        sign = "+" if signed else ""
        low, value, high = (round(scale * x, 1) + 0.0 for x in (self.low, self.value, self.high))  # no "-0.0"
        return f"{value:{sign}.1f} [{low:{sign}.1f}, {high:{sign}.1f}]"


@dataclass(frozen=True, eq=False)
class BootstrapMaps:
    """One row's mAP50 and mAP50-95 on all its images and on each resample."""

    frames: FrozenSet[str]
    map50: float
    map50_95: float
    samples: Float[np.ndarray, "resamples 2"]
    """mAP50 and mAP50-95 of each resample."""

    def intervals(self, confidence: float = CONFIDENCE) -> Tuple[Interval, Interval]:
        """(mAP50, mAP50-95) with their percentile intervals."""
        return percentile_interval(self.map50, self.samples[:, 0], confidence), percentile_interval(
            self.map50_95, self.samples[:, 1], confidence
        )

    def minus(self, other: "BootstrapMaps", confidence: float = CONFIDENCE) -> Tuple[Interval, Interval]:
        """Paired difference self - other of (mAP50, mAP50-95), resampling the same images for both rows."""
        if self.frames != other.frames:
            raise ValueError("a paired difference needs both rows scored on the same frames")
        if len(self.samples) != len(other.samples):
            raise ValueError("a paired difference needs both rows resampled alike")
        diff = self.samples - other.samples
        return (
            percentile_interval(self.map50 - other.map50, diff[:, 0], confidence),
            percentile_interval(self.map50_95 - other.map50_95, diff[:, 1], confidence),
        )


def bootstrap_maps(
    matched: MatchedImages, resamples: int = BOOTSTRAP_RESAMPLES, seed: int = BOOTSTRAP_SEED
) -> BootstrapMaps:
    """mAP50 and mAP50-95 of ``matched`` and of ``resamples`` resamples of its images (seeded, paired across rows)."""
    point = matched.average_precisions(np.ones((1, len(matched.frames))))[0]
    aps = matched.average_precisions(resample_counts(matched.frames, resamples, seed))
    samples = np.stack([aps[:, 0], aps.mean(axis=1)], axis=1)
    return BootstrapMaps(frozenset(matched.frames), float(point[0]), float(point.mean()), samples)


def percentile_interval(value: float, samples: Float[np.ndarray, " resamples"], confidence: float) -> Interval:
    """``value`` with the central ``confidence`` percentile range of its finite resamples (NaN bounds when none is)."""
    tail = 100 * (1 - confidence) / 2
    finite = samples[np.isfinite(samples)]
    if len(finite) == 0:
        return Interval(value, float("nan"), float("nan"))
    low, high = np.percentile(finite, [tail, 100 - tail])
    return Interval(value, float(low), float(high))
