"""A detection's pixels to a 3D fruit centre and diameter with the rendered depth.

The pixels' surface points are ``origin + direction x depth`` (unit directions, depth along the ray: see
:mod:`agrinerf_ns.count.render`); pixels whose depth is far from the detection's median (background seen past the
fruit's rim) are dropped. A sphere of radius r seen from the front shows its cap: over the image disk, the median
depth of the cap lies ``r / sqrt(2)`` in front of the centre (depth offset sqrt(r^2 - rho^2) with rho^2 uniform
over [0, r^2]), so the centre lies on the mean ray of the pixels at their median depth plus ``r / sqrt(2)`` (all of
it independent of the frame's axes, unlike a per-axis median of the points). The radius is that of the disk of the
detection's area at the centre's distance.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np
from jaxtyping import Bool, Float

from agrinerf_ns.count.render import RenderedView, WorldFrame
from agrinerf_ns.robust import robust_spread

CAP_MEDIAN_OFFSET = 1.0 / np.sqrt(2.0)
"""Median depth of a sphere's visible cap in front of its centre, in radii."""
DEPTH_INLIER_MADS = 3.0
"""Pixels farther than this many robust spreads (and a radius) from the median depth are not the fruit's."""
OPAQUE = 0.9
"""Accumulated weight of a pixel on an opaque surface (:attr:`LiftedDetection.depth_confidence`)."""


@dataclass(frozen=True)
class LiftedDetection:
    """A detection in 3D, in the dataset's frame and units."""

    view: int
    """Index of the view in the render set."""
    centre: Float[np.ndarray, "3"]
    diameter: float
    score: float
    temperature: Optional[float]
    """Mean rendered temperature (degrees C) over the detection's pixels, where the run renders one."""
    origin: Optional[Float[np.ndarray, "3"]] = None
    """Where the view's camera was (dataset frame), for `ray`."""
    ray: Optional[Float[np.ndarray, "3"]] = None
    """The unit mean ray of all the detection's pixels (dataset frame): it passes through the fruit's centre whatever
    the rendered depth (`rays.triangulate`)."""
    depth_confidence: float = 0.0
    """The share of the detection's pixels on an opaque surface (accumulation at least ``OPAQUE``) within one fruit
    radius of the median depth: near 1 where the field holds a solid fruit-sized body there, low where the depth
    smears or the density is faint (:func:`depth_confidence`)."""


def lift_detection(
    view: RenderedView,
    mask: Bool[np.ndarray, "h w"],
    frame: WorldFrame,
    view_index: int = 0,
    score: float = 1.0,
    depth: Optional[Float[np.ndarray, "h w"]] = None,
) -> Optional[LiftedDetection]:
    """The fruit centre and diameter of the pixels ``mask`` of ``view`` (None when no pixel has a depth), lifted by
    ``depth`` (default: the view's rendered depth)."""
    depth = view.depth if depth is None else depth
    keep = mask & np.isfinite(depth) & (depth > 0)
    if not keep.any():
        return None
    d = depth[keep]
    median = float(np.median(d))
    rho = np.sqrt(mask.sum() / np.pi)  # pixels
    radius = rho * median / max(view.focal - CAP_MEDIAN_OFFSET * rho, 1e-6)  # Nerfstudio units
    spread = robust_spread(d, median)
    inlier = np.abs(d - median) <= DEPTH_INLIER_MADS * spread + radius
    keep[keep] = inlier
    ray = view.directions[keep].mean(0)
    ray = ray / max(float(np.linalg.norm(ray)), 1e-9)
    distance = float(np.median(depth[keep])) + CAP_MEDIAN_OFFSET * radius
    centre_ns = view.origins[keep].mean(0) + distance * ray
    temperature = None
    if view.temperature is not None:
        values = view.temperature[keep]
        values = values[np.isfinite(values)]
        temperature = float(values.mean()) if values.size else None
    confidence = depth_confidence(depth[mask], view.accumulation[mask], median, radius)
    origin, through = view.origins[mask].mean(0), view.directions[mask].mean(0)
    origin_ds, through_ds = frame.to_dataset(np.stack([origin, origin + through]))
    return LiftedDetection(
        view=view_index,
        centre=frame.to_dataset(centre_ns[None])[0],
        diameter=2.0 * radius / frame.scale,
        score=score,
        temperature=temperature,
        origin=origin_ds,
        ray=(through_ds - origin_ds) / max(float(np.linalg.norm(through_ds - origin_ds)), 1e-12),
        depth_confidence=confidence,
    )


def depth_confidence(
    depth: Float[np.ndarray, " n"], accumulation: Float[np.ndarray, " n"], median: float, radius: float
) -> float:
    """The share of pixels (a detection's depth and accumulation) on an opaque surface within ``radius`` of the
    ``median`` depth."""
    if depth.size == 0:
        return 0.0
    near = np.isfinite(depth) & (np.abs(depth - median) <= radius)
    return float(np.mean(near & (accumulation >= OPAQUE)))
