"""TensoRF VM encoding with a bilinear lookup that is cheaper to train than `grid_sample` on a CPU.

`BilinearVMEncoding` is Nerfstudio's `TensorVMEncoding` (same parameters, same initialisation, same upsampling, same
features for coordinates in [-1, 1]) with a different lookup: the planes are stored channels-last, so that a plane is
a table of `3 * resolution**2` rows of `num_components` features, and a bilinear sample is a weighted sum of four rows
(`F.embedding_bag`). Its backward pass adds rows of gradient instead of scattering single values into channel-major
planes, which is where `grid_sample`'s backward spends its time on a CPU.
The corner indices and weights (`VMCorners`) depend only on the coordinates and the resolution, so volumes of the same
resolution can share them (the field computes them once for its RGB and thermal volumes).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Tuple

import torch
import torch.nn.functional as F
from jaxtyping import Bool, Float, Int
from nerfstudio.field_components.encodings import TensorVMEncoding
from torch import Tensor, nn

_PLANE_AXES_W = (0, 0, 1)
"""Coordinate axis along each plane's width (Nerfstudio's plane order: xy, xz, yz; grid x is the width)."""
_PLANE_AXES_H = (1, 2, 2)
"""Coordinate axis along each plane's height."""
_LINE_AXES = (2, 1, 0)
"""Coordinate axis along each line (paired with the plane that lacks it)."""


@dataclass
class VMCorners:
    """Bilinear corners of `n` points in the three planes and linear corners in the three lines of a VM volume.

    Rows are point-major: row `3 * i + p` is point `i` in plane (or line) `p`.
    """

    coords: Float[Tensor, "n 3"]
    """The points, clamped to [-1, 1] (for the `grid_sample` lookup)."""
    plane_index: Int[Tensor, "n3 4"]
    """Row of each corner in the flattened planes (`3 * resolution**2` rows)."""
    plane_weight: Float[Tensor, "n3 4"]
    """Bilinear weight of each corner."""
    line_index: Int[Tensor, "n3 2"]
    """Row of each end in the flattened lines (`3 * resolution` rows)."""
    line_weight: Float[Tensor, "n3 2"]
    """Linear weight of each end."""
    resolution: int
    """Grid resolution the indices refer to."""

    @property
    def num_points(self) -> int:
        return self.plane_index.shape[0] // 3

    def select(self, mask: Bool[Tensor, "n"]) -> "VMCorners":
        """The corners of the points where `mask` is True."""

        def pick(t: Tensor) -> Tensor:
            return t.view(-1, 3, t.shape[-1])[mask].reshape(-1, t.shape[-1])

        return VMCorners(
            self.coords[mask], pick(self.plane_index), pick(self.plane_weight), pick(self.line_index),
            pick(self.line_weight), self.resolution,
        )  # fmt: skip


def vm_corners(coords: Float[Tensor, "n 3"], resolution: int) -> VMCorners:
    """Corner rows and weights of `coords` (in [-1, 1], `align_corners=True` convention) in a VM volume.

    Coordinates outside [-1, 1] are clamped to the border and NaN is read as 0, so indices are always valid.
    """
    res = int(resolution)
    if res < 2:
        raise ValueError(f"A VM volume needs a resolution of at least 2, got {res}")
    clamped = torch.nan_to_num(coords.detach().float()).clamp(-1.0, 1.0)
    pos = (clamped + 1.0) * (0.5 * (res - 1))  # [n, 3]
    low = pos.floor().clamp(0, res - 2)
    frac = pos - low  # in [0, 1]
    low = low.long()
    n = coords.shape[0]
    device = coords.device

    w_axes = torch.tensor(_PLANE_AXES_W, device=device)
    h_axes = torch.tensor(_PLANE_AXES_H, device=device)
    plane_offset = torch.arange(3, device=device) * (res * res)
    base = plane_offset + low[:, h_axes] * res + low[:, w_axes]  # [n, 3]
    plane_index = torch.stack((base, base + 1, base + res, base + res + 1), dim=-1)  # [n, 3, 4]
    fw, fh = frac[:, w_axes], frac[:, h_axes]
    plane_weight = torch.stack(((1 - fw) * (1 - fh), fw * (1 - fh), (1 - fw) * fh, fw * fh), dim=-1)

    l_axes = torch.tensor(_LINE_AXES, device=device)
    line_base = torch.arange(3, device=device) * res + low[:, l_axes]  # [n, 3]
    line_index = torch.stack((line_base, line_base + 1), dim=-1)  # [n, 3, 2]
    fl = frac[:, l_axes]
    line_weight = torch.stack((1 - fl, fl), dim=-1)

    return VMCorners(
        clamped, plane_index.reshape(3 * n, 4), plane_weight.reshape(3 * n, 4),
        line_index.reshape(3 * n, 2), line_weight.reshape(3 * n, 2), res,
    )  # fmt: skip


class _WeightedRows(torch.autograd.Function):
    """`out[i] = sum_k weight[i, k] * table[index[i, k]]`; the backward adds rows with one `index_add_` per corner
    (on a CPU several times faster than `embedding_bag`'s backward, which sorts the indices first)."""

    @staticmethod
    def forward(ctx, table: Tensor, index: Tensor, weight: Tensor) -> Tensor:  # type: ignore[override]
        ctx.save_for_backward(index, weight)
        ctx.table_shape = table.shape
        return F.embedding_bag(index, table, per_sample_weights=weight, mode="sum")

    @staticmethod
    def backward(ctx, grad_out: Tensor) -> Tuple[Tensor, None, None]:  # type: ignore[override]
        index, weight = ctx.saved_tensors
        grad_table = grad_out.new_zeros(ctx.table_shape)
        scaled = torch.empty_like(grad_out)  # one buffer for every corner: no fresh (page-faulting) allocation each
        for k in range(index.shape[1]):
            torch.mul(grad_out, weight[:, k : k + 1], out=scaled)
            grad_table.index_add_(0, index[:, k], scaled)
        return grad_table, None, None


def weighted_rows(
    table: Float[Tensor, "rows c"], index: Int[Tensor, "n k"], weight: Float[Tensor, "n k"]
) -> Float[Tensor, "n c"]:
    """Weighted sum of `k` rows of `table` per output row (differentiable in `table` only)."""
    return _WeightedRows.apply(table, index, weight)


VMLookup = Literal["auto", "rows", "grid_sample"]
"""How a VM volume is sampled: "rows" (weighted row sums, fastest on a CPU), "grid_sample" (Nerfstudio's lookup),
"auto" (rows on a CPU, grid_sample elsewhere)."""


class BilinearVMEncoding(TensorVMEncoding):
    """Nerfstudio's `TensorVMEncoding` with a row-gather bilinear lookup (see the module docstring).

    Args:
        resolution: initial resolution of the grid.
        num_components: components per plane and line.
        init_scale: scale of the random initialisation.
        lookup: see `VMLookup`.
    """

    def __init__(
        self, resolution: int = 128, num_components: int = 24, init_scale: float = 0.1, lookup: VMLookup = "auto"
    ) -> None:
        super().__init__(resolution=resolution, num_components=num_components, init_scale=init_scale)
        if lookup not in ("auto", "rows", "grid_sample"):
            raise ValueError(f"Unknown VM lookup {lookup!r}; expected 'auto', 'rows' or 'grid_sample'")
        self.lookup = lookup
        self._to_channels_last()

    def uses_rows(self) -> bool:
        """Whether lookups gather rows (else Nerfstudio's `grid_sample`)."""
        return self.lookup == "rows" or (self.lookup == "auto" and self.plane_coef.device.type == "cpu")

    def _to_channels_last(self) -> None:
        """Store planes and lines channels-last, so that their row tables are views (no copy per lookup)."""
        self.plane_coef = nn.Parameter(self.plane_coef.data.contiguous(memory_format=torch.channels_last))
        self.line_coef = nn.Parameter(self.line_coef.data.contiguous(memory_format=torch.channels_last))

    def features(self, corners: VMCorners) -> Float[Tensor, "n out_dim"]:
        """Features (`3 * num_components`, Nerfstudio's order: plane-major) at precomputed corners."""
        if corners.resolution != self.resolution:
            raise ValueError(f"Corners for resolution {corners.resolution} used on a volume of {self.resolution}")
        if not self.uses_rows():
            return super().forward(corners.coords)
        comps = self.num_components
        plane_table = self.plane_coef.permute(0, 2, 3, 1).reshape(-1, comps)  # [3 * res * res, comps]
        line_table = self.line_coef.permute(0, 2, 3, 1).reshape(-1, comps)  # [3 * res, comps]
        plane = weighted_rows(plane_table, corners.plane_index, corners.plane_weight)
        line = weighted_rows(line_table, corners.line_index, corners.line_weight)
        return (plane * line).view(corners.num_points, 3 * comps)

    def forward(self, in_tensor: Float[Tensor, "*bs 3"]) -> Float[Tensor, "*bs out_dim"]:
        """Encoding of positions in [-1, 1] (clamped there), as `TensorVMEncoding.forward`."""
        flat = in_tensor.reshape(-1, 3)
        out = self.features(vm_corners(flat, self.resolution))
        return out.reshape(*in_tensor.shape[:-1], out.shape[-1])

    @torch.no_grad()
    def upsample_grid(self, resolution: int) -> None:
        """Nerfstudio's upsampling (new Parameters), then back to channels-last."""
        super().upsample_grid(resolution)
        self._to_channels_last()
