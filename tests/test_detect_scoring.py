"""Scoring: exact cases, hand-computed cases, and a cross-check against torchmetrics' COCO mAP (pycocotools)."""

from __future__ import annotations

import numpy as np
import pytest

from agrinerf_ns.detect.box_metrics import (
    ImageBoxes,
    average_precision,
    box_iou,
    match_image,
    mean_average_precision,
    precision_recall_f1,
    score_detections,
)


def _random_boxes(rng: np.random.Generator, n: int, size: float = 128.0) -> np.ndarray:
    # quarter-pixel coordinates: exact in float32, so torchmetrics/pycocotools see the same boxes we do
    xy = rng.uniform(0, size * 0.8, (n, 2))
    wh = rng.uniform(4, size * 0.2, (n, 2))
    return np.round(np.concatenate([xy, xy + wh], axis=1) * 4) / 4


def test_box_iou_known_values():
    a = np.array([[0, 0, 10, 10]], float)
    b = np.array([[0, 0, 10, 10], [5, 0, 15, 10], [20, 20, 30, 30], [0, 0, 5, 5]], float)
    np.testing.assert_allclose(box_iou(a, b), [[1.0, 50 / 150, 0.0, 0.25]])
    # degenerate boxes give 0, not NaN
    assert box_iou(np.zeros((1, 4)), np.zeros((1, 4)))[0, 0] == 0.0


def test_true_boxes_score_one_and_empty_space_zero():
    rng = np.random.default_rng(0)
    images = []
    for _ in range(5):
        true = _random_boxes(rng, 6, size=100)
        images.append(ImageBoxes(true.copy(), rng.uniform(0.3, 1.0, len(true)), true))
    metrics = score_detections(images)
    assert metrics.map50 == pytest.approx(1.0)
    assert metrics.map50_95 == pytest.approx(1.0)
    assert (metrics.precision, metrics.recall, metrics.f1) == (1.0, 1.0, 1.0)

    # boxes far outside every true box (true boxes lie in [0, 100]^2)
    empty = [ImageBoxes(im.true_boxes + 500.0, im.scores, im.true_boxes) for im in images]
    metrics = score_detections(empty)
    assert metrics.map50 == 0.0 and metrics.map50_95 == 0.0
    assert metrics.precision == 0.0 and metrics.recall == 0.0 and metrics.f1 == 0.0


def test_hand_computed_ap_and_prf():
    true = np.array([[0, 0, 10, 10], [20, 0, 30, 10]], float)
    # ranked: TP (0.9), FP (0.8), TP (0.7) -> precision 1, 1/2, 2/3 at recall 0.5, 0.5, 1
    pred = np.array([[0, 0, 10, 10], [50, 50, 60, 60], [20, 0, 30, 10]], float)
    image = ImageBoxes(pred, np.array([0.9, 0.8, 0.7]), true)
    # monotone envelope: 1 up to recall 0.5, 2/3 above
    assert average_precision([image], 0.5, interpolation="all_point") == pytest.approx(0.5 * 1 + 0.5 * 2 / 3)
    assert average_precision([image], 0.5, interpolation="coco101") == pytest.approx((51 * 1 + 50 * 2 / 3) / 101)
    p, r, f1 = precision_recall_f1([image], conf_threshold=0.75)
    assert (p, r) == (0.5, 0.5) and f1 == pytest.approx(0.5)
    p, r, f1 = precision_recall_f1([image], conf_threshold=0.0)
    assert p == pytest.approx(2 / 3) and r == 1.0 and f1 == pytest.approx(0.8)
    # a duplicate detection of a matched box is a false positive
    dup = ImageBoxes(np.array([[0, 0, 10, 10], [0, 0, 10, 10]], float), np.array([0.9, 0.8]), true[:1])
    assert precision_recall_f1([dup], 0.0) == (0.5, 1.0, pytest.approx(2 / 3))


def test_no_true_boxes_is_nan_not_one():
    image = ImageBoxes(np.array([[0, 0, 5, 5]], float), np.array([0.5]), np.zeros((0, 4)))
    assert np.isnan(average_precision([image], 0.5))
    with pytest.raises(ValueError, match="NaN"):
        ImageBoxes(np.array([[0, 0, np.nan, 5]]), np.array([0.5]), np.zeros((0, 4)))
    with pytest.raises((ValueError, TypeError)):  # jaxtyping's runtime check (TypeError) or our own ValueError
        ImageBoxes(np.zeros((2, 4)), np.array([0.5]), np.zeros((0, 4)))


@pytest.mark.parametrize("seed", range(8))
def test_matches_torchmetrics_coco_map(seed: int):
    torch = pytest.importorskip("torch")
    pytest.importorskip("pycocotools")
    from torchmetrics.detection import MeanAveragePrecision

    rng = np.random.default_rng(seed)
    images = []
    for _ in range(int(rng.integers(3, 9))):
        true = _random_boxes(rng, int(rng.integers(0, 8)))
        # detections: jittered copies of some true boxes (various IoUs), duplicates, and false positives
        keep = true[rng.random(len(true)) < 0.8]
        jitter = np.round(rng.normal(0, rng.uniform(0.5, 6), keep.shape) * 4) / 4
        dup = keep[rng.random(len(keep)) < 0.3]
        pred = np.concatenate([keep + jitter, dup, _random_boxes(rng, int(rng.integers(0, 6)))])
        pred[:, 2:] = np.maximum(pred[:, 2:], pred[:, :2] + 1)
        scores = np.round(rng.uniform(0.05, 1.0, len(pred)), 6)
        images.append(ImageBoxes(pred, scores, true))

    # thresholds passed as float64: torchmetrics' defaults come from float32 torch.linspace (0.2 -> 0.2000000030),
    # which moves recall points such as 7/35 = 0.2 to the next bin; COCOeval itself uses float64 np.linspace.
    metric = MeanAveragePrecision(
        box_format="xyxy",
        iou_type="bbox",
        backend="pycocotools",
        iou_thresholds=np.linspace(0.5, 0.95, 10).tolist(),
        rec_thresholds=np.linspace(0.0, 1.0, 101).tolist(),
    )
    metric.update(
        [
            dict(
                boxes=torch.tensor(im.pred_boxes, dtype=torch.float32),
                scores=torch.tensor(im.scores, dtype=torch.float32),
                labels=torch.zeros(len(im.scores), dtype=torch.int64),
            )
            for im in images
        ],
        [
            dict(
                boxes=torch.tensor(im.true_boxes, dtype=torch.float32),
                labels=torch.zeros(len(im.true_boxes), dtype=torch.int64),
            )
            for im in images
        ],
    )
    reference = metric.compute()
    map50, map50_95 = mean_average_precision(images)
    assert 0.0 < map50 < 1.0, "random case should be neither trivial nor empty"
    assert map50 == pytest.approx(float(reference["map_50"]), abs=1e-6)
    assert map50_95 == pytest.approx(float(reference["map"]), abs=1e-6)


def test_ignored_boxes_are_neither_needed_nor_false_positives():
    true = np.array([[0, 0, 10, 10]], float)
    ignored = np.array([[40, 40, 44, 44], [60, 60, 64, 64]], float)
    # a hit on the counted box, one on an ignored box, one in empty space
    pred = np.array([[0, 0, 10, 10], [40, 40, 44, 44], [90, 90, 99, 99]], float)
    image = ImageBoxes(pred, np.array([0.9, 0.8, 0.7]), true, ignored)
    scores, is_tp = match_image(image, 0.5)
    assert scores.tolist() == [0.9, 0.7] and is_tp.tolist() == [True, False]
    assert precision_recall_f1([image], 0.0) == (0.5, 1.0, pytest.approx(2 / 3))
    # without the ignore list the same detection is a false positive and the small fruit are missed
    plain = ImageBoxes(pred, image.scores, np.concatenate([true, ignored]))
    assert precision_recall_f1([plain], 0.0) == (pytest.approx(2 / 3), pytest.approx(2 / 3), pytest.approx(2 / 3))
    # a detection overlapping a counted and an ignored box takes the counted one even at lower IoU
    both = ImageBoxes(np.array([[0, 0, 10, 12]], float), np.array([0.9]), true, np.array([[0, 0, 10, 12]], float))
    assert match_image(both, 0.5)[1].tolist() == [True]
    # every true box ignored: AP undefined, as with no boxes
    assert np.isnan(average_precision([ImageBoxes(pred, image.scores, np.zeros((0, 4)), ignored)], 0.5))


@pytest.mark.parametrize("seed", range(6))
def test_ignored_boxes_match_cocoeval_area_range(seed: int):
    """Ignored boxes are COCOeval's gts outside the area range: the same mAPs as pycocotools with ``areaRng``."""
    pytest.importorskip("pycocotools")
    from pycocotools.coco import COCO
    from pycocotools.cocoeval import COCOeval

    min_area = 10.0
    rng = np.random.default_rng(100 + seed)
    images, gts, dts = [], [], []
    for image_id in range(int(rng.integers(3, 9))):
        true = _random_boxes(rng, int(rng.integers(1, 9)))
        visible = rng.integers(1, 60, len(true)).astype(float)  # visible pixels: unrelated to the box's size
        keep = true[rng.random(len(true)) < 0.8]
        jitter = np.round(rng.normal(0, rng.uniform(0.5, 4), keep.shape) * 4) / 4
        pred = np.concatenate([keep + jitter, _random_boxes(rng, int(rng.integers(0, 5)))])
        pred[:, 2:] = np.maximum(pred[:, 2:], pred[:, :2] + 4)  # every detection's area >= 16 > min_area
        scores = np.round(rng.uniform(0.05, 1.0, len(pred)), 6)
        small = visible < min_area
        images.append(ImageBoxes(pred, scores, true[~small], true[small]))
        for box, area in zip(true, visible, strict=True):
            gts.append({"id": len(gts) + 1, "image_id": image_id, "category_id": 1, "iscrowd": 0, "area": area,
                        "bbox": [box[0], box[1], box[2] - box[0], box[3] - box[1]]})  # fmt: skip
        for box, score in zip(pred, scores, strict=True):
            dts.append({"image_id": image_id, "category_id": 1, "score": float(score),
                        "bbox": [box[0], box[1], box[2] - box[0], box[3] - box[1]]})  # fmt: skip
    if not any(len(im.true_boxes) for im in images):
        pytest.skip("every box ignored in this draw")
    coco = COCO()
    coco.dataset = {"images": [{"id": i} for i in range(len(images))], "annotations": gts,
                    "categories": [{"id": 1, "name": "fruit"}]}  # fmt: skip
    coco.createIndex()
    evaluation = COCOeval(coco, coco.loadRes(dts), "bbox")
    evaluation.params.areaRng, evaluation.params.areaRngLbl, evaluation.params.maxDets = (
        [[min_area, 1e10]],
        ["all"],
        [100],
    )
    evaluation.evaluate()
    evaluation.accumulate()
    precision = evaluation.eval["precision"][:, :, 0, 0, 0]  # (IoU thresholds, recall points)
    reference = [float(np.mean(np.where(p > -1, p, 0.0))) for p in precision]
    map50, map50_95 = mean_average_precision(images)
    assert any(len(im.ignore_boxes) for im in images) and 0.0 < map50 < 1.0
    assert map50 == pytest.approx(reference[0], abs=1e-6)
    assert map50_95 == pytest.approx(float(np.mean(reference)), abs=1e-6)
