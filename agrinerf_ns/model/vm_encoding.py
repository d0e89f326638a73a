"""TensoRF VM encoding with a bilinear lookup that is cheaper to train than `grid_sample` on a CPU.

`BilinearVMEncoding` is Nerfstudio's `TensorVMEncoding` (same parameters, same initialisation, same upsampling, same
features for coordinates in [-1, 1]) with a different lookup: the planes are stored channels-last, so that a plane is
a table of `3 * resolution**2` rows of `num_components` features, and a bilinear sample is a weighted sum of four rows
(`F.embedding_bag`). The backward pass is a sparse matrix product: the transpose of the lookup, built once from the
corner indices, times the gradient rows (`scatter_matrix`), where `grid_sample`'s backward scatters single values into
channel-major planes, and `index_add_` scatters element by element.
The corners (`VMCorners`) depend only on the coordinates and the resolution, so volumes of the same resolution share
them and their transposed lookups (the field computes them once for its density, RGB and thermal volumes).
"""

from __future__ import annotations

import warnings
from functools import cached_property
from typing import Literal, NamedTuple, Optional, Tuple

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


class CornerRows(NamedTuple):
    """Table rows and weights of a lookup; row `3 * i + p` is point `i` in plane (or line) `p`."""

    plane_index: Int[Tensor, "n3 4"]
    """Row of each corner in the flattened planes (`3 * resolution**2` rows)."""
    plane_weight: Float[Tensor, "n3 4"]
    """Bilinear weight of each corner."""
    line_index: Int[Tensor, "n3 2"]
    """Row of each end in the flattened lines (`3 * resolution` rows)."""
    line_weight: Float[Tensor, "n3 2"]
    """Linear weight of each end."""


class VMCorners:
    """Bilinear corners of `n` points in the three planes and linear corners in the three lines of a VM volume.

    Everything but the clamped points is computed on first use and cached: the `grid_sample` lookup reads `coords`
    only, the row lookup reads `rows`, and its backward pass the transposed lookups, which volumes that share the
    corners share too.

    Args:
        coords: the points, already clamped to [-1, 1] (build with `vm_corners`).
        resolution: grid resolution the indices refer to.
        rows: their `CornerRows`, when already known (else computed on first use).
    """

    def __init__(self, coords: Float[Tensor, "n 3"], resolution: int, rows: Optional[CornerRows] = None) -> None:
        self.coords = coords
        self.resolution = resolution
        self._rows = rows

    @property
    def num_points(self) -> int:
        return self.coords.shape[0]

    @property
    def rows(self) -> CornerRows:
        """Corner rows and weights of the points (`_corner_rows`), cached."""
        if self._rows is None:
            self._rows = _corner_rows(self.coords, self.resolution)
        return self._rows

    @cached_property
    def plane_scatter(self) -> Tensor:
        """Sparse (`3 * resolution**2` x `3n`) transpose of the plane lookup (`scatter_matrix`)."""
        res, rows = self.resolution, self.rows
        return scatter_matrix(rows.plane_index[:, 0], (0, 1, res, res + 1), rows.plane_weight, 3 * res * res)

    @cached_property
    def line_scatter(self) -> Tensor:
        """Sparse (`3 * resolution` x `3n`) transpose of the line lookup (`scatter_matrix`)."""
        rows = self.rows
        return scatter_matrix(rows.line_index[:, 0], (0, 1), rows.line_weight, 3 * self.resolution)

    def select(self, mask: Bool[Tensor, " n"]) -> "VMCorners":
        """The corners of the points where `mask` is True (these corners themselves when it selects every point)."""
        if bool(mask.all()):
            return self
        if self._rows is None:
            return VMCorners(self.coords[mask], self.resolution)

        def pick(t: Tensor) -> Tensor:  # computed already: select them rather than recompute
            return t.view(-1, 3, t.shape[-1])[mask].reshape(-1, t.shape[-1])

        return VMCorners(self.coords[mask], self.resolution, CornerRows(*(pick(t) for t in self._rows)))


def vm_corners(coords: Float[Tensor, "n 3"], resolution: int) -> VMCorners:
    """Corners of `coords` (in [-1, 1], `align_corners=True` convention) in a VM volume of `resolution`.

    Coordinates outside [-1, 1] are clamped to the border and NaN is read as 0, so indices are always valid.
    """
    res = int(resolution)
    if res < 2:
        raise ValueError(f"A VM volume needs a resolution of at least 2, got {res}")
    dtype = torch.promote_types(coords.dtype, torch.float32)  # float16 -> float32, float64 stays
    return VMCorners(torch.nan_to_num(coords.detach().to(dtype)).clamp(-1.0, 1.0), res)


def _corner_rows(clamped: Float[Tensor, "n 3"], res: int) -> CornerRows:
    """Plane corner rows and bilinear weights, line end rows and linear weights of clamped points."""
    pos = (clamped + 1.0) * (0.5 * (res - 1))  # [n, 3]
    low = pos.floor().clamp(0, res - 2)
    frac = pos - low  # in [0, 1]
    low = low.long()
    n = clamped.shape[0]
    device = clamped.device

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
    return CornerRows(
        plane_index.reshape(3 * n, 4), plane_weight.reshape(3 * n, 4),
        line_index.reshape(3 * n, 2), line_weight.reshape(3 * n, 2),
    )  # fmt: skip


def scatter_matrix(
    base: Int[Tensor, " m"], offsets: Tuple[int, ...], weight: Float[Tensor, "m k"], rows: int
) -> Tensor:
    """Sparse CSR matrix `S` (rows x m) with `S[base[i] + offsets[k], i] = weight[i, k]`: `S @ g` adds row `i` of `g`,
    weighted, into table rows `base[i] + offsets[k]` (the transpose of a `k`-corner lookup).

    Built with one sort of `base` (`m` keys, not `m * k`) and counting placement of the `k` corners.
    """
    m, k = weight.shape
    device = base.device
    sorted_base, order = torch.sort(base)
    count = torch.bincount(base, minlength=rows)  # [rows]: points whose first corner is that row
    start = torch.cumsum(count, 0) - count  # exclusive prefix: first sorted position of each base row
    rank = torch.arange(m, device=device) - start[sorted_base]  # position among the points of one base row
    shifted = torch.zeros(k, rows, dtype=count.dtype, device=device)  # corner j's points per table row
    for j, off in enumerate(offsets):
        shifted[j, off:] = count[: rows - off]
    per_row = shifted.sum(0)
    crow = torch.zeros(rows + 1, dtype=torch.int64, device=device)
    torch.cumsum(per_row, 0, out=crow[1:])
    before = torch.cumsum(shifted, 0) - shifted  # entries of earlier corners in the same row
    col = torch.empty(m * k, dtype=torch.int64, device=device)
    val = torch.empty(m * k, dtype=weight.dtype, device=device)
    sorted_weight = weight[order]
    for j, off in enumerate(offsets):
        row = sorted_base + off
        pos = crow[row] + before[j, row] + rank
        col[pos] = order
        val[pos] = sorted_weight[:, j]
    with warnings.catch_warnings():  # "Sparse CSR tensor support is in beta state": said once per process, not news
        warnings.filterwarnings("ignore", message="Sparse CSR tensor support is in beta", category=UserWarning)
        return torch.sparse_csr_tensor(crow, col, val, (rows, m), check_invariants=False)


class _VMProduct(torch.autograd.Function):
    """`plane_rows * line_rows` of a VM volume at precomputed corners, differentiable in both tables.

    Forward: two `embedding_bag` weighted row sums. Backward: one sparse matrix product per table with the corners'
    `scatter_matrix` (built once per `VMCorners` and shared by every volume that reads them), which gathers the gradient
    rows of each table row where an `index_add_` per corner would scatter them element by element.
    """

    @staticmethod
    def forward(ctx, plane_table: Tensor, line_table: Tensor, corners: "VMCorners") -> Tensor:  # type: ignore[override]
        rows = corners.rows
        plane = F.embedding_bag(rows.plane_index, plane_table, per_sample_weights=rows.plane_weight, mode="sum")
        line = F.embedding_bag(rows.line_index, line_table, per_sample_weights=rows.line_weight, mode="sum")
        ctx.save_for_backward(plane, line)
        ctx.corners = corners
        return plane * line

    @staticmethod
    def backward(ctx, grad_out: Tensor) -> Tuple[Optional[Tensor], Optional[Tensor], None]:  # type: ignore[override]
        plane, line = ctx.saved_tensors
        corners: VMCorners = ctx.corners
        grad_plane = grad_line = None
        if ctx.needs_input_grad[0]:
            grad_plane = _sparse_times(corners.plane_scatter, grad_out * line)
        if ctx.needs_input_grad[1]:
            grad_line = _sparse_times(corners.line_scatter, grad_out * plane)
        return grad_plane, grad_line, None


def _sparse_times(matrix: Tensor, dense: Float[Tensor, "m c"]) -> Float[Tensor, "rows c"]:
    """`matrix @ dense` into an uninitialised result (`beta=0`: never read). `matrix @ dense` would zero a result,
    compute into a temporary and copy it over: at 300^3 that is two extra passes over a 52 MB gradient."""
    if dense.shape[0] == 0:  # no points: nothing would be written into the result
        return dense.new_zeros(matrix.shape[0], dense.shape[1])
    out = dense.new_empty(matrix.shape[0], dense.shape[1])
    return torch.addmm(out, matrix, dense, beta=0.0, out=out)


def vm_product(
    plane_table: Float[Tensor, "plane_rows c"], line_table: Float[Tensor, "line_rows c"], corners: "VMCorners"
) -> Float[Tensor, "n3 c"]:
    """Plane feature times line feature at every (point, plane) row of `corners` (differentiable in the tables)."""
    return _VMProduct.apply(plane_table, line_table, corners)


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
        return vm_product(plane_table, line_table, corners).view(corners.num_points, 3 * comps)

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
