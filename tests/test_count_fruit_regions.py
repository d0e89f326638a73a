"""`agrinerf-count --source fruit` on the view path: the regions of a view's rendered fruit probability, touching
fruit split apart, sized in the dataset's units (`agrinerf_ns/fruit/regions.py`)."""

from __future__ import annotations

from typing import List, Tuple

import numpy as np
import pytest

from agrinerf_ns.count.render import RenderedView
from agrinerf_ns.fruit.blobs import BlobConfig
from agrinerf_ns.fruit.regions import fruit_regions, split_touching

SIZE, FOCAL, DEPTH = 64, 64.0, 1.0
CONFIG = BlobConfig(min_diameter=0.1, max_diameter=0.3)
"""At depth 1 and focal 64 px, a 0.2-unit fruit is 12.8 px across."""


def _view(discs: List[Tuple[float, float, float]], probability: float = 0.9) -> RenderedView:
    """A flat view at depth 1 whose fruit output is `probability` inside each (row, col, radius px) disc."""
    y, x = np.mgrid[0:SIZE, 0:SIZE] + 0.5
    fruit = np.full((SIZE, SIZE), 0.05, np.float32)
    for row, col, radius in discs:
        fruit[(y - row) ** 2 + (x - col) ** 2 <= radius**2] = probability
    directions = np.zeros((SIZE, SIZE, 3), np.float32)
    directions[..., 2] = -1.0
    return RenderedView(name="0", split="train", file_path="0.png", rgb=None, depth=np.full((SIZE, SIZE), DEPTH),
                        accumulation=np.ones((SIZE, SIZE)), origins=np.zeros((SIZE, SIZE, 3), np.float32),
                        directions=directions, focal=FOCAL, fruit=fruit)  # fmt: skip


@pytest.mark.parametrize(
    ("discs", "expected"),
    [([(32, 32, 6.4)], 1),
     ([(32, 20, 6.4), (32, 31, 6.4)], 2),  # overlapping by 1.8 px: one region, two fruit
     ([(20, 20, 6.4), (20, 31, 6.4), (31, 26, 6.4)], 3),  # a touching cluster of three
     ([(16, 16, 6.4), (48, 48, 6.4)], 2)],
    ids=["one", "two touching", "three touching", "two apart"],
)  # fmt: skip
def test_touching_fruit_are_split_into_one_detection_each(discs: list, expected: int) -> None:
    detections = fruit_regions(_view(discs), scale=1.0, config=CONFIG)
    assert len(detections) == expected
    centres = np.array([np.argwhere(d.mask).mean(axis=0) for d in detections]) + 0.5  # pixel centres
    for row, col, _ in discs:  # each fruit found once, at its centre
        assert (np.linalg.norm(centres - [row, col], axis=1) < 2.0).sum() == 1
    assert all(0.85 < d.score <= 0.9 for d in detections)


def test_specks_elongated_strips_and_low_probability_are_not_fruit() -> None:
    assert fruit_regions(_view([(32, 32, 1.5)]), 1.0, CONFIG) == []  # 3 px across: 0.05 units, below min_diameter
    assert fruit_regions(_view([(32, 32, 6.4)], probability=0.3), 1.0, CONFIG) == []
    strip = _view([])
    assert strip.fruit is not None
    strip.fruit[30:34, 4:60] = 0.9
    assert fruit_regions(strip, 1.0, CONFIG) == []


def test_a_run_without_a_fruit_head_is_refused_with_the_reason() -> None:
    view = _view([(32, 32, 6.4)])
    view.fruit = None
    with pytest.raises(ValueError, match="no 'fruit' output .trained without fruit masks"):
        fruit_regions(view, 1.0, CONFIG)


def test_a_single_disc_is_not_split_by_its_own_distance_plateau() -> None:
    y, x = np.mgrid[0:SIZE, 0:SIZE] + 0.5
    disc = (y - 32) ** 2 + (x - 32) ** 2 <= 10.0**2
    assert len(split_touching(disc, 3.0)) == 1


def test_the_fruit_depth_places_the_regions_when_asked_and_only_on_the_fruit_source() -> None:
    from agrinerf_ns.count.detectors import DetectorConfig
    from agrinerf_ns.count.pipeline import detect_and_lift
    from agrinerf_ns.count.render import RenderSet, WorldFrame

    view = _view([(32, 32, 6.4)])
    view.depth = np.full((SIZE, SIZE), 1.4)  # the median depth passes through the fruit to the leaves behind it
    view.fruit_depth = np.full((SIZE, SIZE), DEPTH, np.float32)
    renders = RenderSet([view], WorldFrame(np.eye(4)[:3], 1.0), None, None, "agrinerf-lite", False)
    base = DetectorConfig(source="fruit", blobs=CONFIG)
    (by_median,), _ = detect_and_lift(renders, base)
    (by_fruit,), _ = detect_and_lift(renders, DetectorConfig(source="fruit", blobs=CONFIG, fruit_depth=True))
    assert by_median.centre[2] < -1.4 and -1.2 < by_fruit.centre[2] < -1.0  # the cap's median plus r / sqrt(2)
    assert by_fruit.diameter == pytest.approx(0.2, rel=0.1) and by_median.diameter > 1.3 * by_fruit.diameter
    view.fruit_depth = None  # renders made before the output: the rendered depth
    (old,), _ = detect_and_lift(renders, DetectorConfig(source="fruit", blobs=CONFIG, fruit_depth=True))
    assert np.allclose(old.centre, by_median.centre)
