"""Thermal fruit decided in 3D, across the frames of a capture (``--mask-maker.thermal-rule bodies``).

One thermal frame cannot tell a fruit from warm ground, bark or a gap of cold sky: each is a blob a few degrees off
the leaves, on either side of their temperature (results/fruit-masks-dark). Across the capture, with the frames'
poses, they differ:

- **A fruit is a body at one place.** Each blob of a frame (:func:`~agrinerf_ns.fruit.thermal_blobs.thermal_blob_list`: both sides of the canopy's
  temperature) is placed along its thermal ray at the depth where blobs of the same side, of a consistent size, show
  in the most neighbouring frames (a plane sweep over the ray). A blob that no neighbour sees there is noise, a
  glint or a sky gap whose shape changes as the rig moves.
- **Fruit are not far off the leaves' temperature.** A blob whose median, or any pixel of whose disc, is more than
  ``max_offset_c`` from the canopy (on a radiometric capture) is the sky or a machine, not a fruit: a gap of night sky
  between the top leaves, blurred by the coarse thermal camera, has a median a few degrees under the leaves and
  sky-cold pixels at its centre (the dark demo's orchard counted such gaps at 11-13 C before this test,
  results/demo).
- **A fruit is compact.** Ground and sky seen between leaves, a stake or a stem, are parts of larger warm or cool
  structures: the region around such a blob at half its offset from the canopy spans many of its discs
  (:attr:`~agrinerf_ns.fruit.thermal_blobs.Blob.region_ratio`), a fruit's about one.
- **The scene's fruit sit on one side of the leaves' temperature.** Of the blobs left, the side with the more
  sightings is the fruit's (:func:`decide_polarity`), so the polarity is read from the capture, not set by the user:
  a fruit is seen again frame after frame, the compact parts of stakes and ground between leaves in fewer frames
  (on the cool-fruit dark garden of tuning seed 0 as many warm bodies as fruit were placed, with half the
  sightings; results/fruit-masks-dark).

Depths are searched in steps of the camera spacing (``depth_range`` in camera steps), so the rule needs no metric
scale and works on SfM poses as on odometry. (A ground plane fitted to the bodies' heights was tried first: with the
cameras pitched down, as a rig looking at low plants is, their mean up direction is not the world's, and the plane
cut the lowest fruit; results/fruit-masks-dark.)
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, List, Literal, Optional, Sequence, Tuple

import numpy as np
from jaxtyping import Bool, Float

from agrinerf_ns.fruit.thermal_blobs import Blob, blob_discs
from agrinerf_ns.rays import nearest_point

Side = Literal["warm", "cool"]


@dataclass(frozen=True)
class BodySettings:
    """How blobs are placed and judged in 3D."""

    neighbours: int = 4
    """Frames either side of a blob's frame searched for it."""
    min_views: int = 2
    """A blob is a body when it shows at one place in this many frames, its own included (two masked the dark tuning
    gardens better than three: results/fruit-masks-dark)."""
    depth_range: Tuple[float, float] = (4.0, 150.0)
    """Depths searched along a blob's ray, in steps of the median camera spacing (a 7.5 cm step: 0.3-11 m)."""
    depths: int = 96
    """Depths searched (log-spaced)."""
    match_px: float = 2.0
    """A neighbour's blob supports a depth when its centre lies within this many pixels, or 0.5 sigma, of the
    blob's projection there."""
    size_ratio: float = 1.6
    """... and its size at its depth is within this factor of the blob's."""
    max_region_ratio: float = 2.5
    """A blob whose region (:attr:`Blob.region_ratio`) spans more than this many discs is part of a larger structure
    (a stake, a stem, ground or sky between leaves), not a fruit."""
    max_offset_c: float = 8.0
    """Radiometric frames: a blob whose median or most extreme pixel lies more than this many degrees C off the canopy
    is not a fruit (night sky, engines; fruit stay within a few degrees of the leaves)."""
    polarity_margin: float = 1.5
    """One side is the fruit's when it holds this many times the other side's sightings; else both are kept."""


@dataclass(frozen=True)
class FrameGeometry:
    """Where a warped thermal frame's pixels look: the thermal camera's centre and the RGB camera's orientation and
    intrinsics (the frame is warped into the RGB plane at ``plane_depth``)."""

    K: Float[np.ndarray, "3 3"]
    rgb_c2w: Float[np.ndarray, "4 4"]
    """RGB camera to world (OpenCV axes) at the thermal frame's time."""
    thermal_centre: Float[np.ndarray, "3"]
    """The thermal camera's centre in the RGB camera's frame."""
    plane_depth: float = float("inf")

    def rays(self, rows: np.ndarray, cols: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """World origins and unit directions of the thermal rays through warped pixels (rows, cols)."""
        pixels = np.stack([cols, rows, np.ones_like(cols)], -1).astype(np.float64)
        on_plane = pixels @ np.linalg.inv(self.K).T  # RGB camera frame, z = 1
        if np.isfinite(self.plane_depth):
            direction = on_plane * self.plane_depth - self.thermal_centre
        else:
            direction = on_plane
        rot, centre = self.rgb_c2w[:3, :3], self.rgb_c2w[:3, 3]
        world = direction @ rot.T
        world /= np.linalg.norm(world, axis=-1, keepdims=True)
        origin = np.broadcast_to(centre + rot @ self.thermal_centre, world.shape)
        return origin, world

    def project(self, points: Float[np.ndarray, "n 3"]) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Warped pixels (rows, cols) where the thermal camera sees world ``points``, and their distance from it
        (NaN rows behind it)."""
        rot, centre = self.rgb_c2w[:3, :3], self.rgb_c2w[:3, 3]
        x = (points - centre) @ rot  # RGB camera frame
        c = self.thermal_centre
        d = x - c
        if np.isfinite(self.plane_depth):
            with np.errstate(divide="ignore", invalid="ignore"):
                s = (self.plane_depth - c[2]) / d[:, 2]
            on_plane = c + s[:, None] * d
        else:
            on_plane = d
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = on_plane @ self.K.T
            cols, rows = uv[:, 0] / uv[:, 2], uv[:, 1] / uv[:, 2]
        behind = d[:, 2] <= 1e-9
        rows[behind], cols[behind] = np.nan, np.nan
        return rows, cols, np.linalg.norm(d, axis=-1)


def place_blobs(
    blobs: Sequence[Blob], geometry: Sequence[FrameGeometry], settings: BodySettings
) -> Float[np.ndarray, "n 3"]:
    """Each blob at the depth along its ray where blobs of its side and size show in the most neighbouring frames
    (see the module), placed where the rays of those blobs meet; NaN rows where fewer than ``min_views`` frames
    show it."""
    return sweep_blobs(blobs, geometry, settings)[0]


def sweep_blobs(
    blobs: Sequence[Blob], geometry: Sequence[FrameGeometry], settings: BodySettings
) -> Tuple[Float[np.ndarray, "n 3"], List[Tuple[int, int]]]:
    """:func:`place_blobs`, with the pairs (blob, a neighbouring frame's blob that placed it)."""
    n = len(blobs)
    points = np.full((n, 3), np.nan)
    links: List[Tuple[int, int]] = []
    by_frame: Dict[int, List[int]] = {}
    for k, b in enumerate(blobs):
        by_frame.setdefault(b.frame, []).append(k)
    arrays = {
        f: (np.array([blobs[k].row for k in ks]), np.array([blobs[k].col for k in ks]),
            np.array([blobs[k].sigma for k in ks]), np.array([blobs[k].sign for k in ks]))
        for f, ks in by_frame.items()
    }  # fmt: skip
    step = camera_step(geometry)
    depths = step * np.geomspace(*settings.depth_range, settings.depths)
    for k, b in enumerate(blobs):
        origin, direction = geometry[b.frame].rays(np.array([b.row]), np.array([b.col]))
        along = origin[0] + depths[:, None] * direction[0]  # depths x 3
        size = b.sigma * depths  # the blob's extent at each depth (pixel sigma x distance, up to the focal length)
        support = np.ones(len(depths), np.int64)
        matched: List[Tuple[int, np.ndarray]] = []  # per neighbour frame: its matched blob (index or -1) per depth
        for f in range(b.frame - settings.neighbours, b.frame + settings.neighbours + 1):
            if f == b.frame or f not in arrays:
                continue
            rows, cols, dist = geometry[f].project(along)
            r, c, s, sign = arrays[f]
            gap = np.hypot(rows[:, None] - r[None], cols[:, None] - c[None])  # depths x blobs
            ratio = (s[None] * dist[:, None]) / np.maximum(size[:, None], 1e-12)
            ok = (gap <= np.maximum(settings.match_px, 0.5 * s[None])) & (sign[None] == b.sign)
            ok &= (ratio <= settings.size_ratio) & (ratio >= 1.0 / settings.size_ratio)
            gap = np.where(ok, gap, np.inf)
            match = np.where(ok.any(axis=1), np.argmin(gap, axis=1), -1)
            support += match >= 0
            matched.append((f, match))
        best = int(np.argmax(support))
        if support[best] >= settings.min_views:
            origins, directions = [origin[0]], [direction[0]]
            for f, match in matched:
                if match[best] >= 0:
                    j = by_frame[f][int(match[best])]
                    links.append((k, j))
                    o, d = geometry[f].rays(np.array([blobs[j].row]), np.array([blobs[j].col]))
                    origins.append(o[0])
                    directions.append(d[0])
            points[k] = nearest_point(np.stack(origins), np.stack(directions))
    return points, links


def camera_step(geometry: Sequence[FrameGeometry]) -> float:
    """The median distance between consecutive cameras (the unit of depth; 1 for a single frame)."""
    centres = np.stack([g.rgb_c2w[:3, 3] for g in geometry])
    steps = np.linalg.norm(np.diff(centres, axis=0), axis=1)
    steps = steps[steps > 0]
    return float(np.median(steps)) if steps.size else 1.0


def decide_polarity(signs: Float[np.ndarray, " n"], margin: float) -> Tuple[Optional[Side], Dict[str, int]]:
    """The fruit's side from the placed blobs' ``signs`` (+1 warm, -1 cool): the side with ``margin`` times the
    other's sightings, else None (both kept); with the sightings per side."""
    counts = {"warm": int(np.sum(signs > 0)), "cool": int(np.sum(signs < 0))}
    if counts["warm"] >= margin * max(counts["cool"], 1) and counts["warm"] > 0:
        return "warm", counts
    if counts["cool"] >= margin * max(counts["warm"], 1) and counts["cool"] > 0:
        return "cool", counts
    return None, counts


@dataclass
class BodyDecision:
    """Which blobs are fruit, and why the others are not (for the dataset's record)."""

    fruit: Bool[np.ndarray, " n"]
    placed: Bool[np.ndarray, " n"]
    """Blobs seen at one place in ``min_views`` frames."""
    polarity: Optional[Side]
    sightings: Dict[str, int]
    """Placed, kept blobs per side (what decided the polarity)."""
    dropped: Dict[str, int]
    points: Float[np.ndarray, "n 3"] = field(default_factory=lambda: np.zeros((0, 3)))
    """Where each placed blob lies (world frame of the geometry; NaN rows unplaced)."""


def decide_bodies(
    blobs: Sequence[Blob], geometry: Sequence[FrameGeometry], settings: BodySettings, radiometric: bool
) -> BodyDecision:
    """Which ``blobs`` are fruit (see the module)."""
    n = len(blobs)
    if n == 0:
        return BodyDecision(np.zeros(0, bool), np.zeros(0, bool), None, {"warm": 0, "cool": 0}, {}, np.zeros((0, 3)))
    points = place_blobs(blobs, geometry, settings)
    signs = np.array([b.sign for b in blobs])
    offsets = np.array([b.offset for b in blobs])
    body = np.isfinite(points[:, 0])
    extremes = np.array([b.extreme for b in blobs])
    plausible = (
        np.maximum(np.abs(offsets), np.abs(extremes)) <= settings.max_offset_c if radiometric else np.ones(n, bool)
    )
    compact = np.array([0.0 < b.region_ratio <= settings.max_region_ratio for b in blobs])
    candidate = body & plausible & compact
    polarity, sightings = decide_polarity(signs[candidate], settings.polarity_margin)
    side = np.ones(n, bool) if polarity is None else signs == (1.0 if polarity == "warm" else -1.0)
    dropped = {
        "not placed": int((~body).sum()),
        "too far off the canopy": int((body & ~plausible).sum()),
        "not compact": int((body & plausible & ~compact).sum()),
        "other side": int((candidate & ~side).sum()),
    }
    return BodyDecision(candidate & side, body, polarity, sightings, dropped, points)


@dataclass(frozen=True)
class Sighting:
    """One frame's sighting of a thermal fruit body, placed in 3D (the geometry's world frame)."""

    frame: int
    """The frame's index in the sequence the bodies were decided on."""
    centre: Float[np.ndarray, "3"]
    diameter: float
    """The blob's disc (radius sqrt(2) sigma) at its distance from the thermal camera, in world units."""
    temperature: Optional[float]
    """The median over the blob's disc (degrees C) on a radiometric capture."""
    origin: Float[np.ndarray, "3"]
    """The thermal camera's centre at the frame's time."""
    ray: Float[np.ndarray, "3"]
    """The unit ray from ``origin`` through the blob's centre."""


def fruit_sightings(
    blobs: Sequence[Blob],
    decision: BodyDecision,
    geometry: Sequence[FrameGeometry],
    celsius: Optional[Sequence[Float[np.ndarray, "h w"]]] = None,
) -> List[Sighting]:
    """The blobs decided fruit, each where it was placed; with the median temperature of its disc where ``celsius``
    (per frame) is given."""
    return [
        placed_sighting(blobs[k], decision.points[k], geometry, None if celsius is None else celsius[blobs[k].frame])
        for k in np.flatnonzero(decision.fruit)
    ]


def disc_diameter(blob: Blob, view: FrameGeometry, distance: float) -> float:
    """The width (world units) of ``blob``'s disc (radius sqrt(2) sigma pixels) at ``distance`` from ``view``."""
    return 2.0 * np.sqrt(2.0) * blob.sigma * distance / float(view.K[0, 0])


def placed_sighting(
    blob: Blob,
    centre: Float[np.ndarray, "3"],
    geometry: Sequence[FrameGeometry],
    celsius: Optional[Float[np.ndarray, "h w"]] = None,
) -> Sighting:
    """``blob`` placed at ``centre``: its ray, its disc's diameter at that distance, and the median temperature of
    its disc in its frame's radiometric image ``celsius`` where given."""
    view = geometry[blob.frame]
    origin, ray = (a[0] for a in view.rays(np.array([blob.row]), np.array([blob.col])))
    diameter = disc_diameter(blob, view, float(np.linalg.norm(centre - origin)))
    temperature = None
    if celsius is not None:
        values = celsius[blob_discs(celsius.shape, np.isfinite(celsius), [blob])]
        temperature = float(np.median(values)) if values.size else None
    return Sighting(blob.frame, np.asarray(centre, np.float64), float(diameter), temperature, origin, ray)
