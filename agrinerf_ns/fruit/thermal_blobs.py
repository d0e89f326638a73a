"""Fruit in a thermal frame: the fruit-sized blobs of its values (temperature, or the 8-bit frame), filled as discs.

The data stage's ``thermal`` fruit masks (:mod:`agrinerf_ns.process.fruit_mask_makers`, ``--mask-maker.thermal-rule
blobs``) are these discs; the settings were chosen on tuning seeds (results/fruit-masks-dark). The ``bodies`` rule
places the same blobs in 3D across frames (:mod:`agrinerf_ns.fruit.thermal_bodies`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import List, Tuple

import numpy as np
from jaxtyping import Bool, Float

from agrinerf_ns.fruit.contrast import Polarity
from agrinerf_ns.robust import robust_spread

MIN_BLOB_SIGMA = 1.5
"""The smallest scale in pixels (a disc about 4 px across) on any frame size: below it the Laplacian answers single
noisy pixels."""
MAX_CURVATURE_RATIO = 3.0
"""A blob whose principal curvatures differ by more than this factor is a ridge, not a fruit (`curvature_ratio`;
`agrinerf_ns.fruit.blobs.elongation` measures a mask's shape instead)."""
MIN_DISC_SHARE = 0.9
"""A blob whose disc lies less than this share inside the seen frame is not taken."""


@dataclass(frozen=True)
class Blob:
    """A fruit-sized blob of one thermal frame."""

    frame: int
    row: float
    col: float
    sigma: float
    """Laplacian scale (pixels); the blob's disc has radius sqrt(2) sigma."""
    sign: float
    """+1 warmer than the canopy, -1 cooler."""
    offset: float
    """Median over its disc minus the canopy's value, in the frame's units (degrees C where radiometric)."""
    region_ratio: float = 1.0
    """The area of the connected region around its centre that lies at least half its offset from the canopy's
    value, over its disc's area: about 1 for a compact body among leaves, several for a part of a larger warm or cool
    structure (a stake, a stem, ground or sky seen between leaves)."""
    extreme: float = 0.0
    """The disc's value farthest from the canopy's on its side, minus the canopy's value, in the frame's units: a
    blob of leaves around a gap of sky has a median a few degrees off the leaves and sky-cold pixels inside."""


def thermal_blobs(
    thermal: Float[np.ndarray, "h w"],
    seen: Bool[np.ndarray, "h w"],
    *,
    sizes: Tuple[float, float],
    polarity: Polarity,
    threshold: float,
    min_canopy_offset: float,
) -> Bool[np.ndarray, "h w"]:
    """The seen discs of the blobs of :func:`thermal_blob_list` on the side(s) of ``polarity``."""
    sides = {"warm": (1.0,), "cool": (-1.0,), "both": (1.0, -1.0)}[polarity]
    found = thermal_blob_list(thermal, seen, sizes=sizes, threshold=threshold, min_canopy_offset=min_canopy_offset)
    return blob_discs(thermal.shape, seen, [b for b in found if b.sign in sides])


def blob_discs(shape: Tuple[int, ...], seen: Bool[np.ndarray, "h w"], blobs: List[Blob]) -> Bool[np.ndarray, "h w"]:
    """The seen pixels of the blobs' discs (radius sqrt(2) sigma)."""
    rows, cols = np.mgrid[0 : shape[0], 0 : shape[1]]
    fruit = np.zeros(shape[:2], bool)
    for b in blobs:
        fruit |= (rows - b.row) ** 2 + (cols - b.col) ** 2 <= 2.0 * b.sigma**2
    return fruit & seen


def thermal_blob_list(
    thermal: Float[np.ndarray, "h w"],
    seen: Bool[np.ndarray, "h w"],
    *,
    sizes: Tuple[float, float],
    threshold: float,
    min_canopy_offset: float,
    frame: int = 0,
) -> List[Blob]:
    """The fruit-sized blobs of a thermal frame on both sides of the canopy's value: scikit-image's scale-normalised
    Laplacian of Gaussian (`blob_log`) on the frame in robust spreads (median and 1.4826 MAD over the seen pixels,
    the unseen ones set to the median so the view's border is no blob), warm blobs on it and cool ones on its
    negative: a blob responds to the Laplacian at its own scale and an edge does not, so the rims of large warm or
    cool regions, which a local contrast marks, are not fruit.

    ``sizes``: the least and largest fruit diameter, as fractions of the frame's shorter side; ``threshold``: the
    least Laplacian response, in robust spreads; a blob whose median lies less than ``min_canopy_offset`` spreads from
    the canopy's value (`canopy_value`), on its own side, is leaves, not fruit; ``frame``: the frame's index, kept
    with each blob."""
    from skimage.feature import blob_log

    values = thermal[seen].astype(np.float64)
    if values.size == 0:
        return []
    median = float(np.median(values))
    spread = max(robust_spread(values, median), 1e-6)
    z = np.where(seen, (thermal - median) / spread, 0.0)
    short = min(thermal.shape)
    # a disc of diameter d is found at sigma d / (2 sqrt 2)
    low, high = (max(MIN_BLOB_SIGMA, f * short / (2.0 * np.sqrt(2.0))) for f in sizes)
    rows, cols = np.mgrid[0 : thermal.shape[0], 0 : thermal.shape[1]]
    canopy = canopy_value(z[seen])
    found: List[Blob] = []
    for sign in (1.0, -1.0):
        for row, col, sigma in blob_log(np.clip(sign * z, 0.0, None), min_sigma=low, max_sigma=high, num_sigma=12,
                                        threshold=threshold, log_scale=True):  # fmt: skip
            disc = ((rows - row) ** 2 + (cols - col) ** 2 <= 2.0 * sigma**2) & seen
            if disc.sum() < MIN_DISC_SHARE * 2.0 * np.pi * sigma**2:
                continue  # cut by the frame's or the view's border: a band of sky or ground there looks like a blob
            if curvature_ratio(z, row, col, sigma) > MAX_CURVATURE_RATIO:
                continue  # a ridge (a band of sky, a stake) answers the Laplacian too, with one curvature only
            offset = float(np.median(z[disc])) - canopy
            if sign * offset >= min_canopy_offset:
                ratio = region_ratio(z, seen, row, col, sigma, canopy + 0.5 * offset, sign)
                extreme = sign * float(np.max(sign * z[disc])) - canopy
                found.append(Blob(frame, float(row), float(col), float(sigma), sign, offset * spread, ratio,
                                  extreme * spread))  # fmt: skip
    return found


def region_ratio(
    z: Float[np.ndarray, "h w"],
    seen: Bool[np.ndarray, "h w"],
    row: float,
    col: float,
    sigma: float,
    level: float,
    sign: float,
) -> float:
    """The connected region of the seen pixels beyond ``level`` (on ``sign``'s side) that holds (row, col), in units
    of the blob's disc area (:attr:`Blob.region_ratio`); 0 where the centre itself is not beyond it."""
    from scipy import ndimage

    labels, _ = ndimage.label((sign * (z - level) > 0) & seen)
    label = labels[int(round(row)), int(round(col))] if 0 <= int(round(row)) < z.shape[0] else 0
    if label == 0:
        return 0.0
    return float((labels == label).sum()) / (2.0 * np.pi * sigma**2)


def curvature_ratio(z: Float[np.ndarray, "h w"], row: float, col: float, sigma: float) -> float:
    """The ratio of the larger to the smaller principal curvature of ``z`` smoothed at ``sigma`` at (row, col): about
    1 at the centre of a round blob, large along a ridge (the Hessian test of Lowe's SIFT)."""
    from scipy import ndimage

    reach = int(np.ceil(4 * sigma)) + 1
    r0, c0 = max(0, int(row) - reach), max(0, int(col) - reach)
    window = z[r0 : int(row) + reach + 1, c0 : int(col) + reach + 1]
    at = (int(row) - r0, int(col) - c0)
    drr, dcc, drc = (float(ndimage.gaussian_filter(window, sigma, order=o)[at]) for o in ((2, 0), (0, 2), (1, 1)))
    curvatures = np.abs(np.linalg.eigvalsh(np.array([[drr, drc], [drc, dcc]])))
    return float(curvatures.max() / max(float(curvatures.min()), 1e-12))


def canopy_value(z: Float[np.ndarray, " n"], bin_width: float = 1.0) -> float:
    """The most common value of ``z`` (robust spreads), the centre of the fullest bin of ``bin_width``: bins as wide as
    a spread hold the canopy's noisy values together, so a sky clipped to one value does not outnumber them."""
    edges = np.arange(float(z.min()), float(z.max()) + bin_width, bin_width)
    if len(edges) < 2:
        return float(z.min())
    counts, edges = np.histogram(z, bins=edges)
    return float(edges[counts.argmax()] + bin_width / 2)
