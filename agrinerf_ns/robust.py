"""Robust statistics shared by the fruit mask makers and the counter."""

from __future__ import annotations

from typing import Optional

import numpy as np
from jaxtyping import Float

MAD_TO_SIGMA = 1.4826
"""A normal distribution's standard deviation over its median absolute deviation."""


def robust_spread(values: Float[np.ndarray, " n"], centre: Optional[float] = None) -> float:
    """1.4826 x the median absolute deviation of ``values`` from ``centre`` (default: their median), a standard
    deviation that outliers (fruit among leaves, the sky beside the canopy) do not inflate."""
    middle = np.median(values) if centre is None else centre
    return MAD_TO_SIGMA * float(np.median(np.abs(values - middle)))
