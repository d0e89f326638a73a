"""Detections in 3D to fruit: complete-linkage clustering with a distance from the fruit size, then a view count.

Complete linkage joins two groups only when every pair of their detections is within the merge distance, so a
cluster never spans more than that distance and fruit do not chain together the way single-linkage or DBSCAN
neighbourhoods can in a dense canopy. The default merge distance is ``merge_fraction`` x the median detected
diameter: two fruit one fruit-width apart stay two, while one fruit's detections from many views (which scatter by
much less than a diameter) become one. A cluster is a fruit when at least ``min_views`` distinct views saw it (and, in the pipeline, at least
``min_view_fraction`` of the views that show its place).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import List, Optional, Sequence

import numpy as np
from jaxtyping import Float, Int

from agrinerf_ns.count.lift import LiftedDetection


@dataclass(frozen=True)
class ClusterConfig:
    """How detections become fruit."""

    min_views: int = 2
    """Distinct views a fruit must be detected in."""
    merge_distance: Optional[float] = None
    """Largest distance between two detections of one fruit (dataset units); None: ``merge_fraction`` x the median
    detected diameter."""
    merge_fraction: float = 0.8
    """The default merge distance as a fraction of the median detected diameter."""
    min_view_fraction: float = 0.25
    """Of the views that show a fruit's centre unoccluded (:mod:`agrinerf_ns.count.support`), the fraction that must
    have detected it (0: no test)."""


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


def merge_distance(detections: Sequence[LiftedDetection], config: ClusterConfig) -> float:
    """The merge distance of ``config`` for these detections."""
    if config.merge_distance is not None:
        return config.merge_distance
    if not detections:
        return 0.0
    return config.merge_fraction * float(np.median([d.diameter for d in detections]))


def cluster_fruit(detections: Sequence[LiftedDetection], config: ClusterConfig = ClusterConfig()) -> List[Fruit]:
    """Fruit from lifted detections, largest view count first."""
    if not detections:
        return []
    labels = cluster_labels(np.stack([d.centre for d in detections]), merge_distance(detections, config))
    fruit = []
    for label in np.unique(labels):
        members = [d for d, keep in zip(detections, labels == label, strict=True) if keep]
        views = len({d.view for d in members})
        if views < config.min_views:
            continue
        temperatures = [d.temperature for d in members if d.temperature is not None]
        fruit.append(
            Fruit(
                centre=np.median(np.stack([d.centre for d in members]), axis=0),
                diameter=float(np.median([d.diameter for d in members])),
                views=views,
                detections=len(members),
                temperature=float(np.mean(temperatures)) if temperatures else None,
                score=float(np.mean([d.score for d in members])),
            )
        )
    return sorted(fruit, key=lambda f: (-f.views, tuple(f.centre)))
