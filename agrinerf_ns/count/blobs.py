"""The default fruit detector: fruit-sized blobs of local contrast, found with OpenCV (no learnt weights, no AGPL).

A view is reduced to one feature image: the cross-spectral ``thermal`` output itself (fruit differ from the leaves
around them in temperature, warmer or cooler) or, for ``rgb``, a fruit-colour score (saturation where the hue is red
to yellow, after stretching the view's brightness so that a dark render is not black). Local contrast is a
difference of Gaussians in units of its robust spread over the view; connected components beyond ``threshold`` whose
metric size, from the rendered depth, is that of a fruit are the detections.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import List, Literal, Optional

import cv2
import numpy as np
from jaxtyping import Bool, Float

from agrinerf_ns.count.render import RenderedView
from agrinerf_ns.robust import robust_spread

Polarity = Literal["both", "warm", "cool"]
MIN_ACCUMULATION = 0.5
"""Pixels whose accumulation is below this (sky, nothing rendered) are never fruit."""


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
    min_hue_deg: float = -20.0
    """``rgb``: fruit hues span ``min_hue_deg`` .. ``max_hue_deg`` (0 = red, 60 = yellow, 120 = green)."""
    max_hue_deg: float = 70.0


def feature_image(view: RenderedView, source: str) -> Float[np.ndarray, "h w"]:
    """The image a view's fruit stand out in: ``temperature`` (degrees C), ``thermal`` (cross-spectral output) or
    ``rgb`` (fruit-colour score)."""
    if source in ("temperature", "thermal"):
        return view.optional_output(source).astype(np.float32)
    if source != "rgb":
        raise ValueError(f"unknown detection source {source!r} (temperature, thermal or rgb)")
    return fruit_colour(view.optional_output("rgb"), view.accumulation >= MIN_ACCUMULATION)


def fruit_colour(
    rgb: Float[np.ndarray, "h w 3"], valid: Bool[np.ndarray, "h w"], config: BlobConfig = BlobConfig()
) -> Float[np.ndarray, "h w"]:
    """Saturation where the hue is a fruit's (red to yellow), after scaling the view so its 99th percentile of
    brightness over ``valid`` pixels is 1."""
    rgb = np.clip(np.nan_to_num(rgb.astype(np.float32)), 0.0, None)
    peak = float(np.percentile(rgb.max(-1)[valid], 99)) if valid.any() else 1.0
    rgb = np.clip(rgb / max(peak, 1e-6), 0.0, 1.0)
    hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)  # float input: H in degrees [0, 360), S and V in [0, 1]
    hue = np.where(hsv[..., 0] > 180.0, hsv[..., 0] - 360.0, hsv[..., 0])
    in_band = (hue >= config.min_hue_deg) & (hue <= config.max_hue_deg)
    return np.where(in_band, hsv[..., 1] * np.sqrt(hsv[..., 2]), 0.0).astype(np.float32)


def contrast(
    feature: Float[np.ndarray, "h w"], valid: Bool[np.ndarray, "h w"], background_sigma: float
) -> Float[np.ndarray, "h w"]:
    """Difference of Gaussians (about one pixel against ``background_sigma`` x the shorter side) over the valid
    pixels only (normalised convolution), divided by its robust spread (1.4826 MAD) over them."""
    weight = valid.astype(np.float32)
    values = np.where(valid, feature, 0.0).astype(np.float32)

    def blur(sigma: float) -> np.ndarray:
        num = cv2.GaussianBlur(values, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
        den = cv2.GaussianBlur(weight, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
        return num / np.maximum(den, 1e-6)

    sigma_bg = max(2.0, background_sigma * min(feature.shape))
    dog = blur(0.7) - blur(sigma_bg)
    dog[~valid] = 0.0
    if not valid.any():
        return dog
    spread = robust_spread(dog[valid])
    return dog / max(spread, 1e-6)


def valid_pixels(view: RenderedView, feature: Float[np.ndarray, "h w"]) -> Bool[np.ndarray, "h w"]:
    """The pixels of ``view`` a detection may use: rendered surface (accumulation), a finite positive depth to lift
    it with, and a finite ``feature``."""
    return (view.accumulation >= MIN_ACCUMULATION) & np.isfinite(view.depth) & (view.depth > 0) & np.isfinite(feature)


def detect_blobs(view: RenderedView, source: str, scale: float, config: BlobConfig = BlobConfig()) -> List[Detection]:
    """Fruit-sized blobs of ``source`` in ``view``; ``scale`` is the dataparser scale (Nerfstudio units per dataset
    unit), so that sizes are compared in the dataset's units."""
    feature = feature_image(view, source)
    valid = valid_pixels(view, feature)
    z = contrast(feature, valid, config.background_sigma)
    signs = (
        [1.0] if source == "rgb" or config.polarity == "warm" else [-1.0] if config.polarity == "cool" else [1.0, -1.0]
    )
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


def blob_diameter(mask: Bool[np.ndarray, "h w"], view: RenderedView, scale: float) -> Optional[float]:
    """A blob's diameter in dataset units: that of the disk of its area, at its median depth."""
    depths = view.depth[mask]
    depths = depths[np.isfinite(depths) & (depths > 0)]
    if depths.size == 0:
        return None
    pixels = 2.0 * np.sqrt(mask.sum() / np.pi)
    return float(pixels * np.median(depths) / view.focal / scale)
