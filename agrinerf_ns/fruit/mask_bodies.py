"""Fruit of the lit RGB frames' masks placed in 3D across the capture, without a trained field.

In light the RGB fruit masks are right (the colour rule's pixel IoU 0.94-0.98 on tuning seeds, results/fruit-masks);
what a count needs from a field is only where each masked fruit lies. The poses already say that: a fruit of one
frame shows again at one place in its neighbours, which the thermal bodies' plane sweep
(:func:`agrinerf_ns.fruit.thermal_bodies.place_blobs`) finds along the fruit's ray, so the same sweep places the
masks' fruit from the RGB camera. Each region of a mask is split into discs at the peaks of its distance to the
background (:func:`mask_blobs`: fruit that touch in the image are two discs, as a watershed would cut them), a disc
is a :class:`~agrinerf_ns.fruit.thermal_blobs.Blob` of the RGB frame, the discs the sweep matched are one fruit's
track, placed where the rays of all its frames meet (:func:`track_points`) and then at the centre of the smallest ball
that the rays through all its discs' outlines pass through (:func:`outline_points`: a leaf or trunk in front cuts a
fruit's visible part, whose centre then follows the occluder), and its temperature is read where the thermal camera
sees the placed point (:func:`disc_temperature`). No field is trained: a capture is counted in seconds
(``agrinerf-count --path bodies``; measured beside trained runs in results/fruit-count-lit).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np
from jaxtyping import Bool, Float
from scipy import ndimage

from agrinerf_ns.fruit.thermal_blobs import Blob
from agrinerf_ns.fruit.thermal_bodies import (
    BodySettings,
    FrameGeometry,
    Sighting,
    disc_diameter,
    placed_sighting,
    sweep_blobs,
)
from agrinerf_ns.rays import enclosing_ball, triangulate

MIN_DISC_RADIUS_PX = 2.0
"""The least radius of a mask's disc (pixels): a thinner region is a sliver of a hidden fruit or the colour rule's
noise, not a fruit one can place (the colour rule leaves regions under 8 pixels unknown)."""
CLOSING = ndimage.generate_binary_structure(2, 1)
CLOSING_STEPS = 2
"""A mask's fruit are closed (this many steps of the 4-neighbour cross) and their holes filled before they are cut
into discs: the colour rule leaves specular highlights and dim pixels of a fruit out, a speckle that would cut one
fruit into many small discs."""
MIN_DISC_GAP = 1.0
"""A peak of a region's distance map starts another disc when it lies farther than this many radii of a disc already
taken from every such disc's centre: two touching fruit are two discs, one fruit's flat ridge one."""


MAX_OUTLINE_MOVE = 3.0
"""A track's outline ball moves its place by at most this many fruit diameters; farther, its outlines gather more
than one fruit and the rays' meeting point stays (chosen on the bright tuning captures among 3, 6 and 10:
results/fruit-count-lit/README.md)."""


def filled(fruit: Bool[np.ndarray, "h w"]) -> Bool[np.ndarray, "h w"]:
    """A mask's fruit closed (:data:`CLOSING_STEPS`) and their holes filled: the regions cut into discs."""
    return ndimage.binary_fill_holes(ndimage.binary_closing(fruit, CLOSING, iterations=CLOSING_STEPS))


def mask_blobs(fruit: Bool[np.ndarray, "h w"], frame: int) -> List[Blob]:
    """The discs of a frame's fruit mask (see the module), each a :class:`Blob` (sigma: the disc's radius over sqrt(2),
    as for a Laplacian blob) of sign +1; the largest discs first."""
    fruit = filled(fruit)
    distance = ndimage.distance_transform_edt(fruit)
    peaks = (distance >= MIN_DISC_RADIUS_PX) & (distance == ndimage.maximum_filter(distance, size=3))
    rows, cols = np.nonzero(peaks)
    order = np.argsort(-distance[rows, cols], kind="stable")
    taken: List[Blob] = []
    for r, c in zip(rows[order], cols[order], strict=True):
        radius = float(distance[r, c])
        if any(np.hypot(r - b.row, c - b.col) <= MIN_DISC_GAP * np.sqrt(2.0) * b.sigma for b in taken):
            continue
        taken.append(Blob(frame, float(r), float(c), radius / np.sqrt(2.0), 1.0, 0.0))
    return taken


def rgb_geometry(K: Float[np.ndarray, "3 3"], c2w: Float[np.ndarray, "4 4"]) -> FrameGeometry:
    """The RGB camera's own view (OpenCV axes): a frame is not warped, so its rays leave the camera's centre."""
    return FrameGeometry(np.asarray(K, np.float64), np.asarray(c2w, np.float64), np.zeros(3), float("inf"))


def tracks(count: int, links: Sequence[Tuple[int, int]]) -> List[List[int]]:
    """The groups of ``count`` items that ``links`` join, directly or through others (union-find)."""
    parent = list(range(count))

    def root(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    for a, b in links:
        parent[root(a)] = root(b)
    groups: Dict[int, List[int]] = {}
    for a in range(count):
        groups.setdefault(root(a), []).append(a)
    return list(groups.values())


def track_points(
    blobs: Sequence[Blob],
    views: Sequence[FrameGeometry],
    points: Float[np.ndarray, "n 3"],
    links: Sequence[Tuple[int, int]],
) -> Float[np.ndarray, "n 3"]:
    """The placed blobs joined into tracks by the sweep's matches, each track placed again where the rays of all its
    frames meet (:func:`~agrinerf_ns.rays.triangulate`: the consensus of the rays within a fruit's radius), the blobs
    of that consensus moved there. A blob is placed by the frames next to its own, whose short baseline leaves its
    depth uncertain by several centimetres at a tree row's distance; a track spans every frame that matched the
    fruit, and its one place keeps one fruit from splitting into several along the rays (on the bright tuning
    captures the count's error fell from +25/+15/+33/+153% to 0/0/-17/+50%; results/fruit-count-lit)."""
    out = np.array(points, np.float64)
    placed = np.isfinite(out[:, 0])
    for track in tracks(len(blobs), [(a, b) for a, b in links if placed[a] and placed[b]]):
        if len(track) < 2:
            continue
        origins, rays = blob_rays([blobs[k] for k in track], views)
        distance = float(np.median(np.linalg.norm(out[track] - origins, axis=1)))
        pixels = float(np.median([np.sqrt(2.0) * blobs[k].sigma for k in track]))
        radius = max(pixels * distance / float(views[blobs[track[0]].frame].K[0, 0]), 1e-6)
        point, keep = triangulate(origins, rays, [blobs[k].frame for k in track], radius, 2)
        if point is not None:
            out[np.asarray(track)[keep]] = point
    return out


def disc_outlines(fruit: Bool[np.ndarray, "h w"], blobs: Sequence[Blob]) -> List[Float[np.ndarray, "m 2"]]:
    """Per disc of one frame (``blobs``, from :func:`mask_blobs` of ``fruit``): the (row, col) pixels of its region's
    outline that lie nearer its centre than any other disc's (touching fruit share a region's outline)."""
    import cv2

    region = filled(fruit)
    labels = ndimage.label(region)[0]
    contours, _ = cv2.findContours(region.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    edge = np.concatenate([c[:, 0, ::-1] for c in contours]) if contours else np.zeros((0, 2), np.int64)
    if not blobs or not len(edge):
        return [np.zeros((0, 2)) for _ in blobs]
    centres = np.array([[b.row, b.col] for b in blobs])
    nearest = np.argmin(np.linalg.norm(edge[:, None, :] - centres[None], axis=-1), axis=1)
    height, width = region.shape
    out = []
    for k, b in enumerate(blobs):
        own = labels[min(max(int(round(b.row)), 0), height - 1), min(max(int(round(b.col)), 0), width - 1)]
        pick = (nearest == k) & (labels[edge[:, 0], edge[:, 1]] == own) & (own > 0)
        out.append(edge[pick].astype(np.float64))
    return out


def outline_points(
    blobs: Sequence[Blob],
    views: Sequence[FrameGeometry],
    masks: Sequence[Bool[np.ndarray, "h w"]],
    points: Float[np.ndarray, "n 3"],
    links: Sequence[Tuple[int, int]],
) -> Float[np.ndarray, "n 3"]:
    """Each track of placed blobs (:func:`track_points`) moved to the centre of the smallest ball that the rays
    through all its discs' outlines pass through (:func:`~agrinerf_ns.rays.enclosing_ball`), where that lies within
    :data:`MAX_OUTLINE_MOVE` fruit diameters of its place. The centre of a fruit's visible part follows a leaf or
    trunk in front of it from frame to frame, and the rays through those centres meet between the two; the rays
    through its outline all pass through the fruit, and a ball just large enough to meet them all stays on it."""
    out = np.array(points, np.float64)
    placed = np.isfinite(out[:, 0])
    by_frame: Dict[int, List[int]] = {}
    for k, b in enumerate(blobs):
        by_frame.setdefault(b.frame, []).append(k)
    outline: Dict[int, np.ndarray] = {}
    for frame, ks in by_frame.items():
        for k, edge in zip(ks, disc_outlines(masks[frame], [blobs[k] for k in ks]), strict=True):
            outline[k] = edge
    for track in tracks(len(blobs), [(a, b) for a, b in links if placed[a] and placed[b]]):
        if len(track) < 2:
            continue
        pairs = [views[blobs[k].frame].rays(outline[k][:, 0], outline[k][:, 1]) for k in track if len(outline[k])]
        if len(pairs) < 2:
            continue
        start = out[track[0]]
        centre, _ = enclosing_ball(np.concatenate([o for o, _ in pairs]), np.concatenate([r for _, r in pairs]), start)
        if centre is None:
            continue
        origins, _ = blob_rays([blobs[k] for k in track], views)
        distances = np.linalg.norm(start - origins, axis=1)
        diameter = float(
            np.median(
                [disc_diameter(blobs[k], views[blobs[k].frame], d) for k, d in zip(track, distances, strict=True)]
            )
        )
        if np.linalg.norm(centre - start) <= MAX_OUTLINE_MOVE * diameter:
            out[track] = centre
    return out


def blob_rays(blobs: Sequence[Blob], views: Sequence[FrameGeometry]) -> Tuple[np.ndarray, np.ndarray]:
    """The origins and unit rays (world) of ``blobs``' centres, each from its own frame's view."""
    pairs = [views[b.frame].rays(np.array([b.row]), np.array([b.col])) for b in blobs]
    return np.concatenate([o for o, _ in pairs]), np.concatenate([r for _, r in pairs])


def disc_temperature(
    centre: Float[np.ndarray, "3"], diameter: float, thermal: FrameGeometry, celsius: Float[np.ndarray, "h w"]
) -> Optional[float]:
    """The median temperature (degrees C, NaN outside the thermal camera's view) over the disc where ``thermal`` sees
    a fruit of ``diameter`` at ``centre``; None where it sees none of it."""
    rows, cols, distance = thermal.project(np.asarray(centre, np.float64)[None])
    if not np.isfinite(rows[0]):
        return None
    radius = max(0.5 * diameter * float(thermal.K[0, 0]) / max(float(distance[0]), 1e-9), 1.0)
    grid_r, grid_c = np.ogrid[0 : celsius.shape[0], 0 : celsius.shape[1]]
    disc = (grid_r - rows[0]) ** 2 + (grid_c - cols[0]) ** 2 <= radius**2
    values = celsius[disc]
    values = values[np.isfinite(values)]
    return float(np.median(values)) if values.size else None


def mask_sightings(
    masks: Sequence[Bool[np.ndarray, "h w"]],
    views: Sequence[FrameGeometry],
    settings: BodySettings,
    thermal: Optional[Sequence[Optional[FrameGeometry]]] = None,
    celsius: Optional[Sequence[Optional[Float[np.ndarray, "h w"]]]] = None,
) -> List[Sighting]:
    """The fruit of consecutive frames' ``masks`` (fruit pixels) that show at one place in ``settings.min_views``
    frames, each placed where its matched rays meet (frames by their index in ``masks``); with its temperature where
    the frame's ``thermal`` view and radiometric frame ``celsius`` are given."""
    blobs = [b for k, mask in enumerate(masks) for b in mask_blobs(mask, k)]
    if not blobs:
        return []
    points, links = sweep_blobs(blobs, views, settings)
    points = outline_points(blobs, views, masks, track_points(blobs, views, points, links), links)
    placed = np.isfinite(points[:, 0])
    found = [placed_sighting(blobs[k], points[k], views) for k in np.flatnonzero(placed)]
    if thermal is None or celsius is None:
        return found
    out = []
    for s in found:
        view, image = thermal[s.frame], celsius[s.frame]
        warm = None if view is None or image is None else disc_temperature(s.centre, s.diameter, view, image)
        out.append(replace(s, temperature=warm))
    return out
