"""AgriNeRF losses as pure functions (paper: ../shared/paper/agrinerf_paper.tex, Method section).

All functions compute in float32 whatever the input precision, ignore non-finite targets through their masks, and
return a scalar tensor. Weights are applied by the model (`loss_coefficients`), not here.
"""

from __future__ import annotations

import functools
from typing import Optional, Tuple, Union

import torch
from jaxtyping import Float
from torch import Tensor

from agrinerf_ns.colour import srgb_to_linear

LUMA_WEIGHTS = (0.299, 0.587, 0.114)
"""ITU-R BT.601 luma weights: the RGB -> one channel mapping of L_reg (the same weights as OpenCV's RGB2GRAY, so a
grey image computed by the processing stage and by the loss agree)."""


@functools.lru_cache(maxsize=None)
def constant(values: Tuple[float, ...], device: torch.device) -> Float[Tensor, " n"]:
    """`values` as a float32 tensor on `device`, made once per device: a tensor made from Python numbers on a GPU is
    an upload, which waits for the device, at every call."""
    return torch.tensor(values, dtype=torch.float32, device=device)


def luminance(rgb: Float[Tensor, "*bs 3"]) -> Float[Tensor, "*bs 1"]:
    """Y = 0.299 R + 0.587 G + 0.114 B of gamma-encoded RGB in [0, 1] (BT.601 luma)."""
    return (rgb.float() * constant(LUMA_WEIGHTS, rgb.device)).sum(dim=-1, keepdim=True)


REC709_WEIGHTS = (0.2126, 0.7152, 0.0722)
"""Rec. 709 luminance weights of linear RGB: what an event pixel's photodiode integrates (approximately: a real sensor
has its own spectral response; the synthetic event camera uses exactly these)."""


def log_luminance(rgb: Float[Tensor, "*bs 3"], eps: float) -> Float[Tensor, "*bs 1"]:
    """The event camera's response to an sRGB-encoded colour: log(Y + eps), Y the Rec. 709 luminance of linear RGB.

    Events fire on changes of this quantity; `eps` (in the linear units of the rendered colour) keeps the log finite
    at black and sets how much a change near black counts.
    """
    return torch.log((srgb_to_linear(rgb) * constant(REC709_WEIGHTS, rgb.device)).sum(dim=-1, keepdim=True) + eps)


def event_loss(
    log_start: Float[Tensor, "*bs 1"],
    log_end: Float[Tensor, "*bs 1"],
    on_counts: Float[Tensor, "*bs 1"],
    off_counts: Float[Tensor, "*bs 1"],
    c_on: Union[float, Float[Tensor, ""]],
    c_off: Union[float, Float[Tensor, ""]],
    mask: Optional[Float[Tensor, "*bs 1"]] = None,
    lower_bound: bool = False,
) -> Float[Tensor, ""]:
    """EvDeblurNeRF-style event loss: mean (log L(t_end) - log L(t_start) - (C_on N_on - C_off N_off))^2.

    The rendered log luminance of one pixel at the two ends of a window, against the contrast thresholds times the ON
    and OFF event counts the pixel fired in it. Pixels without events count too (their target is no change); pixels
    outside the event camera's view are masked out.

    ``lower_bound``: a pixel's count only bounds its change from below. A real pixel drops events (its refractory
    period after each event, its bandwidth), never adds them beyond noise, so a change larger than C N in the counted
    direction is not penalised; a smaller one, one of the other sign and any change where no event fired are.
    """
    target = c_on * on_counts.float() - c_off * off_counts.float()
    pred = log_end.float() - log_start.float()
    if lower_bound:
        beyond = (target != 0) & (torch.sign(pred - target) == torch.sign(target))
        pred = torch.where(beyond, target, pred)
    return masked_mse(pred, target, mask)


def event_pair_loss(
    log_start: Float[Tensor, "m 1"], log_end: Float[Tensor, "m 1"], target: Float[Tensor, "m 1"]
) -> Float[Tensor, ""]:
    """EvDeblurNeRF's event-to-event loss (its ``egm_loss``): mean (log L(t_successor) - log L(t_event) - target)^2
    over event samples, each target +C_on or -C_off (``event_pairs.pair_targets``). 0 without samples, never NaN."""
    return masked_mse(log_end.float() - log_start.float(), target)


def masked_mse(
    pred: Float[Tensor, "*bs c"], target: Float[Tensor, "*bs c"], mask: Optional[Float[Tensor, "*bs 1"]] = None
) -> Float[Tensor, ""]:
    """Mean of (pred - target)^2 over the pixels where `mask` > 0.5 (all pixels when `mask` is None).

    Returns 0 (with a gradient path) when no pixel is valid, never NaN.
    """
    pred = pred.float()
    target = target.float().to(pred.device)
    valid = torch.isfinite(target).all(dim=-1, keepdim=True)
    if mask is not None:
        valid = valid & (mask.to(pred.device).float() > 0.5)
    sq = torch.where(valid, (pred - torch.nan_to_num(target)) ** 2, torch.zeros_like(pred))
    count = valid.float().sum() * pred.shape[-1]
    return sq.sum() / count.clamp(min=1.0)


def rgb_loss(pred_rgb: Float[Tensor, "*bs 3"], gt_rgb: Float[Tensor, "*bs 3"]) -> Float[Tensor, ""]:
    """Paper Eq. 1, L_rgb = 1/|R| sum_r ||C~_rgb(r) - C_rgb(r)||^2 (mean over rays and channels, as Nerfstudio's MSE)."""
    return masked_mse(pred_rgb, gt_rgb)


def thermal_loss(
    pred_thermal: Float[Tensor, "*bs 1"],
    gt_thermal: Float[Tensor, "*bs 1"],
    thermal_mask: Optional[Float[Tensor, "*bs 1"]] = None,
) -> Float[Tensor, ""]:
    """Paper Eq. 2, L_th = 1/|R| sum_r ||C~_th(r) - C_th(r)||^2 over rays the thermal camera saw (`thermal_mask`)."""
    return masked_mse(pred_thermal, gt_thermal, thermal_mask)


def cross_spectral_rgb_term(pred_thermal: Float[Tensor, "*bs 1"], gt_rgb: Float[Tensor, "*bs 3"]) -> Float[Tensor, ""]:
    """First term of paper Eq. 3: mean ||C~_th - Y(C_rgb)||^2, with Y the BT.601 luma of the ground-truth RGB."""
    return masked_mse(pred_thermal, luminance(gt_rgb))


def cross_spectral_event_term(
    pred_thermal: Float[Tensor, "*bs 1"],
    gt_event: Float[Tensor, "*bs 1"],
    event_mask: Optional[Float[Tensor, "*bs 1"]] = None,
) -> Float[Tensor, ""]:
    """Second term of paper Eq. 3: mean ||C~_th - C_ev||^2 over rays with a valid event frame (`event_mask`)."""
    return masked_mse(pred_thermal, gt_event, event_mask)


def cross_spectral_loss(
    pred_thermal: Float[Tensor, "*bs 1"],
    gt_rgb: Optional[Float[Tensor, "*bs 3"]],
    gt_event: Optional[Float[Tensor, "*bs 1"]],
    event_mask: Optional[Float[Tensor, "*bs 1"]] = None,
    rgb_weight: float = 1.0,
    event_weight: float = 1.0,
) -> Float[Tensor, ""]:
    """Paper Eq. 3, L_reg = mean(w_rgb ||C~_th - Y(C_rgb)||^2 + w_ev ||C~_th - C_ev||^2); absent modalities drop out.

    The model keeps the two terms apart (each with its own `loss_coefficients` entry); this is their weighted sum.
    """
    total = pred_thermal.float().sum() * 0.0
    if gt_rgb is not None:
        total = total + rgb_weight * cross_spectral_rgb_term(pred_thermal, gt_rgb)
    if gt_event is not None:
        total = total + event_weight * cross_spectral_event_term(pred_thermal, gt_event, event_mask)
    return total


def scale_gradient(values: Tensor, scale: float) -> Tensor:
    """`values` unchanged in the forward pass, with the gradient flowing back through them multiplied by `scale`.

    The model composites a head's samples with `scale_gradient(weights, s)` to choose how strongly a loss term may move
    the density (the rendering weights) without changing what the term sees: 1 is the plain path, 0 a detach.
    """
    if scale == 1.0:
        return values
    if scale == 0.0:
        return values.detach()
    frozen = values.detach()
    return frozen + scale * (values - frozen)


def l1_volume_loss(*tensors: Tensor) -> Float[Tensor, ""]:
    """L1 sparsity of VM factors: one mean |w| over every entry of all the given tensors (plane entries outnumber line
    entries by the resolution, so the planes dominate). TensoRF's `TensorVMSplit.density_L1` instead sums one mean |w|
    per factor, so a line weighs as much as a plane; the loss weight absorbs the difference in scale."""
    if not tensors:
        return torch.zeros(())  # cpu: a 0-dim tensor, which torch adds to any device's tensors
    total = torch.stack([t.abs().sum() for t in tensors]).sum()
    count = sum(t.numel() for t in tensors)
    return total / max(count, 1)
