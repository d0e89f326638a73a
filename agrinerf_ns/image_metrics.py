"""Image quality against the clean truth of synthetic scenes, after exposure alignment."""

from __future__ import annotations

import torch
from jaxtyping import Float
from torch import Tensor
from torchmetrics.functional.image import structural_similarity_index_measure

from agrinerf_ns.colour import linear_to_srgb, srgb_to_linear


def exposure_align(pred: Float[Tensor, "h w 3"], truth: Float[Tensor, "h w 3"]) -> Float[Tensor, "h w 3"]:
    """Scale each channel of ``pred`` in linear light by the least-squares gain that best matches ``truth``.

    The synthetic truth is auto-exposed while a camera in the dark is gain-limited, so a faithful reconstruction of
    a dark capture is darker than the truth by an unknown exposure factor; aligning it per image and channel (as
    low-light NeRF evaluations do) scores structure and noise, not the exposure setting.
    """
    p, t = srgb_to_linear(pred).reshape(-1, 3), srgb_to_linear(truth).reshape(-1, 3)
    gain = (p * t).sum(0) / (p * p).sum(0).clamp(min=1e-12)
    return linear_to_srgb(srgb_to_linear(pred) * gain)


def psnr(pred: Float[Tensor, "h w c"], truth: Float[Tensor, "h w c"]) -> float:
    """Peak signal-to-noise ratio for images in [0, 1] (capped at 100 dB for identical images)."""
    mse = torch.mean((pred.clamp(0, 1) - truth) ** 2)
    return float(-10.0 * torch.log10(mse.clamp(min=1e-10)))


def ssim(pred: Float[Tensor, "h w c"], truth: Float[Tensor, "h w c"]) -> float:
    """SSIM as Nerfstudio computes it (torchmetrics, 11x11 Gaussian window)."""
    return float(
        structural_similarity_index_measure(
            pred.clamp(0, 1).permute(2, 0, 1)[None], truth.permute(2, 0, 1)[None], data_range=1.0
        )
    )
