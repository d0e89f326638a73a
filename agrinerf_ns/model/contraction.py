"""L-inf scene contraction (mip-NeRF 360's, with the max norm) computed with `amax`.

Nerfstudio's `SceneContraction(order=inf)` takes the norm with `torch.linalg.norm(ord=inf)`; the max of absolute
values is the same number without the general p-norm code path; the field contracts every coarse and fine sample.
"""

from __future__ import annotations

import torch
from jaxtyping import Float
from nerfstudio.field_components.spatial_distortions import SceneContraction
from torch import Tensor


class LinfContraction(SceneContraction):
    """`SceneContraction(order=inf)`: points in the unit cube stay, points outside go to `(2 - 1/|x|) x / |x|`, so
    all of space lands in the cube of half-width 2 (|x| is the max norm)."""

    def __init__(self) -> None:
        super().__init__(order=float("inf"))

    def forward(self, positions):  # Tensor or Nerfstudio Gaussians, as the parent
        if not isinstance(positions, Tensor):
            return super().forward(positions)
        return contract_linf(positions)


def contract_linf(positions: Float[Tensor, "*bs 3"]) -> Float[Tensor, "*bs 3"]:
    """The L-inf contraction of `positions` (see `LinfContraction`)."""
    mag = positions.abs().amax(dim=-1, keepdim=True)
    return torch.where(mag < 1, positions, (2 - 1 / mag) * (positions / mag))
