"""The fruit-colour score of an RGB image: saturation where the hue is a fruit's (red to yellow), after stretching the
image's brightness so that a dark frame or render is not black."""

from __future__ import annotations

import cv2
import numpy as np
from jaxtyping import Bool, Float

MIN_HUE_DEG = -20.0
"""Fruit hues span ``MIN_HUE_DEG`` .. ``MAX_HUE_DEG`` (0 = red, 60 = yellow, 120 = green)."""
MAX_HUE_DEG = 70.0


def fruit_colour(
    rgb: Float[np.ndarray, "h w 3"],
    valid: Bool[np.ndarray, "h w"],
    min_hue_deg: float = MIN_HUE_DEG,
    max_hue_deg: float = MAX_HUE_DEG,
) -> Float[np.ndarray, "h w"]:
    """Saturation x sqrt(value) where the hue lies in ``min_hue_deg`` .. ``max_hue_deg``, after scaling the image so
    its 99th percentile of brightness over ``valid`` pixels is 1."""
    rgb = np.clip(np.nan_to_num(rgb.astype(np.float32)), 0.0, None)
    peak = float(np.percentile(rgb.max(-1)[valid], 99)) if valid.any() else 1.0
    rgb = np.clip(rgb / max(peak, 1e-6), 0.0, 1.0)
    hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)  # float input: H in degrees [0, 360), S and V in [0, 1]
    hue = np.where(hsv[..., 0] > 180.0, hsv[..., 0] - 360.0, hsv[..., 0])
    in_band = (hue >= min_hue_deg) & (hue <= max_hue_deg)
    return np.where(in_band, hsv[..., 1] * np.sqrt(hsv[..., 2]), 0.0).astype(np.float32)
