"""The default fruit detector of a rendered view: fruit-sized blobs of local contrast, found with OpenCV (no learnt
weights, no AGPL).

A view is reduced to one feature image, as its counting source's row makes it (:mod:`agrinerf_ns.count.source_table`):
a thermal output itself (fruit differ from the leaves around them in temperature, warmer or cooler) or, for ``rgb``, a
fruit-colour score (:func:`agrinerf_ns.fruit.colour_score.fruit_colour`). Local contrast (:func:`agrinerf_ns.fruit.contrast.contrast`) is
a difference of Gaussians in units of its robust spread over the view; connected components beyond ``threshold``
whose metric size, from the rendered depth, is that of a fruit are the detections.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import List, Optional

import cv2
import numpy as np
from jaxtyping import Bool, Float

from agrinerf_ns.fruit.contrast import Polarity, contrast
from agrinerf_ns.fruit.view import MIN_ACCUMULATION, View


@dataclass(frozen=True)
class Detection:
    """A fruit found in one view: its pixels and a confidence."""

    mask: Bool[np.ndarray, "h w"]
    score: float


@dataclass(frozen=True)
class BlobConfig:
    """Settings of the blob detector (lengths in the dataset's units, metres for a metric capture)."""

    threshold: float = 3.0
    """Local contrast, in robust standard deviations of the view's contrast, a fruit pixel exceeds."""
    polarity: Polarity = "both"
    """``thermal``: fruit warmer than their surroundings, cooler, or either (``rgb`` looks for fruit colour only)."""
    min_diameter: float = 0.03
    """Smallest fruit diameter kept (from the blob's area and its rendered depth)."""
    max_diameter: float = 0.16
    """Largest fruit diameter kept."""
    min_pixels: int = 3
    """Smallest blob kept, in pixels."""
    max_elongation: float = 2.5
    """Largest ratio of a blob's principal axes (fruit are round; a canopy edge's halo is a strip)."""
    background_sigma: float = 0.05
    """Scale of the surroundings a fruit is compared with, as a fraction of the image's shorter side."""
    min_surround_sides: int = 4
    """Of the four sides (quadrants around its centre) of a ring around a blob, how many must be lower in contrast
    than the blob's own pixels by half their median (an edge between two surfaces is lower on one side only;
    0: no test)."""
    fruit_probability: float = 0.5
    """``fruit``: a pixel whose rendered fruit probability reaches this is fruit (0.5: the head's BCE boundary)."""


def valid_pixels(view: View, feature: Float[np.ndarray, "h w"]) -> Bool[np.ndarray, "h w"]:
    """The pixels of ``view`` a detection may use: rendered surface (accumulation), a finite positive depth to lift
    it with, and a finite ``feature``."""
    return (view.accumulation >= MIN_ACCUMULATION) & np.isfinite(view.depth) & (view.depth > 0) & np.isfinite(feature)


def find_blobs(
    view: View,
    feature: Float[np.ndarray, "h w"],
    scale: float,
    config: BlobConfig = BlobConfig(),
    one_sided: bool = False,
) -> List[Detection]:
    """Fruit-sized blobs of ``feature`` (an image of ``view``, e.g. its temperature or fruit-colour score); ``scale``
    is the dataparser scale (Nerfstudio units per dataset unit), so that sizes are compared in the dataset's units;
    ``one_sided``: blobs above their surroundings only, whatever ``config.polarity`` says (a score, not a
    temperature)."""
    valid = valid_pixels(view, feature)
    z = contrast(feature, valid, config.background_sigma)
    signs = [1.0] if one_sided or config.polarity == "warm" else [-1.0] if config.polarity == "cool" else [1.0, -1.0]
    detections: List[Detection] = []
    for sign in signs:
        above = (sign * z > config.threshold) & valid
        count, labels, stats, _ = cv2.connectedComponentsWithStats(above.astype(np.uint8), connectivity=8)
        for label in range(1, count):
            if stats[label, cv2.CC_STAT_AREA] < config.min_pixels:
                continue
            mask = labels == label
            if elongation(mask) > config.max_elongation:
                continue
            if config.min_surround_sides and surround_sides(mask, sign * z, valid) < config.min_surround_sides:
                continue
            diameter = blob_diameter(mask, view, scale)
            if diameter is None or not config.min_diameter <= diameter <= config.max_diameter:
                continue
            detections.append(Detection(mask, float(np.max(sign * z[mask]))))
    return detections


def surround_sides(mask: Bool[np.ndarray, "h w"], z: Float[np.ndarray, "h w"], valid: Bool[np.ndarray, "h w"]) -> int:
    """Quadrants of the ring of valid pixels around ``mask`` (two pixels wide) whose median of ``z`` lies below half
    the blob's median: a compact object stands out on all four sides, an edge or a strip's end on fewer."""
    ys, xs = np.nonzero(mask)
    cy, cx = ys.mean(), xs.mean()
    grown = cv2.dilate(mask.astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))) > 0
    ring = grown & ~mask & valid
    level = 0.5 * float(np.median(z[mask]))
    ry, rx = np.nonzero(ring)
    sides = 0
    for quadrant in ((ry < cy) & (rx < cx), (ry < cy) & (rx >= cx), (ry >= cy) & (rx < cx), (ry >= cy) & (rx >= cx)):
        values = z[ry[quadrant], rx[quadrant]]
        if values.size and float(np.median(values)) < level:
            sides += 1
    return sides


def elongation(mask: Bool[np.ndarray, "h w"]) -> float:
    """Ratio of the principal axes of a blob's pixels (1 for a disk; a pixel's own extent keeps it finite)."""
    ys, xs = np.nonzero(mask)
    cov = np.cov(np.stack([xs, ys]).astype(np.float64)) if len(xs) > 1 else np.zeros((2, 2))
    low, high = np.linalg.eigvalsh(np.atleast_2d(cov) + np.eye(2) / 12.0)
    return float(np.sqrt(high / low))


def blob_diameter(mask: Bool[np.ndarray, "h w"], view: View, scale: float) -> Optional[float]:
    """A blob's diameter in dataset units: that of the disk of its area, at its median depth."""
    depths = view.depth[mask]
    depths = depths[np.isfinite(depths) & (depths > 0)]
    if depths.size == 0:
        return None
    pixels = 2.0 * np.sqrt(mask.sum() / np.pi)
    return float(pixels * np.median(depths) / view.focal / scale)
