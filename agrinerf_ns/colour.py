"""The sRGB transfer curve (IEC 61966-2-1) and its inverse: the one colour transfer of the project (the frames, the
RGB head's output and the metrics' exposure alignment are sRGB-encoded; blur, events and alignment work in linear
light)."""

from __future__ import annotations

import torch
from jaxtyping import Float
from torch import Tensor


def _unit(values: Tensor) -> Tensor:
    return (values if values.is_floating_point() else values.float()).clamp(0.0, 1.0)


def srgb_to_linear(rgb: Float[Tensor, "*bs 3"]) -> Float[Tensor, "*bs 3"]:
    """Inverse sRGB transfer curve of values clamped to [0, 1]."""
    rgb = _unit(rgb)
    return torch.where(rgb <= 0.04045, rgb / 12.92, ((rgb + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(linear: Float[Tensor, "*bs 3"]) -> Float[Tensor, "*bs 3"]:
    """sRGB transfer curve of linear values clamped to [0, 1] (the inverse of `srgb_to_linear`). The power branch
    sees at least 1e-12, so its gradient stays finite where the linear branch is taken."""
    linear = _unit(linear)
    return torch.where(linear <= 0.0031308, linear * 12.92, 1.055 * linear.clamp(min=1e-12) ** (1 / 2.4) - 0.055)
