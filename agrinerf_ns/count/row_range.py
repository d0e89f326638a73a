"""The row the rig drove: fruit within a range of its cameras (``agrinerf-count --max-range``).

Along a tree row the cameras also see the next row through gaps in the canopy. Those fruit are small and far, and
the next row's own pass counts them again, so a per-row yield leaves them out: a counted fruit farther than the range
from every camera of the run is dropped, and in scoring so are the true fruit farther than it from the capture's
cameras (the same cameras, moved into the capture's frame). The rig's standoff from the row plus half the row
spacing puts the cut midway between two rows.
"""

from __future__ import annotations

from typing import List, Optional, Sequence

import numpy as np
from jaxtyping import Bool, Float

from agrinerf_ns.count.cluster import Fruit


def camera_distance(points: Float[np.ndarray, "n 3"], cameras: Float[np.ndarray, "c 3"]) -> Float[np.ndarray, " n"]:
    """Distance of each point to its nearest camera centre (inf without cameras)."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    cameras = np.asarray(cameras, np.float64).reshape(-1, 3)
    if len(cameras) == 0:
        return np.full(len(points), np.inf)
    from scipy.spatial import cKDTree

    return cKDTree(cameras).query(points)[0].astype(np.float64)


def check_range(max_range: Optional[float]) -> None:
    """ValueError unless ``max_range`` is None or positive."""
    if max_range is not None and not max_range > 0:
        raise ValueError(f"--max-range must be positive, got {max_range}")


def in_range(
    points: Float[np.ndarray, "n 3"], cameras: Float[np.ndarray, "c 3"], max_range: Optional[float]
) -> Bool[np.ndarray, " n"]:
    """Which points lie within ``max_range`` of a camera (all of them when ``max_range`` is None)."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    check_range(max_range)
    if max_range is None:
        return np.ones(len(points), bool)
    return camera_distance(points, cameras) <= max_range


def fruit_in_range(
    fruit: Sequence[Fruit], cameras: Float[np.ndarray, "c 3"], max_range: Optional[float]
) -> List[Fruit]:
    """The counted fruit (dataset frame) within ``max_range`` of a camera (dataset frame)."""
    if max_range is None or not fruit:
        return list(fruit)
    keep = in_range(np.stack([f.centre for f in fruit]), cameras, max_range)
    return [f for f, k in zip(fruit, keep, strict=True) if k]
