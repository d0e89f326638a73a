"""The lit frames' fruit masks placed in 3D without a field (``fruit/mask_bodies.py``): touching fruit cut into discs,
each fruit placed where the frames that show it agree, a fruit too few frames show left out, its temperature read
where the thermal camera sees it; and a real lit capture processed and counted by ``agrinerf-count --path bodies``."""

from __future__ import annotations

import json
from pathlib import Path
from typing import List

import numpy as np
import pytest

from agrinerf_ns.fruit.mask_bodies import (
    disc_temperature,
    mask_blobs,
    mask_sightings,
    outline_points,
    rgb_geometry,
    track_points,
)
from agrinerf_ns.fruit.thermal_bodies import BodySettings, FrameGeometry, sweep_blobs

K = np.array([[800.0, 0.0, 160.0], [0.0, 800.0, 120.0], [0.0, 0.0, 1.0]])
SIZE = (240, 320)
RADIUS = 0.03
FRUIT = np.array([[0.20, 1.5, 0.05], [0.35, 1.6, -0.10], [0.50, 1.4, 0.12], [0.60, 1.5, 0.0]])


def _camera(x: float) -> np.ndarray:
    """A camera at (x, 0, 0) looking along +y (OpenCV axes: x right, y down, z forward)."""
    c2w = np.eye(4)
    c2w[:3, :3] = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
    c2w[:3, 3] = [x, 0.0, 0.0]
    return c2w


def _disc(mask: np.ndarray, row: float, col: float, radius: float) -> None:
    rows, cols = np.mgrid[0 : mask.shape[0], 0 : mask.shape[1]]
    mask |= (rows - row) ** 2 + (cols - col) ** 2 <= radius**2


def _masks(views: List[FrameGeometry], fruit: np.ndarray) -> List[np.ndarray]:
    """Each frame's mask: every fruit in front of it drawn as its projected disc."""
    masks = []
    for view in views:
        mask = np.zeros(SIZE, bool)
        rows, cols, distance = view.project(fruit)
        for r, c, d in zip(rows, cols, distance, strict=True):
            if np.isfinite(r):
                _disc(mask, r, c, K[0, 0] * RADIUS / d)
        masks.append(mask)
    return masks


def test_touching_fruit_are_two_discs_and_a_speckled_fruit_one() -> None:
    mask = np.zeros((60, 80), bool)
    _disc(mask, 30, 25, 9.0)
    _disc(mask, 30, 43, 9.0)  # touching: centres 18 px apart, radii 9
    found = sorted(mask_blobs(mask, frame=3), key=lambda b: b.col)
    assert len(found) == 2 and all(b.frame == 3 for b in found)
    for blob, col in zip(found, (25, 43), strict=True):
        assert abs(blob.col - col) <= 1.5 and abs(blob.row - 30) <= 1.5
        assert np.sqrt(2.0) * blob.sigma == pytest.approx(9.0, abs=1.5)
    speckled = np.zeros((60, 80), bool)
    _disc(speckled, 30, 40, 10.0)
    speckled[::3, ::3] = False  # the colour rule's holes at highlights and dim pixels
    (blob,) = mask_blobs(speckled, frame=0)
    assert np.sqrt(2.0) * blob.sigma == pytest.approx(10.0, abs=1.5)
    assert mask_blobs(np.zeros((20, 20), bool), frame=0) == []


def test_fruit_are_placed_where_the_frames_agree_and_a_fruit_seen_twice_is_left_out() -> None:
    views = [rgb_geometry(K, _camera(x)) for x in 0.075 * np.arange(12)]
    masks = _masks(views, FRUIT)
    lone = np.array([1.0, 1.5, 0.0])  # drawn in two frames only (the rest of the row hides it)
    for k in (10, 11):
        rows, cols, distance = views[k].project(lone[None])
        _disc(masks[k], rows[0], cols[0], K[0, 0] * RADIUS / distance[0])
    found = mask_sightings(masks, views, BodySettings(min_views=3))
    centres = np.stack([s.centre for s in found])
    nearest = np.linalg.norm(centres[:, None] - FRUIT[None], axis=-1)
    assert nearest.min(1).max() < 0.02  # every sighting on a true fruit (the lone fruit's among none)
    assert set(nearest.argmin(1)) == set(range(len(FRUIT)))
    assert np.linalg.norm(centres - lone, axis=1).min() > 0.2
    for s in found:
        assert s.diameter == pytest.approx(2 * RADIUS, rel=0.25)
        assert s.temperature is None
    assert len(mask_sightings(masks, views, BodySettings(min_views=2))) > len(found)  # two frames place it


def _sphere_hits(origins: np.ndarray, rays: np.ndarray, centre: np.ndarray, radius: float) -> np.ndarray:
    """Where each ray first meets the sphere (inf where it misses)."""
    offset = origins - centre
    b = (offset * rays).sum(-1)
    disc = b * b - ((offset * offset).sum(-1) - radius**2)
    return np.where(disc > 0, -b - np.sqrt(np.maximum(disc, 0.0)), np.inf)


def test_a_fruit_a_nearer_leaf_cuts_is_placed_by_its_outline() -> None:
    fruit, leaf = np.array([0.3, 2.5, 0.0]), np.array([0.25, 1.8, 0.01])
    views = [rgb_geometry(K, _camera(x)) for x in 0.3 + 0.075 * np.arange(-5, 6)]
    rows, cols = np.mgrid[0 : SIZE[0], 0 : SIZE[1]]
    masks = []
    for view in views:  # the fruit's pixels where the leaf (not in the mask) does not hide it
        origins, rays = view.rays(rows.ravel().astype(float), cols.ravel().astype(float))
        on_fruit, on_leaf = _sphere_hits(origins, rays, fruit, 0.04), _sphere_hits(origins, rays, leaf, 0.03)
        masks.append((np.isfinite(on_fruit) & ~(on_leaf < on_fruit)).reshape(SIZE))
    assert min(m.sum() for m in masks) < 0.3 * max(m.sum() for m in masks)  # the leaf hides most of it somewhere
    blobs = [b for k, mask in enumerate(masks) for b in mask_blobs(mask, k)]
    points, links = sweep_blobs(blobs, views, BodySettings(min_views=3))
    tracked = track_points(blobs, views, points, links)
    placed = np.isfinite(tracked[:, 0])
    assert placed.sum() >= 5
    # the visible parts' centres follow the leaf, and their rays meet off the fruit; its outline's ball does not
    assert np.linalg.norm(tracked[placed] - fruit, axis=1).max() > 0.02
    outlined = outline_points(blobs, views, masks, tracked, links)
    assert np.linalg.norm(outlined[placed] - fruit, axis=1).max() < 0.005
    found = mask_sightings(masks, views, BodySettings(min_views=3))
    assert found and max(np.linalg.norm(s.centre - fruit) for s in found) < 0.005


def test_a_sighting_takes_the_temperature_where_the_thermal_camera_sees_it() -> None:
    view = rgb_geometry(K, _camera(0.0))
    thermal = FrameGeometry(K, _camera(0.0), np.array([0.05, 0.0, 0.0]))  # 5 cm beside the RGB camera
    celsius = np.full(SIZE, 15.0, np.float32)
    rows, cols, _ = thermal.project(FRUIT[:1])
    fruit = np.zeros(SIZE, bool)
    _disc(fruit, rows[0], cols[0], 12.0)
    celsius[fruit] = 21.0
    celsius[:, :5] = np.nan  # outside the thermal camera's view
    assert disc_temperature(FRUIT[0], 2 * RADIUS, thermal, celsius) == pytest.approx(21.0)
    rgb_rows, rgb_cols, _ = view.project(FRUIT[:1])
    assert abs(rgb_cols[0] - cols[0]) > 5  # the two cameras see the fruit at different pixels
    assert disc_temperature(np.array([0.0, -1.0, 0.0]), 0.06, thermal, celsius) is None  # behind the camera


def test_a_lit_capture_is_counted_from_its_masks_without_a_run(tmp_path: Path) -> None:
    from agrinerf_ns.count.cli import CountArgs, main
    from agrinerf_ns.count.pipeline import CountConfig
    from agrinerf_ns.dataset_format import FRUIT_BODIES
    from agrinerf_ns.process.capture_to_dataset import process_capture
    from agrinerf_ns.process.config import ProcessConfig
    from agrinerf_ns.process.fruit_mask_makers import MaskMakerConfig
    from agrinerf_ns.synth.capture import generate_capture
    from agrinerf_ns.synth.config import SynthConfig

    raw = tmp_path / "raw"
    generate_capture(SynthConfig(scene="garden", lighting="bright", views=16, width=160, height=120, heldout=0,
                                 rgb_hfov_deg=22.0, thermal_hfov_deg=20.0, event_substeps=1, event_supersample=1),
                     raw)  # fmt: skip
    data = process_capture(raw, tmp_path / "data", ProcessConfig(poses="given", show_progress=False,
                                                                 fruit_mask_maker="auto"))  # fmt: skip
    sightings = json.loads((data / FRUIT_BODIES).read_text())["sightings"]
    assert sightings and {s["camera"] for s in sightings} == {"rgb"}
    warm = [s["temperature"] is not None for s in sightings]  # radiometric: read where the thermal camera sees them
    assert sum(warm) >= 0.8 * len(warm)
    record = json.loads((data / "transforms.json").read_text())["agrinerf"]["fruit_masks"]
    assert record["rgb_bodies"]["sightings"] == len(sightings)
    result = main(
        CountArgs(out=tmp_path / "count", path="bodies", data=data, truth=raw, count=CountConfig(max_range=2.4))
    )
    assert result.score is not None and result.score.true_positives >= 5
    assert result.score.precision >= 0.5
    assert result.score.mean_temperature_error < 1.0
    report = json.loads((tmp_path / "count" / "count.json").read_text())
    assert report["path"] == "bodies" and report["sightings"] == {"rgb": len(sightings), "thermal": 0}
    # frames as dim as dusk keep their colour masks, and their fruit are placed from the thermal camera instead
    dim = process_capture(raw, tmp_path / "dim", ProcessConfig(poses="given", show_progress=False,
                                                               fruit_mask_maker="auto",
                                                               mask_maker=MaskMakerConfig(dim_level=1.0)))  # fmt: skip
    assert {s["camera"] for s in json.loads((dim / FRUIT_BODIES).read_text())["sightings"]} == {"thermal"}
    for name in sorted(p.name for p in (data / "fruit_masks").iterdir()):
        assert (dim / "fruit_masks" / name).read_bytes() == (data / "fruit_masks" / name).read_bytes()
    record = json.loads((dim / "transforms.json").read_text())["agrinerf"]["fruit_masks"]
    assert record["bodies"]["dim_frames"] == 16 and "rgb_bodies" not in record
