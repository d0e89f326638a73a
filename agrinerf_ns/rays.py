"""The point nearest to a set of rays, shared by the thermal bodies (data stage) and the counter's triangulation."""

from __future__ import annotations

import numpy as np
from jaxtyping import Float


def nearest_point(origins: Float[np.ndarray, "n 3"], rays: Float[np.ndarray, "n 3"]) -> Float[np.ndarray, "3"]:
    """The point nearest (least squares) to every line ``origin + t ray`` (unit ``rays``): the sum of the projectors
    onto each ray's normal plane, solved by least squares, so that parallel rays give a point rather than an error."""
    origins, rays = np.asarray(origins, np.float64), np.asarray(rays, np.float64)
    projectors = np.eye(3)[None] - rays[:, :, None] * rays[:, None, :]  # [n, 3, 3]
    return np.linalg.lstsq(projectors.sum(0), np.einsum("mij,mj->i", projectors, origins), rcond=None)[0]
