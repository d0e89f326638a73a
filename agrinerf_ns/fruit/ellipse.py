"""A round fruit's pixels from its box: the ellipse inscribed in a pixel box."""

from __future__ import annotations

import numpy as np
from jaxtyping import Bool, Float


def inscribed_ellipse(height: int, width: int, box: Float[np.ndarray, " 4"]) -> Bool[np.ndarray, "h w"]:
    """The pixels of an ``height`` x ``width`` image whose centres lie in the ellipse inscribed in the pixel box
    ``x1 y1 x2 y2``: a round fruit's pixels, from its box (half-axes at least half a pixel)."""
    y, x = np.mgrid[0:height, 0:width] + 0.5
    cx, cy = (box[0] + box[2]) / 2, (box[1] + box[3]) / 2
    rx, ry = max((box[2] - box[0]) / 2, 0.5), max((box[3] - box[1]) / 2, 0.5)
    return ((x - cx) / rx) ** 2 + ((y - cy) / ry) ** 2 <= 1.0
