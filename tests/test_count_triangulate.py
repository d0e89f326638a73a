"""Fruit placed where their detections' rays meet (`agrinerf_ns/rays.py`, `--triangulate`)."""

from __future__ import annotations

from typing import List

import numpy as np
import pytest

from agrinerf_ns.count.cluster import ClusterConfig, cluster_fruit
from agrinerf_ns.count.lift import LiftedDetection
from agrinerf_ns.rays import closest_point, enclosing_ball, miss_distances, triangulate

FRUIT_D = 0.08
TRIANGULATE = ClusterConfig(min_views=2, min_view_fraction=0.0, triangulate=True)


def _cameras(views: int, spacing: float = 0.15) -> np.ndarray:
    """Camera centres along a row (x), 1.5 m from the fruit plane (y = 0)."""
    return np.stack([np.array([spacing * (v - views / 2), -1.5, 0.0]) for v in range(views)])


def _seen(centre, cameras: np.ndarray, depth_error: float, rng: np.random.Generator, first_view: int = 0):
    """Detections of a fruit at `centre` from `cameras`: rays through the centre (direction noise 0.1 degree), and
    depth-lifted centres off along their ray by a random depth error of scale `depth_error`."""
    out: List[LiftedDetection] = []
    for v, origin in enumerate(cameras):
        ray = np.asarray(centre) - origin
        ray = ray / np.linalg.norm(ray) + rng.normal(0.0, np.radians(0.1), 3)
        ray = ray / np.linalg.norm(ray)
        lifted = np.asarray(centre) + rng.normal(0.0, depth_error) * ray
        out.append(LiftedDetection(first_view + v, lifted, FRUIT_D, 1.0, 20.0, origin=origin, ray=ray))
    return out


def test_closest_point_of_rays_through_one_point_is_that_point() -> None:
    point = np.array([0.3, 1.2, -0.4])
    origins = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    rays = (point - origins) / np.linalg.norm(point - origins, axis=1, keepdims=True)
    found = closest_point(origins, rays)
    assert found is not None and np.allclose(found, point, atol=1e-9)
    assert np.allclose(miss_distances(point, origins, rays), 0.0, atol=1e-9)
    assert closest_point(origins[:1], rays[:1]) is None  # one ray places nothing


def test_parallel_rays_and_points_behind_a_camera_place_nothing() -> None:
    origins = np.array([[0.0, 0.0, 0.0], [0.001, 0.0, 0.0]])
    parallel = np.array([[0.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
    assert closest_point(origins, parallel) is None
    diverging = np.array([[-0.6, -0.8, 0.0], [0.6, -0.8, 0.0]])  # they meet behind both cameras
    assert closest_point(np.array([[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0]]), diverging) is None


def test_a_ray_of_another_fruit_is_dropped() -> None:
    rng = np.random.default_rng(0)
    cameras = _cameras(6)
    mine = _seen([0.0, 0.0, 0.0], cameras, 0.0, rng)
    other = _seen([0.2, 0.0, 0.1], cameras[:1], 0.0, rng, first_view=6)
    members = mine + other
    origins = np.stack([d.origin for d in members])
    rays = np.stack([d.ray for d in members])
    point, keep = triangulate(origins, rays, [d.view for d in members], 0.5 * FRUIT_D, 2)
    assert point is not None and np.linalg.norm(point) < 0.01
    assert keep.tolist() == [True] * 6 + [False]
    assert triangulate(origins[:1], rays[:1], [0], 0.5 * FRUIT_D, 2)[0] is None


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_rays_place_fruit_whose_depth_is_off_by_more_than_a_fruit(seed: int) -> None:
    """Two fruit 1.5 diameters apart, each seen from 8 places, their depth off by 10 cm (more than a fruit): the
    median of the depth-lifted centres misses them (or merges them), their rays place both within 1.5 cm."""
    rng = np.random.default_rng(seed)
    truth = np.array([[0.0, 0.0, 0.0], [1.5 * FRUIT_D, 0.0, 0.05]])
    cameras = _cameras(8)
    detections = _seen(truth[0], cameras, 0.1, rng) + _seen(truth[1], cameras, 0.1, rng, first_view=0)
    placed = cluster_fruit(detections, TRIANGULATE)
    assert len(placed) == 2
    errors = sorted(min(np.linalg.norm(f.centre - t) for f in placed) for t in truth)
    assert errors[-1] < 0.015, errors
    lifted = cluster_fruit(detections, ClusterConfig(min_views=2, min_view_fraction=0.0))
    worst = max(min(np.linalg.norm(f.centre - t) for f in lifted) for t in truth)
    assert worst > 0.02, worst  # the depth alone does not place them


def test_without_rays_or_with_the_option_off_the_depth_places_them() -> None:
    rng = np.random.default_rng(3)
    detections = _seen([0.0, 0.0, 0.0], _cameras(5), 0.005, rng)
    no_rays = [LiftedDetection(d.view, d.centre, d.diameter, d.score, d.temperature) for d in detections]
    for config, dets in ((ClusterConfig(min_view_fraction=0.0), detections), (TRIANGULATE, no_rays)):
        fruit = cluster_fruit(dets, config)
        assert len(fruit) == 1 and fruit[0].views == 5
        assert np.allclose(fruit[0].centre, np.median(np.stack([d.centre for d in dets]), axis=0))


def test_a_large_group_tries_a_fixed_sample_of_its_crossings() -> None:
    """200 rays through one point (19900 pairs): placed as well from the sample, the same on every call."""
    rng = np.random.default_rng(4)
    detections = _seen([0.0, 0.0, 0.0], _cameras(200, spacing=0.01), 0.0, rng)
    origins = np.stack([d.origin for d in detections])
    rays = np.stack([d.ray for d in detections])
    first = triangulate(origins, rays, list(range(200)), 0.5 * FRUIT_D, 2)
    again = triangulate(origins, rays, list(range(200)), 0.5 * FRUIT_D, 2)
    assert first[0] is not None and again[0] is not None
    assert np.linalg.norm(first[0]) < 0.01 and np.array_equal(first[0], again[0]) and bool(first[1].all())


def test_the_smallest_ball_the_rays_meet_is_the_sphere_they_graze() -> None:
    centre, radius = np.array([0.2, 2.0, 0.1]), 0.04
    origins, rays = [], []
    for x in (-0.4, 0.0, 0.4):  # tangent rays from three cameras, on all four sides of the sphere
        origin = np.array([x, 0.0, 0.0])
        axis = (centre - origin) / np.linalg.norm(centre - origin)
        side = np.cross(axis, [0.0, 0.0, 1.0])
        side /= np.linalg.norm(side)
        up = np.cross(side, axis)
        for offset in (side, -side, up, -up):
            ray = (centre + radius * offset) - origin
            origins.append(origin)
            rays.append(ray / np.linalg.norm(ray))
    found, r = enclosing_ball(np.array(origins), np.array(rays), centre + np.array([0.05, -0.3, 0.02]))
    assert found is not None
    assert np.linalg.norm(found - centre) < 0.005 and r == pytest.approx(radius, abs=0.003)
    assert enclosing_ball(np.array(origins[:1]), np.array(rays[:1]), centre) == (
        None,
        pytest.approx(float("nan"), nan_ok=True),
    )
