"""Detections in 3D to fruit: complete-linkage clustering with a distance from the fruit size (with `triangulate`,
then placing by the detections' rays: `rays.py`), then a view count.

Complete linkage joins two groups only when every pair of their detections is within the merge distance, so a
cluster never spans more than that distance and fruit do not chain together the way single-linkage or DBSCAN
neighbourhoods can in a dense canopy. The default merge distance is ``merge_fraction`` x the median detected
diameter: two fruit one fruit-width apart stay two, while one fruit's detections from many views (which scatter by
much less than a diameter) become one. A cluster is a fruit when at least ``min_views`` distinct views saw it (and, in the pipeline, at least
``min_view_fraction`` of the views that show its place).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import List, Optional, Sequence, Tuple

import numpy as np
from jaxtyping import Float, Int

from agrinerf_ns.count.lift import LiftedDetection
from agrinerf_ns.rays import triangulate


@dataclass(frozen=True)
class ClusterConfig:
    """How detections become fruit."""

    min_views: int = 2
    """Distinct views a fruit must be detected in."""
    merge_distance: Optional[float] = None
    """Largest distance between two detections of one fruit (dataset units); None: ``merge_fraction`` x the median
    detected diameter."""
    merge_fraction: Optional[float] = None
    """The default merge distance as a fraction of the median detected diameter; None: the path's own (views 0.8;
    bodies 1.2, whose sightings scatter more along the thermal rays: chosen on tuning captures,
    results/fruit-count-dark)."""
    triangulate: bool = False
    """Place each fruit where the rays of its detections meet (`rays.triangulate`) rather than at the median of their
    depth-lifted centres; the rendered depth then only groups them. Better where the field's depth at the fruit is
    off by more than a fruit (F1 doubled on CPU-trained `agrinerf-lite` runs), worse where it is right (the capture's
    true depth: a detection's centroid ray misses a partly hidden fruit's centre), and it counts fewer fruit
    (docs/count.md)."""
    association_factor: float = 3.0
    """With `triangulate`: detections are grouped at this many times the merge distance before their rays place and
    split the groups (a trained field's depth scatters one fruit's detections by more than a fruit)."""
    min_view_fraction: float = 0.25
    """Of the views that show a fruit's centre unoccluded (:mod:`agrinerf_ns.count.support`), the fraction that must
    have detected it (0: no test)."""
    single_view_confidence: Optional[float] = None
    """Also count a fruit detected in fewer than ``min_views`` views when one of its detections was lifted with at
    least this depth confidence (`lift.depth_confidence`: a solid fruit-sized body at the rendered depth) and, in the
    pipeline, few views show its place (``min_view_fraction``): a fruit seen well once, behind leaves from the other
    viewpoints. None: no such fruit."""


@dataclass(frozen=True)
class Fruit:
    """A counted fruit, in the dataset's frame and units."""

    centre: Float[np.ndarray, "3"]
    diameter: float
    views: int
    detections: int
    temperature: Optional[float]
    score: float


def cluster_labels(points: Float[np.ndarray, "n 3"], distance: float) -> Int[np.ndarray, " n"]:
    """Complete-linkage cluster label (0 ..) of each point, no two points of a cluster farther apart than
    ``distance``."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    if len(points) < 2:
        return np.zeros(len(points), dtype=np.int64)
    from scipy.cluster.hierarchy import fcluster, linkage

    tree = linkage(points, method="complete")
    return fcluster(tree, t=distance, criterion="distance").astype(np.int64) - 1


VIEWS_MERGE_FRACTION = 0.8
"""The views path's merge fraction (:attr:`ClusterConfig.merge_fraction`)."""


def merge_distance(detections: Sequence[LiftedDetection], config: ClusterConfig) -> float:
    """The merge distance of ``config`` for these detections."""
    if config.merge_distance is not None:
        return config.merge_distance
    if not detections:
        return 0.0
    fraction = VIEWS_MERGE_FRACTION if config.merge_fraction is None else config.merge_fraction
    return fraction * float(np.median([d.diameter for d in detections]))


Group = Tuple[List[LiftedDetection], Float[np.ndarray, "3"]]
"""Detections of one fruit and its centre."""


def _median_groups(detections: Sequence[LiftedDetection], distance: float) -> List[Group]:
    """Complete-linkage groups of the depth-lifted centres, each at their median."""
    labels = cluster_labels(np.stack([d.centre for d in detections]), distance)
    groups = []
    for label in np.unique(labels):
        members = [d for d, keep in zip(detections, labels == label, strict=True) if keep]
        groups.append((members, np.median(np.stack([d.centre for d in members]), axis=0)))
    return groups


def _placed(members: List[LiftedDetection], distance: float, reach: float, min_views: int) -> List[Group]:
    """A group placed where its rays meet (`triangulate.triangulate`) within ``reach`` of the median of its kept
    detections' depth-lifted centres, the rays that miss that point placed the same way as a group of their own
    (another fruit in the group); where rays do not meet, split and placed by the depth as without rays."""
    radius = 0.5 * float(np.median([d.diameter for d in members]))
    origins = np.stack([np.asarray(d.origin) for d in members])
    rays = np.stack([np.asarray(d.ray) for d in members])
    point, keep = triangulate(origins, rays, [d.view for d in members], radius, min_views)
    kept = [d for d, k in zip(members, keep, strict=True) if k]
    # the rays of two fruit can meet anywhere: the point must lie where the depth put its detections
    if point is None or np.linalg.norm(point - np.median(np.stack([d.centre for d in kept]), axis=0)) > reach:
        return _median_groups(members, distance)
    rest = [d for d, k in zip(members, keep, strict=True) if not k]
    return [(kept, point)] + (_placed(rest, distance, reach, min_views) if rest else [])


def _triangulated_groups(detections: Sequence[LiftedDetection], config: ClusterConfig) -> List[Group]:
    """Groups at `association_factor` x the merge distance, each placed by its rays; then the groups whose points
    lie within the merge distance (one fruit the depth had split) joined and placed again."""
    distance = merge_distance(detections, config)
    reach = config.association_factor * distance
    placed: List[Group] = []
    for members, _ in _median_groups(detections, reach):
        placed += _placed(members, distance, reach, config.min_views)
    if len(placed) < 2:
        return placed
    labels = cluster_labels(np.stack([centre for _, centre in placed]), distance)
    joined: List[Group] = []
    for label in np.unique(labels):
        parts = [group for group, keep in zip(placed, labels == label, strict=True) if keep]
        if len(parts) == 1:
            joined += parts
            continue
        members = [d for group, _ in parts for d in group]
        joined += _placed(members, distance, reach, config.min_views)
    return joined


def confident(members: Sequence[LiftedDetection], threshold: Optional[float]) -> bool:
    """Whether a detection of these was lifted with at least ``threshold`` depth confidence (never when None)."""
    return threshold is not None and max(d.depth_confidence for d in members) >= threshold


def cluster_fruit(detections: Sequence[LiftedDetection], config: ClusterConfig = ClusterConfig()) -> List[Fruit]:
    """Fruit from lifted detections, largest view count first: placed where their rays meet where every detection
    has its ray and `triangulate` is on, else at the median of their depth-lifted centres."""
    if not detections:
        return []
    if config.triangulate and all(d.ray is not None and d.origin is not None for d in detections):
        groups = _triangulated_groups(detections, config)
    else:
        groups = _median_groups(detections, merge_distance(detections, config))
    fruit = []
    for members, centre in groups:
        views = len({d.view for d in members})
        if views < config.min_views and not confident(members, config.single_view_confidence):
            continue
        temperatures = [d.temperature for d in members if d.temperature is not None]
        fruit.append(
            Fruit(
                centre=np.asarray(centre, np.float64),
                diameter=float(np.median([d.diameter for d in members])),
                views=views,
                detections=len(members),
                temperature=float(np.mean(temperatures)) if temperatures else None,
                score=float(np.mean([d.score for d in members])),
            )
        )
    return sorted(fruit, key=lambda f: (-f.views, tuple(f.centre)))
