"""A counting source is one row of one table (issue 65): a toy source added here, in this file only, is rendered into
a render folder, found in its views by the real ``run_count`` (also as the ``auto`` choice of views that hold nothing
else), and sampled in the field by the real field counter."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np
import pytest
from helpers.fruit_field import FRUIT_C, assert_finds_the_known_fruit, fruit_model

from agrinerf_ns.count.cluster import ClusterConfig
from agrinerf_ns.count.components import ComponentConfig
from agrinerf_ns.count.detectors import DetectorConfig
from agrinerf_ns.count.field_count import FieldCountConfig, count_model
from agrinerf_ns.count.pipeline import CountConfig, run_count
from agrinerf_ns.count.render import RenderedView, RenderSet, WorldFrame, load_renders, save_renders
from agrinerf_ns.count.source_table import (
    SOURCE_TABLE,
    RenderedOutput,
    SourceRow,
    add_source,
    auto_order,
    channel,
    sample_temperature,
)
from agrinerf_ns.count.sources import field_outputs, resolve_source
from agrinerf_ns.count.volume import VolumeConfig

IDENTITY = WorldFrame(np.eye(4)[:3], 1.0)
KELVIN = SourceRow(
    "kelvin",
    lambda plan: plan.has_temperature,
    renders=(RenderedOutput("kelvin", missing=" (the toy source's)"),),
    image=channel("kelvin"),
    sample=lambda model, coords, heads: sample_temperature(model, coords, heads) + 273.15,
    thermal=True,
    order={"views": 9, "field": 9},
)
"""The toy source: the temperature in kelvin, rendered as an output of its own and sampled from the temperature head."""


@pytest.fixture
def kelvin() -> Iterator[SourceRow]:
    """The toy source in the table for one test (taken out again afterwards)."""
    add_source(KELVIN)
    try:
        yield KELVIN
    finally:
        del SOURCE_TABLE[KELVIN.name]


def _warm_disc_view(name: str, centres: list, depth: float = 1.5, focal: float = 200.0) -> RenderedView:
    """A 128x96 view of a plane at ``depth`` (leaves at 291 K) with 6 cm fruit 3 K warmer at ``centres`` (pixels);
    it renders only the toy's output (no RGB, no thermal)."""
    height, width = 96, 128
    kelvin = 291.15 + np.random.default_rng(0).normal(0, 0.03, (height, width))
    for x, y in centres:
        cv2.circle(kelvin, (x, y), 4, 294.15, -1)
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    dirs = np.stack([(u - width / 2) / focal, -(v - height / 2) / focal, -np.ones_like(u)], -1)
    norm = np.linalg.norm(dirs, axis=-1, keepdims=True)
    return RenderedView(
        name, "train", f"images/{name}.png", None, depth * norm[..., 0], np.ones((height, width)),
        np.zeros((height, width, 3)), dirs / norm, focal, extra={"kelvin": kelvin.astype(np.float32)},
    )  # fmt: skip


def test_a_toy_source_added_as_one_row_counts_in_views_and_in_the_field(kelvin: SourceRow, tmp_path: Path) -> None:
    """One row: its render output is saved and read back, the view path finds its four fruit by name and as the
    ``auto`` choice of views that hold nothing else, the field path samples it and finds the known fruit."""
    centres = [(20, 20), (60, 25), (100, 20), (30, 70)]
    views = [_warm_disc_view("000000", centres)]
    save_renders(RenderSet(views, IDENTITY, None, None, "toy"), tmp_path / "renders")
    with np.load(tmp_path / "renders" / "train_000000.npz") as data:
        assert "kelvin" in data and data["kelvin"].dtype == np.float32
    (loaded,) = load_renders(tmp_path / "renders").views
    np.testing.assert_array_equal(loaded.optional_output("kelvin"), views[0].extra["kelvin"])
    assert loaded.outputs().available() == ("kelvin",)
    with pytest.raises(ValueError, match="view 000000: the run renders no 'kelvin' output \\(the toy source's\\)"):
        RenderedView(**{**loaded.__dict__, "extra": {}}).optional_output("kelvin")

    for source in ("kelvin", "auto"):
        settings = CountConfig(detect=DetectorConfig(source=source), cluster=ClusterConfig(min_views=1))
        result = run_count(tmp_path / source, settings, renders_dir=tmp_path / "renders")
        report = json.loads((tmp_path / source / "count.json").read_text())
        assert len(result.fruit) == 4 and report["fruit"] == 4 and report["detector"]["source"] == "kelvin", report
    assert resolve_source("auto", "views", loaded.outputs()) == (
        "kelvin",
        "the run's first thermal output (temperature, thermal, kelvin)",
    )

    model = fruit_model(steps=300)
    assert "kelvin" in field_outputs(model).available() and auto_order("field")[-1] == "kelvin"
    config = FieldCountConfig(
        source="kelvin",
        volume=VolumeConfig(voxel_size=0.025, density_threshold=10.0),
        components=ComponentConfig(min_diameter=0.1, max_diameter=0.4, background_size=0.5, min_views=1),
    )
    box = np.array([[-1.0] * 3, [1.0] * 3])
    result, sampled, info = count_model(model, None, IDENTITY, config, box=box)
    assert info["source"] == "kelvin" and np.nanmedian(sampled.feature) > 273.15 + 10  # kelvin, not Celsius
    assert_finds_the_known_fruit(result.fruit)
    assert all(abs(f.temperature - FRUIT_C) < 1.0 for f in result.fruit)  # type: ignore[operator]


def test_a_source_is_added_once() -> None:
    with pytest.raises(ValueError, match="counting source 'rgb' exists"):
        add_source(SourceRow("rgb", lambda plan: True))
    assert tuple(SOURCE_TABLE) == ("fruit", "temperature", "thermal_camera", "thermal", "rgb")
