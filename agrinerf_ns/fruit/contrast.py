"""Local contrast: how far a pixel's value stands out from its surroundings, in robust spreads over the image."""

from __future__ import annotations

from typing import Literal

import cv2
import numpy as np
from jaxtyping import Bool, Float

from agrinerf_ns.robust import robust_spread

Polarity = Literal["both", "warm", "cool"]
"""Fruit warmer than their surroundings (a positive contrast), cooler, or either."""


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
