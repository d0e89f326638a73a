"""How many views could have seen a fruit: its centre projected into every rendered view, not occluded there.

A fruit seen in 3 of 4 views that show its place is better supported than one seen in 3 of 25: a blob that comes
from one viewpoint's accident (an edge, noise, a patch of soil in one light) is detected in few of the views that
see the same spot. ``--min-view-fraction`` keeps a fruit when the views that detected it are at least that fraction
of the views that show its centre.
"""

from __future__ import annotations

from typing import List, Sequence

import numpy as np
from jaxtyping import Float, Int

from agrinerf_ns.count.cluster import Fruit
from agrinerf_ns.count.render import RenderedView, WorldFrame

OCCLUSION_RADII = 2.0
"""A view shows a fruit's centre when its rendered depth there is no less than the centre's distance less this many
radii (the fruit's own front surface lies one radius in front of it)."""


def views_showing(
    centres: Float[np.ndarray, "n 3"],
    diameters: Float[np.ndarray, " n"],
    views: Sequence[RenderedView],
    frame: WorldFrame,
) -> Int[np.ndarray, " n"]:
    """Per fruit (centres and diameters in the dataset's frame and units), the number of ``views`` whose image holds
    its centre (within half a pixel's angle of a pixel's ray) unoccluded by the rendered depth."""
    centres_ns = frame.to_ns(np.asarray(centres, np.float64).reshape(-1, 3))
    radii_ns = 0.5 * np.asarray(diameters, np.float64).reshape(-1) * frame.scale
    counts = np.zeros(len(centres_ns), np.int64)
    if len(centres_ns) == 0:
        return counts
    for view in views:
        origin = view.origins.reshape(-1, 3).mean(0).astype(np.float64)
        rays = view.directions.reshape(-1, 3).astype(np.float64)
        depth = view.depth.reshape(-1)
        offset = centres_ns - origin
        distance = np.linalg.norm(offset, axis=1)
        cosines = rays @ (offset / np.maximum(distance, 1e-12)[:, None]).T
        pixel = cosines.argmax(0)
        inside = cosines[pixel, np.arange(len(pixel))] >= np.cos(0.5 * np.sqrt(2.0) / view.focal)
        d = depth[pixel]
        counts += inside & np.isfinite(d) & (d >= distance - OCCLUSION_RADII * radii_ns)
    return counts


def keep_supported(
    fruit: Sequence[Fruit], views: Sequence[RenderedView], frame: WorldFrame, min_fraction: float
) -> List[Fruit]:
    """The fruit detected in at least ``min_fraction`` of the views that show them (all of them when 0)."""
    if min_fraction <= 0 or not fruit:
        return list(fruit)
    shown = views_showing(np.stack([f.centre for f in fruit]), np.array([f.diameter for f in fruit]), views, frame)
    return [f for f, n in zip(fruit, shown, strict=True) if f.views >= min_fraction * max(int(n), f.views)]
