"""What fruit vision reads of a rendered view: its depth, accumulation, focal length and named outputs.

:class:`agrinerf_ns.count.render.RenderedView` is one; fruit vision names only this protocol, so that it sits below the
counter that renders the views.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np
from jaxtyping import Float

MIN_ACCUMULATION = 0.5
"""Rendered pixels below this accumulation are sky or nothing: no surface point, never fruit."""


@runtime_checkable
class View(Protocol):
    """One camera's rendered images, (H, W[, C]) arrays."""

    depth: Float[np.ndarray, "h w"]
    """Distance along each ray (Nerfstudio units)."""
    accumulation: Float[np.ndarray, "h w"]
    focal: float
    """Focal length in pixels at this resolution."""

    def optional_output(self, name: str) -> Float[np.ndarray, "h w *channels"]:
        """The ``rgb``, ``thermal``, ``temperature`` or ``fruit`` image; ValueError naming the view where there is
        none."""
        ...
