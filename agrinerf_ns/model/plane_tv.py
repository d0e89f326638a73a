"""Total variation of a VM volume's planes, with a hand-written gradient (the regulariser of TensoRF's VM fields)."""

from __future__ import annotations

from typing import Optional, Tuple

import torch
from jaxtyping import Float
from torch import Tensor

from agrinerf_ns.model.vm_encoding import VMLayout, VMVolume, plane_views


def plane_tv(volume: VMVolume) -> Float[Tensor, ""]:
    """Total variation of a volume's planes: the mean squared difference of neighbours along the height plus that
    along the width, each averaged over every difference of the three planes and all components (for a cube, half of
    Nerfstudio's `tv_loss` on the stacked planes; TensoRF's `TV_loss_density` sums a TV per plane with its own scale:
    the loss weights absorb the constant). The gradient is written by hand (`_PlaneTV`): autograd's dense chain of
    slices, differences and powers over every plane was most of a step at 300^3."""
    return _PlaneTV.apply(volume.plane_table, volume.layout)


class _PlaneTV(torch.autograd.Function):
    """`plane_tv` with a hand-written backward: d/dP of sum(d^2) / N is 2 d / N added at the later neighbour and
    subtracted at the earlier one, per plane, written into one gradient table."""

    @staticmethod
    def forward(ctx, table: Tensor, layout: VMLayout) -> Tensor:  # type: ignore[override]
        n_h, n_w = _tv_counts(layout, table.shape[-1])
        total_h = table.new_zeros(())
        total_w = table.new_zeros(())
        for plane in plane_views(table, layout):
            total_h = total_h + (plane[1:] - plane[:-1]).pow(2).sum()
            total_w = total_w + (plane[:, 1:] - plane[:, :-1]).pow(2).sum()
        ctx.save_for_backward(table)
        ctx.layout = layout
        return total_h / max(n_h, 1) + total_w / max(n_w, 1)

    @staticmethod
    def backward(ctx, grad_out: Tensor) -> Tuple[Optional[Tensor], None]:  # type: ignore[override]
        (table,) = ctx.saved_tensors
        layout: VMLayout = ctx.layout
        n_h, n_w = _tv_counts(layout, table.shape[-1])
        grad = torch.zeros_like(table)
        scale_h = 2.0 * grad_out / max(n_h, 1)
        scale_w = 2.0 * grad_out / max(n_w, 1)
        for plane, g in zip(plane_views(table, layout), plane_views(grad, layout), strict=True):
            dh = (plane[1:] - plane[:-1]).mul_(scale_h)
            g[1:] += dh
            g[:-1] -= dh
            dw = (plane[:, 1:] - plane[:, :-1]).mul_(scale_w)
            g[:, 1:] += dw
            g[:, :-1] -= dw
        return grad, None


def _tv_counts(layout: VMLayout, comps: int) -> Tuple[int, int]:
    """Differences along the height and along the width over all planes and components."""
    n_h = sum((h - 1) * w for h, w in layout.plane_shapes) * comps
    n_w = sum(h * (w - 1) for h, w in layout.plane_shapes) * comps
    return n_h, n_w
