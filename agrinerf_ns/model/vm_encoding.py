"""TensoRF VM volume with a resolution per axis and a bilinear row lookup that is cheap to train on a CPU.

`VMVolume` holds the three planes (xy, xz, yz) and three lines (z, y, x) of a VM decomposition (TensoRF's
`TensorVMSplit`; Nerfstudio's `TensorVMEncoding` for a cube) as two channels-last tables: `plane_table`, the planes'
texels one row each (`sum_p H_p * W_p` rows of `num_components` features), and `line_table` (`sum_p R_p` rows). Each
axis has its own resolution, so a box that is long and flat (an orchard row) gets square voxels. A bilinear sample is
a weighted sum of four rows (`F.embedding_bag`); its backward pass is a sparse matrix product, the transpose of the
lookup built once from the corner indices (`scatter_matrix`), where `grid_sample`'s backward scatters single values
into channel-major planes. The corners (`VMCorners`) depend only on the coordinates and the resolution, so volumes of
one resolution share them and their transposed lookups (the field computes them once for all its volumes).

For a cube the features, the initial values (same random draws) and the upsampling are those of Nerfstudio's
`TensorVMEncoding`; checkpoints written with its `plane_coef` / `line_coef` layout load (`_load_legacy_layout`).
"""

from __future__ import annotations

import warnings
from functools import cached_property
from typing import Any, Dict, List, Literal, NamedTuple, Optional, Sequence, Tuple, Union

import torch
import torch.nn.functional as F
from jaxtyping import Bool, Float, Int
from torch import Tensor, nn

PLANE_AXES_W = (0, 0, 1)
"""Coordinate axis along each plane's width (Nerfstudio's plane order: xy, xz, yz; grid x is the width)."""
PLANE_AXES_H = (1, 2, 2)
"""Coordinate axis along each plane's height."""
LINE_AXES = (2, 1, 0)
"""Coordinate axis along each line (paired with the plane that lacks it)."""

# torch says "Sparse CSR tensor support is in beta state" once per process: not news to a user. Filtered once, here:
# a `warnings.catch_warnings()` around each lookup would reset Python's once-per-location registry every step, so that
# every other library's warning (Nerfstudio's indexing notices among them) was printed again at every training step.
warnings.filterwarnings("ignore", message="Sparse CSR tensor support is in beta", category=UserWarning)

Resolution = Tuple[int, int, int]
"""Grid points along x, y and z."""


def as_resolution(resolution: Union[int, Sequence[int]]) -> Resolution:
    """`resolution` as three ints (one int: a cube); each must be at least 2."""
    res = (int(resolution),) * 3 if isinstance(resolution, int) else tuple(int(r) for r in resolution)
    if len(res) != 3 or min(res) < 2:
        raise ValueError(f"A VM volume needs a resolution of at least 2 along each of 3 axes, got {resolution}")
    return res  # type: ignore[return-value]


class VMLayout(NamedTuple):
    """Where each plane and line of a volume of one resolution sits in its tables."""

    plane_shapes: Tuple[Tuple[int, int], ...]
    """(height, width) of each plane."""
    plane_offsets: Tuple[int, ...]
    """First table row of each plane, and the row count at the end."""
    line_offsets: Tuple[int, ...]
    """First table row of each line, and the row count at the end."""

    @staticmethod
    def of(resolution: Resolution) -> "VMLayout":
        shapes = tuple((resolution[h], resolution[w]) for h, w in zip(PLANE_AXES_H, PLANE_AXES_W, strict=True))
        plane_offsets = [0]
        for h, w in shapes:
            plane_offsets.append(plane_offsets[-1] + h * w)
        line_offsets = [0]
        for axis in LINE_AXES:
            line_offsets.append(line_offsets[-1] + resolution[axis])
        return VMLayout(shapes, tuple(plane_offsets), tuple(line_offsets))


class CornerRows(NamedTuple):
    """Table rows and weights of a lookup; row `3 * i + p` is point `i` in plane (or line) `p`."""

    plane_index: Int[Tensor, "n3 4"]
    """Row of each corner in the plane table."""
    plane_weight: Float[Tensor, "n3 4"]
    """Bilinear weight of each corner."""
    line_index: Int[Tensor, "n3 2"]
    """Row of each end in the line table."""
    line_weight: Float[Tensor, "n3 2"]
    """Linear weight of each end."""


class VMCorners:
    """Bilinear corners of `n` points in the three planes and linear corners in the three lines of a VM volume.

    Everything but the clamped points is computed on first use and cached: the `grid_sample` lookup reads `coords`
    only, the row lookup reads `rows`, and its backward pass the transposed lookups, which volumes that share the
    corners share too.

    Args:
        coords: the points, already clamped to [-1, 1] (build with `vm_corners`), without a graph.
        resolution: grid resolution per axis the indices refer to.
        rows: their `CornerRows`, when already known (else computed on first use).
        source: the same clamped points with their graph, where they need a gradient (a moved ray's positions: a
            learnt blur kernel, camera pose refinement); None: the lookup is differentiable in the tables only.
    """

    def __init__(
        self,
        coords: Float[Tensor, "n 3"],
        resolution: Resolution,
        rows: Optional[CornerRows] = None,
        source: Optional[Float[Tensor, "n 3"]] = None,
    ) -> None:
        self.coords = coords
        self.resolution = resolution
        self.layout = VMLayout.of(resolution)
        self._rows = rows
        self.source = source

    @property
    def num_points(self) -> int:
        return self.coords.shape[0]

    @property
    def rows(self) -> CornerRows:
        """Corner rows and weights of the points (`_corner_rows`), cached."""
        if self._rows is None:
            self._rows = _corner_rows(self.coords, self.resolution, self.layout)
        return self._rows

    @cached_property
    def plane_scatter(self) -> Tensor:
        """Sparse (plane rows x `3n`) transpose of the plane lookup (`scatter_matrix`)."""
        offsets = [(0, 1, w, w + 1) for _, w in self.layout.plane_shapes]
        return scatter_matrix(self.rows.plane_index[:, 0], offsets, self.rows.plane_weight, self.layout.plane_offsets)

    @cached_property
    def line_scatter(self) -> Tensor:
        """Sparse (line rows x `3n`) transpose of the line lookup (`scatter_matrix`)."""
        return scatter_matrix(self.rows.line_index[:, 0], [(0, 1)] * 3, self.rows.line_weight, self.layout.line_offsets)

    def select(self, mask: Bool[Tensor, " n"]) -> "VMCorners":
        """The corners of the points where `mask` is True (these corners themselves when it selects every point)."""
        if bool(mask.all()):
            return self
        source = None if self.source is None else self.source[mask]
        if self._rows is None:
            return VMCorners(self.coords[mask], self.resolution, source=source)

        def pick(t: Tensor) -> Tensor:  # computed already: select them rather than recompute
            return t.view(-1, 3, t.shape[-1])[mask].reshape(-1, t.shape[-1])

        return VMCorners(self.coords[mask], self.resolution, CornerRows(*(pick(t) for t in self._rows)), source)


def vm_corners(coords: Float[Tensor, "n 3"], resolution: Union[int, Sequence[int]]) -> VMCorners:
    """Corners of `coords` (in [-1, 1], `align_corners=True` convention) in a VM volume of `resolution`.

    Coordinates outside [-1, 1] are clamped to the border and NaN is read as 0, so indices are always valid. Where
    `coords` need a gradient (and autograd records), the lookups are differentiable in them too (`VMCorners.source`).
    """
    res = as_resolution(resolution)
    dtype = torch.promote_types(coords.dtype, torch.float32)  # float16 -> float32, float64 stays
    clamped = torch.nan_to_num(coords.to(dtype)).clamp(-1.0, 1.0)
    source = clamped if clamped.requires_grad else None
    return VMCorners(clamped.detach(), res, source=source)


def _corner_rows(clamped: Float[Tensor, "n 3"], res: Resolution, layout: VMLayout) -> CornerRows:
    """Plane corner rows and bilinear weights, line end rows and linear weights of clamped points."""
    device = clamped.device
    res_t = torch.tensor(res, device=device, dtype=clamped.dtype)
    pos = (clamped + 1.0) * (0.5 * (res_t - 1))  # [n, 3]
    low = torch.minimum(pos.floor().clamp(min=0), res_t - 2)
    frac = pos - low  # in [0, 1]
    low = low.long()
    n = clamped.shape[0]

    w_axes = torch.tensor(PLANE_AXES_W, device=device)
    h_axes = torch.tensor(PLANE_AXES_H, device=device)
    widths = torch.tensor([w for _, w in layout.plane_shapes], device=device)
    plane_offset = torch.tensor(layout.plane_offsets[:3], device=device)
    base = plane_offset + low[:, h_axes] * widths + low[:, w_axes]  # [n, 3]
    plane_index = torch.stack((base, base + 1, base + widths, base + widths + 1), dim=-1)  # [n, 3, 4]
    fw, fh = frac[:, w_axes], frac[:, h_axes]
    plane_weight = torch.stack(((1 - fw) * (1 - fh), fw * (1 - fh), (1 - fw) * fh, fw * fh), dim=-1)

    l_axes = torch.tensor(LINE_AXES, device=device)
    line_base = torch.tensor(layout.line_offsets[:3], device=device) + low[:, l_axes]  # [n, 3]
    line_index = torch.stack((line_base, line_base + 1), dim=-1)  # [n, 3, 2]
    fl = frac[:, l_axes]
    line_weight = torch.stack((1 - fl, fl), dim=-1)
    return CornerRows(
        plane_index.reshape(3 * n, 4), plane_weight.reshape(3 * n, 4),
        line_index.reshape(3 * n, 2), line_weight.reshape(3 * n, 2),
    )  # fmt: skip


def scatter_matrix(
    base: Int[Tensor, " m"],
    offsets: Sequence[Sequence[int]],
    weight: Float[Tensor, "m k"],
    segments: Sequence[int],
) -> Tensor:
    """Sparse CSR matrix `S` (rows x m) with `S[base[i] + offsets[s][k], i] = weight[i, k]`, where `s` is the segment
    of table rows (`segments[s] <= base[i] < segments[s + 1]`; the last entry of `segments` is the row count) that
    holds `base[i]`: `S @ g` adds row `i` of `g`, weighted, into the table rows of its `k` corners (the transpose of a
    `k`-corner lookup). Corners never leave their segment (a plane's or a line's rows).

    Built with one sort of `base` (`m` keys, not `m * k`) and counting placement of the `k` corners.
    """
    m, k = weight.shape
    rows = int(segments[-1])
    device = base.device
    sorted_base, order = torch.sort(base)
    count = torch.bincount(base, minlength=rows)  # [rows]: points whose first corner is that row
    start = torch.cumsum(count, 0) - count  # exclusive prefix: first sorted position of each base row
    rank = torch.arange(m, device=device) - start[sorted_base]  # position among the points of one base row
    shifted = torch.zeros(k, rows, dtype=count.dtype, device=device)  # corner j's points per table row
    for s, offs in enumerate(offsets):
        lo, hi = int(segments[s]), int(segments[s + 1])
        for j, off in enumerate(offs):
            if hi - lo > off:
                shifted[j, lo + off : hi] = count[lo : hi - off]
    per_row = shifted.sum(0)
    crow = torch.zeros(rows + 1, dtype=torch.int64, device=device)
    torch.cumsum(per_row, 0, out=crow[1:])
    before = torch.cumsum(shifted, 0) - shifted  # entries of earlier corners in the same row
    segment = torch.bucketize(sorted_base, torch.tensor(segments[1:], device=device), right=True)
    offset_table = torch.tensor(offsets, device=device, dtype=torch.int64)  # [segments, k]
    col = torch.empty(m * k, dtype=torch.int64, device=device)
    val = torch.empty(m * k, dtype=weight.dtype, device=device)
    sorted_weight = weight[order]
    for j in range(k):
        row = sorted_base + offset_table[segment, j]
        pos = crow[row] + before[j, row] + rank
        col[pos] = order
        val[pos] = sorted_weight[:, j]
    return torch.sparse_csr_tensor(crow, col, val, (rows, m), check_invariants=False)


class _VMProduct(torch.autograd.Function):
    """`plane_rows * line_rows` of a VM volume at precomputed corners, differentiable in both tables and, where given,
    in the points' coordinates.

    Forward: two `embedding_bag` weighted row sums. Backward: one sparse matrix product per table with the corners'
    `scatter_matrix` (built once per `VMCorners` and shared by every volume that reads them), which gathers the gradient
    rows of each table row where an `index_add_` per corner would scatter them element by element. The coordinate
    gradient (`_coordinate_gradient`) is computed only when the coordinates need one.
    """

    @staticmethod
    def forward(ctx, plane_table: Tensor, line_table: Tensor, coords: Optional[Tensor], corners: "VMCorners") -> Tensor:  # type: ignore[override]
        del coords  # the corners hold their values; the argument only links the graph
        rows = corners.rows
        plane = F.embedding_bag(rows.plane_index, plane_table, per_sample_weights=rows.plane_weight, mode="sum")
        line = F.embedding_bag(rows.line_index, line_table, per_sample_weights=rows.line_weight, mode="sum")
        if ctx.needs_input_grad[2]:
            ctx.save_for_backward(plane, line, plane_table, line_table)
        else:
            ctx.save_for_backward(plane, line)
        ctx.corners = corners
        return plane * line

    @staticmethod
    def backward(ctx, grad_out: Tensor) -> Tuple[Optional[Tensor], Optional[Tensor], Optional[Tensor], None]:  # type: ignore[override]
        plane, line = ctx.saved_tensors[:2]
        corners: VMCorners = ctx.corners
        grad_plane = grad_line = grad_coords = None
        if ctx.needs_input_grad[0]:
            grad_plane = _sparse_times(corners.plane_scatter, grad_out * line)
        if ctx.needs_input_grad[1]:
            grad_line = _sparse_times(corners.line_scatter, grad_out * plane)
        if ctx.needs_input_grad[2]:
            plane_table, line_table = ctx.saved_tensors[2:]
            grad_coords = _coordinate_gradient(grad_out, plane, line, plane_table, line_table, corners)
        return grad_plane, grad_line, grad_coords, None


def _coordinate_gradient(
    grad_out: Float[Tensor, "n3 c"],
    plane: Float[Tensor, "n3 c"],
    line: Float[Tensor, "n3 c"],
    plane_table: Float[Tensor, "plane_rows c"],
    line_table: Float[Tensor, "line_rows c"],
    corners: "VMCorners",
) -> Float[Tensor, "n 3"]:
    """d(loss)/d(coords) of `plane * line`: the bilinear (linear) weights' derivatives in each plane's (line's) cell
    fractions, times d(fraction)/d(coordinate) = (resolution - 1) / 2 along each axis (a sample's cell is fixed)."""
    rows = corners.rows
    n = corners.num_points
    fw = rows.plane_weight[:, 1] + rows.plane_weight[:, 3]  # the fractions: the weights of the corners at w + 1
    fh = rows.plane_weight[:, 2] + rows.plane_weight[:, 3]  # and at h + 1
    one = torch.ones_like(fw)
    d_w = torch.stack((fh - one, one - fh, -fh, fh), dim=-1)  # d(weights)/d(fw)
    d_h = torch.stack((fw - one, -fw, one - fw, fw), dim=-1)  # d(weights)/d(fh)
    g_plane = grad_out * line  # [n3, c]
    g_line = grad_out * plane
    dp_w = F.embedding_bag(rows.plane_index, plane_table, per_sample_weights=d_w, mode="sum")
    dp_h = F.embedding_bag(rows.plane_index, plane_table, per_sample_weights=d_h, mode="sum")
    d_l = torch.stack((-one, one), dim=-1)
    dl = F.embedding_bag(rows.line_index, line_table, per_sample_weights=d_l, mode="sum")
    per_w = (g_plane * dp_w).sum(-1).view(n, 3)  # [point, plane]
    per_h = (g_plane * dp_h).sum(-1).view(n, 3)
    per_l = (g_line * dl).sum(-1).view(n, 3)
    grad = per_w.new_zeros(n, 3)
    for p in range(3):
        grad[:, PLANE_AXES_W[p]] += per_w[:, p]
        grad[:, PLANE_AXES_H[p]] += per_h[:, p]
        grad[:, LINE_AXES[p]] += per_l[:, p]
    scale = torch.tensor([(r - 1) / 2.0 for r in corners.resolution], dtype=grad.dtype, device=grad.device)
    return grad * scale


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
    """Plane feature times line feature at every (point, plane) row of `corners` (differentiable in the tables, and in
    the points where `corners.source` holds them with a graph)."""
    return _VMProduct.apply(plane_table, line_table, corners.source, corners)


VMLookup = Literal["auto", "rows", "grid_sample"]
"""How a VM volume is sampled: "rows" (weighted row sums, fastest on a CPU), "grid_sample" (Nerfstudio's lookup),
"auto" (rows on a CPU, grid_sample elsewhere)."""

AxisSource = Tensor
"""Float [r]: for each of the r grid points along one axis of a resampled volume, the coordinate in [-1, 1] of the old
volume it takes its value from (`VMVolume.resample`; each axis has its own r)."""


class VMVolume(nn.Module):
    """A TensoRF VM volume (three planes, three lines) with one resolution per axis (see the module docstring).

    Args:
        resolution: grid points per axis (x, y, z), or one int for a cube.
        num_components: components per plane and line.
        init_scale: scale of the random initialisation (normal, as Nerfstudio's `TensorVMEncoding`).
        lookup: see `VMLookup`.
    """

    res: Int[Tensor, "3"]
    """The resolution, a buffer, so that a checkpoint restores the tables' shapes before their values."""

    def __init__(
        self,
        resolution: Union[int, Sequence[int]] = 128,
        num_components: int = 24,
        init_scale: float = 0.1,
        lookup: VMLookup = "auto",
    ) -> None:
        super().__init__()
        if lookup not in ("auto", "rows", "grid_sample"):
            raise ValueError(f"Unknown VM lookup {lookup!r}; expected 'auto', 'rows' or 'grid_sample'")
        res = as_resolution(resolution)
        self.num_components = int(num_components)
        self.lookup = lookup
        self.register_buffer("res", torch.tensor(res, dtype=torch.int64))
        # `res` as Python numbers, kept with the buffer: every lookup reads it, and a read of the buffer on a GPU waits
        # for the device; it changes only when the volume is resampled or a checkpoint loads
        self._resolution: Resolution = res
        comps = self.num_components
        layout = VMLayout.of(res)
        if len(set(res)) == 1:  # a cube: Nerfstudio's draws, `randn(3, C, R, R)` then `randn(3, C, R, 1)`
            planes = list(init_scale * torch.randn(3, comps, res[0], res[0]))
            lines = list(init_scale * torch.randn(3, comps, res[0], 1))
        else:
            planes = [init_scale * torch.randn(comps, h, w) for h, w in layout.plane_shapes]
            lines = [init_scale * torch.randn(comps, res[a], 1) for a in LINE_AXES]
        self.plane_table = nn.Parameter(torch.cat([p.permute(1, 2, 0).reshape(-1, comps) for p in planes]))
        self.line_table = nn.Parameter(torch.cat([q.permute(1, 2, 0).reshape(-1, comps) for q in lines]))
        self._register_load_state_dict_pre_hook(self._load_legacy_layout)

    # ---------------------------------------------------------------- layout
    @property
    def resolution(self) -> Resolution:
        """Grid points along x, y and z."""
        return self._resolution

    @property
    def layout(self) -> VMLayout:
        return VMLayout.of(self.resolution)

    def get_out_dim(self) -> int:
        return 3 * self.num_components

    def planes(self, table: Optional[Tensor] = None) -> List[Float[Tensor, "h w c"]]:
        """Views of the three planes (height, width, components) of `table` (default: this volume's plane table)."""
        return plane_views(self.plane_table if table is None else table, self.layout)

    def lines(self) -> List[Float[Tensor, "r c"]]:
        """Views of the three lines (length, components)."""
        offs = self.layout.line_offsets
        return [self.line_table[offs[p] : offs[p + 1]] for p in range(3)]

    def uses_rows(self) -> bool:
        """Whether lookups gather rows (else `grid_sample`)."""
        return self.lookup == "rows" or (self.lookup == "auto" and self.plane_table.device.type == "cpu")

    # ---------------------------------------------------------------- lookup
    def features(self, corners: VMCorners) -> Float[Tensor, "n out_dim"]:
        """Features (`3 * num_components`, Nerfstudio's order: plane-major) at precomputed corners."""
        if corners.resolution != self.resolution:
            raise ValueError(f"Corners for resolution {corners.resolution} used on a volume of {self.resolution}")
        if not self.uses_rows():
            return self._grid_sample_features(corners.coords if corners.source is None else corners.source)
        return vm_product(self.plane_table, self.line_table, corners).view(corners.num_points, self.get_out_dim())

    def _grid_sample_features(self, coords: Float[Tensor, "n 3"]) -> Float[Tensor, "n out_dim"]:
        """The same features by `F.grid_sample`, one plane and line at a time (the GPU path)."""
        feats = []
        for p, (plane, line) in enumerate(zip(self.planes(), self.lines(), strict=True)):
            uv = coords[:, [PLANE_AXES_W[p], PLANE_AXES_H[p]]].view(1, -1, 1, 2)
            plane_f = F.grid_sample(plane.permute(2, 0, 1)[None], uv, align_corners=True)[0, :, :, 0]  # [C, n]
            lc = coords[:, LINE_AXES[p]]
            lv = torch.stack([torch.zeros_like(lc), lc], dim=-1).view(1, -1, 1, 2)
            line_f = F.grid_sample(line.T[None, :, :, None], lv, align_corners=True)[0, :, :, 0]  # [C, n]
            feats.append((plane_f * line_f).T)
        return torch.cat(feats, dim=-1)

    def forward(self, in_tensor: Float[Tensor, "*bs 3"]) -> Float[Tensor, "*bs out_dim"]:
        """Features at positions in [-1, 1] (clamped there)."""
        flat = in_tensor.reshape(-1, 3)
        out = self.features(vm_corners(flat, self.resolution))
        return out.reshape(*in_tensor.shape[:-1], out.shape[-1])

    # ------------------------------------------------------------ resampling
    @torch.no_grad()
    def resample(self, resolution: Union[int, Sequence[int]], sources: Optional[Sequence[AxisSource]] = None) -> None:
        """Replace the tables (new Parameters) by the volume resampled bilinearly at `resolution`.

        `sources`: per axis, where in the old volume's coordinates each new grid point takes its value (an axis-wise
        change of the grid's mapping, e.g. a refitted scene box); default: the same coordinates, a plain up- or
        downsampling (Nerfstudio's `upsample_grid` for a cube). Exact for the VM product at the grid points: every plane
        and line depends on its own axes only.
        """
        res = as_resolution(resolution)
        device, dtype = self.plane_table.device, self.plane_table.dtype
        if sources is None:
            sources = [torch.linspace(-1.0, 1.0, r, device=device, dtype=dtype) for r in res]
        if [int(s.shape[0]) for s in sources] != list(res):
            raise ValueError(f"resample: sources of lengths {[s.shape[0] for s in sources]} for resolution {res}")
        src = [s.to(device=device, dtype=dtype).clamp(-1.0, 1.0) for s in sources]
        planes = []
        for p, plane in enumerate(self.planes()):
            sw, sh = src[PLANE_AXES_W[p]], src[PLANE_AXES_H[p]]
            grid = torch.stack(torch.broadcast_tensors(sw[None, :], sh[:, None]), dim=-1)[None]  # [1, H, W, 2]
            new = F.grid_sample(plane.permute(2, 0, 1)[None], grid, mode="bilinear", align_corners=True)[0]
            planes.append(new.permute(1, 2, 0).reshape(-1, self.num_components))
        lines = []
        for p, line in enumerate(self.lines()):
            sl = src[LINE_AXES[p]]
            grid = torch.stack([torch.zeros_like(sl), sl], dim=-1).view(1, -1, 1, 2)
            new = F.grid_sample(line.T[None, :, :, None], grid, mode="bilinear", align_corners=True)[0, :, :, 0]
            lines.append(new.T)
        self.plane_table = nn.Parameter(torch.cat(planes).contiguous())
        self.line_table = nn.Parameter(torch.cat(lines).contiguous())
        self.res.copy_(torch.tensor(res, dtype=torch.int64, device=self.res.device))
        self._resolution = res

    def upsample_grid(self, resolution: Union[int, Sequence[int]]) -> None:
        """Resample to `resolution` over the same coordinates (Nerfstudio's `upsample_grid`)."""
        self.resample(resolution)

    # ------------------------------------------------------------ checkpoints
    def _load_legacy_layout(self, state_dict: Dict[str, Any], prefix: str, *args: Any) -> None:
        """Before a checkpoint loads: give the tables the checkpoint's shapes (its `res`), and convert the cube layout
        of Nerfstudio's `TensorVMEncoding` (`plane_coef` [3, C, R, R], `line_coef` [3, C, R, 1]) to tables."""
        del args
        plane_coef = state_dict.pop(prefix + "plane_coef", None)
        line_coef = state_dict.pop(prefix + "line_coef", None)
        if plane_coef is not None and line_coef is not None:
            comps, r = plane_coef.shape[1], plane_coef.shape[-1]
            state_dict[prefix + "plane_table"] = plane_coef.permute(0, 2, 3, 1).reshape(-1, comps)
            state_dict[prefix + "line_table"] = line_coef.permute(0, 2, 3, 1).reshape(-1, comps)
            state_dict.setdefault(prefix + "res", torch.tensor([r, r, r], dtype=torch.int64, device=plane_coef.device))
        saved_res = state_dict.get(prefix + "res")
        if saved_res is None:
            return
        res = as_resolution([int(v) for v in saved_res.tolist()])
        if res != self.resolution:
            layout = VMLayout.of(res)
            device, dtype = self.plane_table.device, self.plane_table.dtype
            comps = self.num_components
            self.plane_table = nn.Parameter(torch.empty(layout.plane_offsets[-1], comps, device=device, dtype=dtype))
            self.line_table = nn.Parameter(torch.empty(layout.line_offsets[-1], comps, device=device, dtype=dtype))
            self.res.copy_(torch.tensor(res, dtype=torch.int64, device=self.res.device))
            self._resolution = res


def plane_views(table: Float[Tensor, "rows c"], layout: VMLayout) -> List[Float[Tensor, "h w c"]]:
    """The (height, width, components) views of the planes in a plane table."""
    return [
        table[layout.plane_offsets[p] : layout.plane_offsets[p + 1]].view(h, w, -1)
        for p, (h, w) in enumerate(layout.plane_shapes)
    ]
