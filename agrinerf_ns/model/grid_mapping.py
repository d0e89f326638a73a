"""Where the field's grids are at full resolution: a box fitted to the scene, contracted per axis outside it.

`BoxContraction` maps world points to grid coordinates in [-1, 1]. Inside the box (|u|_inf <= 1, u = (x - centre) /
half) the map is linear, `c = inner * u`, so the box spans the fraction `inner` of the grid along every axis; outside
it each axis is contracted on its own, `c = sign(u) (inner + (1 - inner)(1 - 1/|u|))`, so sky and far trees still land
in the grid (mip-NeRF 360's contraction, per axis rather than with a norm). Because every axis is mapped on its own, a
VM volume (planes and lines of the axes) can be resampled exactly into a new box (`VMVolume.resample`).

`fit_box` chooses the box from where the scene is: the surface points of rendered rays (each ray's median depth) or
SfM points, without the far background (sky, hedges: beyond `depth_cut` times the median depth), as the smallest box
found that holds a share of their weight (`smallest_box`; TensoRF refits its grid to the occupied box the same way:
`updateAlphaMask` + `shrink`).
"""

from __future__ import annotations

from typing import Any, Callable, Dict, Optional, Sequence, Tuple

import torch
from jaxtyping import Bool, Float
from torch import Tensor, nn

START_INNER = 0.5
"""Grid fraction of the first box (the scene box around the cameras, before any fit): the share of today's
L-inf contraction, so that the far scene has a usable resolution until the box is fitted."""


MAX_FIT_POINTS = 16384
"""Points a box fit looks at (more are thinned by a stride): a fit renders 8192 rays; SfM models hold millions."""


class BoxContraction(nn.Module):
    """World -> grid coordinates: a box at full resolution, each axis contracted on its own outside it.

    Args:
        box: (2, 3) world lo / hi corners of the box.
        inner: fraction of the grid (per axis) the box spans.
    """

    centre: Float[Tensor, "3"]
    radius: Float[Tensor, "3"]
    inner: Float[Tensor, ""]

    def __init__(self, box: Float[Tensor, "2 3"], inner: float = START_INNER) -> None:
        super().__init__()
        self.register_buffer("centre", torch.zeros(3))
        self.register_buffer("radius", torch.ones(3))
        self.register_buffer("inner", torch.tensor(float(inner)))
        # `inner` as a Python number (the buffer's float32 value), kept with it: every map reads it, and a read of the
        # buffer on a GPU waits for the device; it changes only when the box is set or a checkpoint loads
        self.inner_value = float(self.inner)
        self._resolutions: Dict[int, Tuple[int, int, int]] = {}  # `axis_resolution` per cube, until the box changes
        self._register_load_state_dict_pre_hook(self._load_inner)
        self.set_box(box, inner)

    def _load_inner(self, state_dict: Dict[str, Any], prefix: str, *args: Any) -> None:
        saved = state_dict.get(prefix + "inner")
        if saved is not None:
            self.inner_value = float(saved.to(self.inner.dtype))  # the buffer's value once it has loaded
        self._resolutions = {}

    def axis_resolution(self, cube: int) -> Tuple[int, int, int]:
        """`axis_resolution` of the box for a `cube`^3 budget, computed once per box (its extents are read back)."""
        if cube not in self._resolutions:
            self._resolutions[cube] = axis_resolution(self.box(), self.inner_value, cube)
        return self._resolutions[cube]

    @torch.no_grad()
    def set_box(self, box: Float[Tensor, "2 3"], inner: float) -> None:
        box = box.detach().to(self.centre)
        if not (0.0 < inner < 1.0) or not bool(torch.isfinite(box).all()) or not bool((box[1] > box[0]).all()):
            raise ValueError(f"A grid box needs finite corners lo < hi and 0 < inner < 1, got {box.tolist()}, {inner}")
        self.centre.copy_((box[0] + box[1]) / 2)
        self.radius.copy_((box[1] - box[0]) / 2)
        self.inner.fill_(float(inner))
        self.inner_value = float(self.inner)
        self._resolutions = {}

    def box(self) -> Float[Tensor, "2 3"]:
        """World lo / hi corners of the full-resolution box."""
        return torch.stack([self.centre - self.radius, self.centre + self.radius])

    def unit(self, positions: Float[Tensor, "*bs 3"]) -> Float[Tensor, "*bs 3"]:
        """Positions in box units: the box is [-1, 1]^3."""
        return (positions - self.centre) / self.radius

    def forward(self, positions: Float[Tensor, "*bs 3"]) -> Float[Tensor, "*bs 3"]:
        """Grid coordinates in [-1, 1] (+-1 only at infinity)."""
        return contract_axes(self.unit(positions), self.inner_value)

    def inverse(self, coords: Float[Tensor, "*bs 3"]) -> Float[Tensor, "*bs 3"]:
        """World positions of grid coordinates in (-1, 1) (+-1 maps to a large finite distance)."""
        return uncontract_axes(coords, self.inner_value) * self.radius + self.centre

    def full_resolution(self, positions: Float[Tensor, "*bs 3"]) -> Bool[Tensor, "*bs"]:
        """Whether each position lies in the box, where the grid has its full resolution."""
        return self.unit(positions).abs().amax(dim=-1) <= 1.0

    def voxel_size(self, positions: Float[Tensor, "*bs 3"], resolution: Sequence[int]) -> Float[Tensor, "*bs 3"]:
        """World size of a grid cell along each axis at `positions`, for a volume of `resolution` grid points."""
        u = self.unit(positions).abs()
        a = self.inner_value
        slope = torch.where(u <= 1.0, torch.full_like(u, a), (1.0 - a) / u.clamp(min=1.0).pow(2))  # dc/du
        cell = 2.0 / (torch.tensor(resolution, dtype=u.dtype, device=u.device) - 1.0)
        return cell / slope * self.radius


def contract_axes(u: Float[Tensor, "*bs 3"], inner: float) -> Float[Tensor, "*bs 3"]:
    """`inner * u` inside [-1, 1], `sign(u) (inner + (1 - inner)(1 - 1/|u|))` outside, per axis."""
    mag = u.abs()
    outer = inner + (1.0 - inner) * (1.0 - 1.0 / mag.clamp(min=1.0))
    return torch.where(mag <= 1.0, inner * u, torch.sign(u) * outer)


def uncontract_axes(c: Float[Tensor, "*bs 3"], inner: float, limit: float = 1.0e6) -> Float[Tensor, "*bs 3"]:
    """The inverse of `contract_axes`; |c| >= 1 (infinity) gives +-`limit`."""
    mag = c.abs()
    outer = (1.0 - inner) / (1.0 - mag).clamp(min=(1.0 - inner) / limit)
    return torch.where(mag <= inner, c / inner, torch.sign(c) * outer)


def axis_resolution(box: Float[Tensor, "2 3"], inner: float, cube: int, minimum: int = 4) -> Tuple[int, int, int]:
    """Grid points per axis with the voxel budget of a `cube`^3 grid and cells of one size in the box.

    The box spans `inner` of every axis, so its cells have side `extent_i / (inner * res_i)`: equal sides for
    res_i proportional to extent_i, with prod(res_i) = cube^3 (TensoRF's `N_to_reso` for a bounding box)."""
    extent = (box[1] - box[0]).double().clamp(min=1e-9)
    scale = float(extent.log().mean().exp())
    res = [max(minimum, int(round(cube * float(e) / scale))) for e in extent]
    return res[0], res[1], res[2]


def box_voxel(box: Float[Tensor, "2 3"], inner: float, cube: int) -> float:
    """Largest side (world units) of a grid cell inside `box` at the per-axis resolution of a `cube`^3 budget, as
    `BoxContraction.voxel_size` gives it there."""
    res = torch.tensor(axis_resolution(box, inner, cube), dtype=torch.float64, device=box.device)
    return float(((box[1] - box[0]).double() / (inner * (res - 1.0))).max())


def _weighted_quantile(values: Float[Tensor, " n"], weights: Float[Tensor, " n"], q: Float[Tensor, " k"]) -> Tensor:
    order = torch.argsort(values)
    cdf = torch.cumsum(weights[order].double(), 0)
    cdf = cdf / cdf[-1].clamp(min=1e-30)
    idx = torch.searchsorted(cdf, q.double().to(cdf.device)).clamp(max=values.shape[0] - 1)
    return values[order][idx]


def fit_box(
    points: Float[Tensor, "n 3"],
    weights: Optional[Float[Tensor, " n"]] = None,
    origins: Optional[Float[Tensor, "n 3"]] = None,
    depth_cut: float = 2.5,
    share: float = 0.95,
    margin: float = 0.05,
    small_enough: Optional[Callable[[Tensor], bool]] = None,
) -> Optional[Float[Tensor, "2 3"]]:
    """The box (lo, hi) that holds the scene's surface points, or None when too few are finite.

    Args:
        points: surface points (rendered median-depth points, SfM points).
        weights: how much each point counts (e.g. the ray's accumulation); default 1.
        origins: the camera centre each point was seen from: points farther than `depth_cut` times the weighted median
            distance are far background (sky, hedges, the next rows) and left out.
        depth_cut: see `origins`.
        share: the box is the smallest (by volume) that `smallest_box` finds holding this share of the remaining
            weight: the rest is what costs the most volume per unit of weight (stray points, the ends of a row).
        margin: each side moves out by this fraction of the box's extent along its axis (an axis under 5% of the
            largest counts as 5% of it, so a flat scene keeps some depth).
        small_enough: whether a (padded) box is small enough (its voxels fine enough): the fit then stops shrinking
            it, holding more than `share` where it can.

    More than `MAX_FIT_POINTS` points (a large SfM model) are thinned to that many by a fixed stride first.
    """
    weights = torch.ones(points.shape[0], device=points.device) if weights is None else weights
    keep = torch.isfinite(points).all(dim=-1) & torch.isfinite(weights) & (weights > 0)
    if origins is not None:
        dist = (points - origins).norm(dim=-1)
        keep &= torch.isfinite(dist)
        if int(keep.sum()) >= 8:
            median = _weighted_quantile(dist[keep], weights[keep], torch.tensor([0.5], device=dist.device))[0]
            keep &= dist <= depth_cut * median
    if int(keep.sum()) < 8:
        return None
    points, weights = points[keep], weights[keep]
    if points.shape[0] > MAX_FIT_POINTS:
        stride = -(-points.shape[0] // MAX_FIT_POINTS)
        points, weights = points[::stride], weights[::stride]

    def padded(bounds: Tensor) -> Tensor:
        extent = bounds[1] - bounds[0]
        pad = margin * torch.maximum(extent, 0.05 * extent.max()).clamp(min=1e-6)
        return torch.stack([bounds[0] - pad, bounds[1] + pad])

    done = None if small_enough is None else (lambda bounds: small_enough(padded(bounds)))
    box = padded(smallest_box(points.double(), weights.double(), share, done)).float()
    if not bool(torch.isfinite(box).all()):
        return None
    return box


def smallest_box(
    points: Float[Tensor, "n 3"],
    weights: Float[Tensor, " n"],
    share: float,
    done: Optional[Callable[[Tensor], bool]] = None,
    steps: int = 40,
) -> Float[Tensor, "2 3"]:
    """A small axis-aligned box holding at least `share` of the points' weight (tight lo / hi corners); with `done`,
    the first box on the way there for which `done(box)` holds.

    Greedy face peeling: from the points' bounding box, move in one of the six faces at a time past a slice of
    (1 - share) / `steps` of the weight (at least one point), always the face whose move shrinks the box's volume the
    most per unit of weight it leaves out, until the next move would leave out more than 1 - `share`. Stray points,
    the next row and the far ends of a long scene go first; a compact scene loses its least-seen edges. The voxel size
    of a grid of fixed budget over the box goes with its volume's cube root (`axis_resolution`), so this trades weight
    for voxel size directly. At most about `steps` moves (each leaves out at least a slice) of O(n log n) each.
    """
    total = float(weights.sum())
    chunk = (1.0 - share) * total / steps
    inside = torch.ones(points.shape[0], dtype=torch.bool, device=points.device)

    def bounds(mask: Tensor) -> Tensor:
        return torch.stack([points[mask].amin(dim=0), points[mask].amax(dim=0)])

    box = bounds(inside)
    while done is None or not done(box):
        w = weights[inside]
        kept = float(w.sum())
        scale = float((box[1] - box[0]).max().clamp(min=1e-12))
        before = (box[1] - box[0]).clamp(min=1e-9 * scale).log().sum()
        q = torch.tensor([chunk / kept, 1.0 - chunk / kept], device=points.device)
        best: Optional[Tuple[float, Tensor]] = None
        for axis in range(3):
            faces = _weighted_quantile(points[inside, axis], w, q)  # the low and the high face's next position
            for side in (0, 1):
                face = faces[side]
                cut = points[:, axis] > face if side == 0 else points[:, axis] < face  # at least one point goes
                candidate = inside & cut
                lost = kept - float(weights[candidate].sum())
                if lost <= 0.0 or kept - lost < share * total or int(candidate.sum()) < 8:
                    continue
                new_box = bounds(candidate)
                after = (new_box[1] - new_box[0]).clamp(min=1e-9 * scale).log().sum()
                score = float(before - after) / (lost / kept)
                if best is None or score > best[0]:
                    best = (score, candidate)
        if best is None:
            return box
        inside = best[1]
        box = bounds(inside)
    return box
