"""Where rays meet: the point nearest to a set of rays, and a fruit's centre from the rays of its detections, shared by
the data stage's bodies (thermal and the lit masks') and the counter's ``--triangulate``.

A detection's centroid ray (the mean ray of its pixels) passes through the fruit's centre whatever the rendered depth
says, so the rays of one fruit seen from several places along the row meet there. Lifting with the rendered depth
puts each detection where the field's surface is, and a trained field's surfaces at the fruit scatter by more than a
fruit (garden-bright, `agrinerf-lite`: F1 0.13 at 0.05 m, 0.30 at 0.10 m, with about the right number counted). The
depth still groups the detections (`count/cluster.py`); the rays then place each group (:func:`triangulate`), as a
least-squares point closest to the rays that pass within a fruit's radius of it, found from the crossings of every
two rays (a consensus, as RANSAC's, so another fruit's detections that a wrong depth grouped with these do not pull
it).
"""

from __future__ import annotations

from typing import Optional, Sequence, Tuple

import numpy as np
from jaxtyping import Bool, Float


def nearest_point(origins: Float[np.ndarray, "n 3"], rays: Float[np.ndarray, "n 3"]) -> Float[np.ndarray, "3"]:
    """The point nearest (least squares) to every line ``origin + t ray`` (unit ``rays``): the sum of the projectors
    onto each ray's normal plane, solved by least squares, so that parallel rays give a point rather than an error."""
    origins, rays = np.asarray(origins, np.float64), np.asarray(rays, np.float64)
    projectors = np.eye(3)[None] - rays[:, :, None] * rays[:, None, :]  # [n, 3, 3]
    return np.linalg.lstsq(projectors.sum(0), np.einsum("mij,mj->i", projectors, origins), rcond=None)[0]


MIN_RAY_ANGLE_DEG = 2.0
"""Rays closer in direction than this (all pairs) meet too far from their true crossing to place a fruit: a group
seen from one place keeps its depth-lifted centre."""
MAX_PAIRS = 2000
"""Crossings tried per group at most (every pair below that): the search costs pairs x rays."""


def closest_point(
    origins: Float[np.ndarray, "n 3"], rays: Float[np.ndarray, "n 3"]
) -> Optional[Float[np.ndarray, "3"]]:
    """The point nearest (least squares) to every line ``origin + t ray`` (unit rays); None where the rays are
    within `MIN_RAY_ANGLE_DEG` of one direction or the point lies behind one of the origins."""
    origins, rays = np.asarray(origins, np.float64), np.asarray(rays, np.float64)
    if len(rays) < 2:
        return None
    cosines = np.clip(rays @ rays.T, -1.0, 1.0)
    if float(np.degrees(np.arccos(cosines.min()))) < MIN_RAY_ANGLE_DEG:
        return None
    point = nearest_point(origins, rays)
    if bool((((point - origins) * rays).sum(-1) <= 0).any()):
        return None
    return point


def miss_distances(
    point: Float[np.ndarray, "3"], origins: Float[np.ndarray, "n 3"], rays: Float[np.ndarray, "n 3"]
) -> Float[np.ndarray, " n"]:
    """How far each line ``origin + t ray`` passes from ``point``."""
    offsets = np.asarray(point)[None] - np.asarray(origins)
    along = (offsets * rays).sum(-1, keepdims=True)
    return np.linalg.norm(offsets - along * rays, axis=-1)


def triangulate(
    origins: Float[np.ndarray, "n 3"],
    rays: Float[np.ndarray, "n 3"],
    views: Sequence[int],
    radius: float,
    min_views: int,
) -> Tuple[Optional[Float[np.ndarray, "3"]], Bool[np.ndarray, " n"]]:
    """The centre of one fruit among detections (their centroid rays, the views they were found in) and which of
    them it keeps: of the points where two rays from different views meet, the one that the rays of the most views
    pass within ``radius`` of, refined on those rays (least squares) and the rays within ``radius`` of it kept.
    None where no point gathers ``min_views`` views (rays too parallel, or too few views)."""
    origins, rays = np.asarray(origins, np.float64), np.asarray(rays, np.float64)
    view_of = np.asarray(views)
    best: Tuple[int, float] = (0, 0.0)
    keep = np.zeros(len(rays), dtype=bool)
    pairs = [(i, j) for i in range(len(rays)) for j in range(i + 1, len(rays)) if view_of[i] != view_of[j]]
    if len(pairs) > MAX_PAIRS:  # a large group (a dense canopy seen from many frames): a fixed sample of its pairs
        pick = np.random.default_rng(len(pairs)).choice(len(pairs), MAX_PAIRS, replace=False)
        pairs = [pairs[k] for k in sorted(pick)]
    for i, j in pairs:
        point = closest_point(origins[[i, j]], rays[[i, j]])
        if point is None:
            continue
        miss = miss_distances(point, origins, rays)
        inside = miss <= radius
        rank = (len(set(view_of[inside].tolist())), -float(miss[inside].sum()))
        if rank > best:
            best, keep = rank, inside
    if best[0] < min_views:
        return None, keep
    point = closest_point(origins[keep], rays[keep])
    if point is None:
        return None, keep
    keep = miss_distances(point, origins, rays) <= radius
    if len(set(view_of[keep].tolist())) < min_views:
        return None, keep
    return point, keep


def enclosing_ball(
    origins: Float[np.ndarray, "n 3"], rays: Float[np.ndarray, "n 3"], start: Float[np.ndarray, "3"]
) -> Tuple[Optional[Float[np.ndarray, "3"]], float]:
    """The centre and radius of the smallest ball that every line ``origin + t ray`` (unit rays) passes through,
    searched from ``start`` (SLSQP on the convex problem: the largest of the lines' miss distances, least); None
    where the search fails.

    The rays through a fruit's outline in several frames all pass through the fruit, and a leaf or trunk in front
    only removes some of them, so this ball stays on the fruit where the centre of each frame's visible part, pulled
    towards the occluder's edge, does not (:func:`agrinerf_ns.fruit.mask_bodies.outline_points`)."""
    from scipy.optimize import minimize

    origins, rays = np.asarray(origins, np.float64), np.asarray(rays, np.float64)
    start = np.asarray(start, np.float64)
    if len(rays) < 2 or not np.isfinite(start).all():
        return None, float("nan")
    x0 = np.append(start, miss_distances(start, origins, rays).max())
    result = minimize(
        lambda x: x[3],
        x0,
        jac=lambda x: np.array([0.0, 0.0, 0.0, 1.0]),
        method="SLSQP",
        constraints=[{"type": "ineq", "fun": lambda x: x[3] - miss_distances(x[:3], origins, rays)}],
        options={"maxiter": 200},
    )
    centre = result.x[:3]
    radius = float(miss_distances(centre, origins, rays).max()) if np.isfinite(centre).all() else float("nan")
    if not radius <= x0[3]:  # the search failed or went astray: no ball smaller than the start's
        return None, float("nan")
    return centre, radius
