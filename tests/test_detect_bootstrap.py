"""Bootstrap intervals of mAP50 / mAP50-95 over held-out images and paired differences (agrinerf_ns.detect.bootstrap)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from agrinerf_ns.detect.bootstrap import BootstrapMaps, Interval, MatchedImages, bootstrap_maps, resample_counts
from agrinerf_ns.detect.box_metrics import ImageBoxes, mean_average_precision


def _image(rng: np.random.Generator, hit_rate: float = 0.6) -> ImageBoxes:
    """Three fruit 20 px wide; each found with probability ``hit_rate`` (a box shifted by up to 4 px), plus a false
    detection in empty space and a detection on an ignored fruit."""
    true = np.array([[10, 10, 30, 30], [50, 10, 70, 30], [90, 10, 110, 30]], float)
    ignored = np.array([[10, 60, 20, 70]], float)
    found = true[rng.uniform(size=3) < hit_rate] + rng.uniform(-4, 4, (1, 4))
    pred = np.concatenate([found, [[200, 200, 220, 220]], ignored])
    return ImageBoxes(pred, rng.uniform(0.05, 1.0, len(pred)), true, ignored)


def _images(n: int, seed: int, hit_rate: float = 0.6) -> list:
    rng = np.random.default_rng(seed)
    return [_image(rng, hit_rate) for _ in range(n)]


def _maps(images: list, frames=None) -> BootstrapMaps:
    frames = frames or [f"{i:06d}" for i in range(len(images))]
    return bootstrap_maps(MatchedImages.from_images(frames, images))


def test_every_image_once_gives_the_scored_maps() -> None:
    """The bootstrap's point estimate is the row's mAP, ignored boxes and all (same ranking, same interpolation)."""
    for seed in range(6):
        images = _images(12, seed)
        maps = _maps(images)
        assert (maps.map50, maps.map50_95) == mean_average_precision(images)
        matched = MatchedImages.from_images([str(i) for i in range(12)], images)
        all_point = matched.average_precisions(np.ones((1, 12)), "all_point")[0]
        # all-point: the same area, summed with zero-width steps for the left-out detections (rounding only)
        assert all_point[0] == pytest.approx(mean_average_precision(images, interpolation="all_point")[0], abs=1e-12)


def test_an_image_drawn_twice_counts_as_two_copies() -> None:
    images = _images(5, 7)
    matched = MatchedImages.from_images([str(i) for i in range(5)], images)
    counts = np.array([[2, 0, 1, 0, 2]])
    copies = [images[0], images[0], images[2], images[4], images[4]]
    assert np.allclose(matched.average_precisions(counts)[0, 0], mean_average_precision(copies)[0])


def test_interval_holds_the_estimate_and_shrinks_with_more_images() -> None:
    few, many = _maps(_images(8, 1)), _maps(_images(128, 1))
    widths = []
    for maps in (few, many):
        for interval in maps.intervals():
            assert interval.low <= interval.value <= interval.high
            assert 0.0 <= interval.low < interval.high <= 1.0
        widths.append(maps.intervals()[0].high - maps.intervals()[0].low)
    assert widths[1] < 0.5 * widths[0], widths


def test_paired_difference_of_a_row_with_itself_is_exactly_zero() -> None:
    images = _images(20, 3)
    a = _maps(images)
    b = _maps(images[::-1], [f"{i:06d}" for i in range(20)][::-1])  # the same frames in another order
    for difference in (*a.minus(a), *a.minus(b)):
        assert (difference.value, difference.low, difference.high) == (0.0, 0.0, 0.0)
        assert not difference.significant() and difference.format(signed=True) == "+0.0 [+0.0, +0.0]"
    assert a.minus(a)[0].format() == "0.0 [0.0, 0.0]"


def test_paired_difference_finds_a_real_gap_and_needs_the_same_frames() -> None:
    good, poor = _maps(_images(60, 5, hit_rate=0.9)), _maps(_images(60, 6, hit_rate=0.3))
    gap50, _ = good.minus(poor)
    assert gap50.value == pytest.approx(good.map50 - poor.map50) and gap50.significant() and gap50.low > 0
    with pytest.raises(ValueError, match="same frames"):
        good.minus(_maps(_images(59, 5)))


def test_resamples_are_seeded_and_depend_only_on_the_frames() -> None:
    frames = ["b", "a", "c"]
    counts = resample_counts(frames, 50, seed=0)
    assert counts.shape == (50, 3) and (counts.sum(axis=1) == 3).all()
    assert np.array_equal(counts, resample_counts(frames, 50, seed=0))
    assert np.array_equal(counts[:, [1, 0, 2]], resample_counts(["a", "b", "c"], 50, seed=0))
    assert not np.array_equal(counts, resample_counts(frames, 50, seed=1))


def test_matched_images_survive_json() -> None:
    images = _images(6, 2)
    matched = MatchedImages.from_images([f"f{i}" for i in range(6)], images)
    again = MatchedImages.from_json(json.loads(json.dumps(matched.to_json())))
    assert again.frames == matched.frames
    for name in ("num_true", "image", "scores", "outcome"):
        assert np.array_equal(getattr(again, name), getattr(matched, name)), name
    assert _maps(images).intervals() == bootstrap_maps(again).intervals()


def test_interval_format() -> None:
    assert Interval(0.1734, 0.121, 0.2204).format() == "17.3 [12.1, 22.0]"
    assert Interval(0.05, -0.0001, 0.1).format(signed=True) == "+5.0 [+0.0, +10.0]"
    assert Interval(-0.05, -0.1, -0.01).significant() and not Interval(0.05, -0.01, 0.1).significant()


def test_tables_print_intervals_and_paired_differences(tmp_path) -> None:
    import csv

    from agrinerf_ns.detect.box_metrics import score_detections
    from agrinerf_ns.lab.paper_merge import merge_evaluations
    from agrinerf_ns.lab.paper_tables import ResultRow, write_tables

    frames = [f"{i:06d}" for i in range(40)]
    good, poor = _images(40, 5, hit_rate=0.9), _images(40, 6, hit_rate=0.3)
    rows = [
        ResultRow("garden", "dark", label, score_detections(images), 9, MatchedImages.from_images(frames, images))
        for label, images in (("Nerfacto (RGB)", poor), ("Ours (Cross-Spectral)", good))
    ]
    md, csv_path = write_tables(rows, tmp_path, "III", "table_iii")
    text = md.read_text()
    (ours50, _), (base50, _) = _maps(good).intervals(), _maps(poor).intervals()
    assert f"| **{100 * ours50.value:.1f}** [{100 * ours50.low:.1f}, {100 * ours50.high:.1f}] |" in text
    assert f"| {base50.format()} |" in text and "95% bootstrap intervals" in text
    gap = _maps(good).minus(_maps(poor))[0]
    assert f"- Ours (Cross-Spectral) - Nerfacto (RGB): mAP50 {gap.format(signed=True)}*" in text
    table = list(csv.DictReader(csv_path.open()))
    for row in table:
        assert float(row["map50_low"]) <= float(row["map50"]) <= float(row["map50_high"])
    # metrics.json keeps the matched detections: a merged table has the same intervals
    results = [
        {"scene": r.scene, "lighting": r.lighting, "method": r.method, "step": r.step, **r.metrics.as_dict(),
         "images": r.matched.to_json()}
        for r in rows
    ]  # fmt: skip
    (tmp_path / "metrics.json").write_text(json.dumps({"command": "x", "settings": {}, "results": results}))
    merged, _ = merge_evaluations([tmp_path / "metrics.json"], tmp_path / "merged", "III", "y")
    assert text.split("\n\nCommand")[0] in merged.read_text()
