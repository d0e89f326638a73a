"""The trained field sampled on a world-space voxel grid: density, what the training cameras see, and the outputs
fruit are told apart by (temperature, the thermal camera's channel, the cross-spectral ``thermal``, RGB).

The grid spans the scene's occupied box (:func:`occupied_box`) in Nerfstudio's frame, at a voxel size in dataset units
(metres for metric poses). A voxel is *dense* when the field's density there reaches ``density_threshold`` and *seen*
when it lies no farther than a fruit radius behind the rendered depth of at least one training view (the views are
rendered at a reduced resolution, their depth max-pooled over 3x3 pixels, so a voxel behind a thin leaf rim still
counts as seen): the heads are trained only where some camera looks, so outputs elsewhere (inside the canopy, behind
the rows) are not read.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, List, Optional, Sequence, Tuple

import numpy as np
from jaxtyping import Bool, Float, Int

from agrinerf_ns.count.render import CountInputError, WorldFrame
from agrinerf_ns.count.source_table import sample_temperature, source_row
from agrinerf_ns.fruit.view import MIN_ACCUMULATION

CHUNK = 1 << 18
"""Points per field evaluation."""


@dataclass(frozen=True)
class VolumeConfig:
    """How the field is sampled."""

    voxel_size: float = 0.01
    """Grid spacing in dataset units (metres with metric poses); coarsened when the box would hold more than
    ``max_voxels``."""
    max_voxels: int = 16_000_000
    """Most voxels in the grid (memory: about 20 bytes each while sampling)."""
    density_threshold: float = 5.0
    """A voxel is dense from this density (per Nerfstudio unit: the opacity of one dataset centimetre is then about
    1 - exp(-threshold * scale / 100))."""
    view_scale: float = 0.5
    """Resolution of the training views rendered for the visibility test and the box (fraction of the dataset's)."""
    max_views: int = 64
    """Training views rendered for the visibility test, evenly spaced."""
    box_percentile: float = 1.0
    """The occupied box spans these percentiles (and 100 minus them) of the rendered surface points per axis."""
    box_max_depth: float = 3.0
    """Surface points farther than this many times the median rendered depth (far hedge, sky shell) are outside the
    box."""


@dataclass
class DepthView:
    """A training camera with its rendered depth (distance along unit rays) at reduced resolution, Nerfstudio frame."""

    c2w: Float[np.ndarray, "3 4"]
    """Camera-to-world, Nerfstudio's OpenGL axes (x right, y up, looking down -z)."""
    fx: float
    fy: float
    cx: float
    cy: float
    depth: Float[np.ndarray, "h w"]
    """Depth along each pixel's unit ray; +inf where nothing was rendered (accumulation below 0.5)."""
    surface: Float[np.ndarray, "n 3"]
    """The rendered surface points (accumulation >= 0.5)."""
    pixel_area: float = 1.0
    """Pixels of the dataset's images per pixel of this view (1 / view_scale^2)."""

    @property
    def centre(self) -> Float[np.ndarray, "3"]:
        return self.c2w[:, 3]


def render_depth_views(model: Any, cameras: Any, config: VolumeConfig) -> List[DepthView]:
    """Render ``cameras`` (Nerfstudio ``Cameras``, the run's training cameras) at ``config.view_scale`` of their
    resolution with ``model``; returns their depth views (evenly spaced, at most ``config.max_views``)."""
    from agrinerf_ns.progress import work_progress

    count = len(cameras)
    indices = np.unique(np.linspace(0, count - 1, min(count, config.max_views)).round().astype(int))
    views = []
    with work_progress(f"rendering {len(indices)} depth views", len(indices)) as progress:
        for index in indices:
            views.append(render_depth_view(model, cameras[int(index) : int(index) + 1], config))
            progress.advance()
    return views


def render_depth_view(model: Any, camera: Any, config: VolumeConfig) -> DepthView:
    """The depth view of one camera (``Cameras`` of length 1) at ``config.view_scale`` of its resolution."""
    import torch

    camera = camera.to(model.device)
    camera.rescale_output_resolution(config.view_scale)
    with torch.no_grad():
        rays = camera.generate_rays(camera_indices=0, keep_shape=True)
        outputs = model.get_outputs_for_camera(camera)
    if "depth" not in outputs:
        raise CountInputError(f"the run's model renders no 'depth' (outputs: {', '.join(sorted(outputs))})")
    depth = outputs["depth"][..., 0].float().cpu().numpy().astype(np.float64)
    acc = outputs["accumulation"][..., 0].float().cpu().numpy() if "accumulation" in outputs else np.ones_like(depth)
    origins = rays.origins.float().cpu().numpy().astype(np.float64)
    directions = rays.directions.float().cpu().numpy().astype(np.float64)
    solid = (acc >= MIN_ACCUMULATION) & np.isfinite(depth)
    surface = (origins + directions * depth[..., None])[solid]
    return DepthView(
        c2w=camera.camera_to_worlds[0].float().cpu().numpy().astype(np.float64),
        fx=float(camera.fx[0, 0]),
        fy=float(camera.fy[0, 0]),
        cx=float(camera.cx[0, 0]),
        cy=float(camera.cy[0, 0]),
        depth=np.where(solid, depth, np.inf),
        surface=surface,
        pixel_area=1.0 / config.view_scale**2,
    )


def occupied_box(
    views: Sequence[DepthView], config: VolumeConfig, pad: float, field: Any = None
) -> Float[np.ndarray, "2 3"]:
    """The scene's occupied box (Nerfstudio frame): per-axis percentiles of the views' rendered surface points within
    ``box_max_depth`` x their median distance from their camera, padded by ``pad`` (Nerfstudio units), and within
    the field's full-resolution box (``AgriNeRFField.full_resolution_box``, fitted to the scene) where it has one."""
    parts, distances = [], []
    for view in views:
        parts.append(view.surface)
        distances.append(np.linalg.norm(view.surface - view.centre, axis=1))
    points = np.concatenate(parts) if parts else np.zeros((0, 3))
    if len(points) < 8:
        raise CountInputError("the run renders no surface in its training views (accumulation < 0.5 everywhere)")
    distance = np.concatenate(distances)
    near = points[distance <= config.box_max_depth * float(np.median(distance))]
    low = np.percentile(near, config.box_percentile, axis=0) - pad
    high = np.percentile(near, 100.0 - config.box_percentile, axis=0) + pad
    if field is not None and hasattr(field, "full_resolution_box"):
        fitted = field.full_resolution_box().detach().float().cpu().numpy().astype(np.float64)
        inner_low, inner_high = np.maximum(low, fitted[0]), np.minimum(high, fitted[1])
        if np.all(inner_high > inner_low):  # else the fit missed what the views render: keep theirs
            low, high = inner_low, inner_high
    return np.stack([low, high])


@dataclass
class VoxelGrid:
    """An axis-aligned grid of the Nerfstudio frame: voxel ``(i, j, k)`` has its centre at ``origin + (i, j, k) *
    step``."""

    origin: Float[np.ndarray, "3"]
    step: float
    """Voxel size in Nerfstudio units."""
    shape: Tuple[int, int, int]

    @classmethod
    def over(cls, box: Float[np.ndarray, "2 3"], step: float, max_voxels: int) -> "VoxelGrid":
        """The grid over ``box`` at ``step`` (enlarged until it holds at most ``max_voxels``)."""
        extent = np.maximum(box[1] - box[0], 0.0)
        step = max(float(step), float(np.cbrt(np.prod(extent) / max(max_voxels, 1))))
        shape = tuple(int(n) for n in np.maximum(np.ceil(extent / step), 1).astype(int))
        while int(np.prod(shape)) > max_voxels:
            step *= 1.05
            shape = tuple(int(n) for n in np.maximum(np.ceil(extent / step), 1).astype(int))
        return cls(np.asarray(box[0], np.float64) + step / 2, step, (shape[0], shape[1], shape[2]))

    def centres(self, flat: np.ndarray) -> Float[np.ndarray, "n 3"]:
        """Centres of the voxels with these flat indices."""
        ijk = np.stack(np.unravel_index(flat, self.shape), axis=-1)
        return self.origin + ijk * self.step


def field_density(field: Any, points: Float[np.ndarray, "n 3"], device: Any = "cpu") -> Float[np.ndarray, " n"]:
    """The field's density at Nerfstudio-frame ``points`` (``to_grid`` then ``density_at``), in chunks."""
    import torch

    out = np.empty(len(points), np.float32)
    with torch.no_grad():
        for start in range(0, len(points), CHUNK):
            part = torch.as_tensor(points[start : start + CHUNK], dtype=torch.float32, device=device)
            coords, inside = field.to_grid(part)
            out[start : start + CHUNK] = field.density_at(coords, inside)[..., 0].float().cpu().numpy()
    return out


def dense_voxels(field: Any, grid: VoxelGrid, threshold: float, device: Any = "cpu") -> np.ndarray:
    """Flat indices of the voxels whose density reaches ``threshold`` (the grid is swept in slabs of ``CHUNK``
    points)."""
    from agrinerf_ns.progress import work_progress

    total = int(np.prod(grid.shape))
    keep = []
    with work_progress(f"sampling the field's density on {total} voxels", -(-total // CHUNK)) as progress:
        for start in range(0, total, CHUNK):
            flat = np.arange(start, min(start + CHUNK, total))
            density = field_density(field, grid.centres(flat), device)
            keep.append(flat[density >= threshold])
            progress.advance()
    return np.concatenate(keep) if keep else np.zeros(0, np.int64)


def seen_pixels(
    points: Float[np.ndarray, "n 3"], view: DepthView, margin: float
) -> Tuple[Bool[np.ndarray, " n"], Int[np.ndarray, " n"]]:
    """Whether ``view`` sees each point (it projects into the image, in front of the camera, and no farther than
    ``margin``, Nerfstudio units, behind the largest rendered depth of the 3x3 pixels around it), and its pixel's flat
    index."""
    from scipy.ndimage import maximum_filter

    rot, centre = view.c2w[:, :3], view.centre
    local = (points - centre) @ rot  # camera axes: x right, y up, -z forward
    forward = -local[:, 2]
    ahead = forward > 1e-6
    u = view.cx + view.fx * local[:, 0] / np.where(ahead, forward, 1.0)
    v = view.cy - view.fy * local[:, 1] / np.where(ahead, forward, 1.0)
    h, w = view.depth.shape
    inside = ahead & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    depth = maximum_filter(np.where(np.isfinite(view.depth), view.depth, 1e9), size=3, mode="nearest")
    iu = np.clip(u.astype(np.int64), 0, w - 1)
    iv = np.clip(v.astype(np.int64), 0, h - 1)
    distance = np.linalg.norm(points - centre, axis=1)
    return inside & (distance <= depth[iv, iu] + margin), iv * w + iu


def views_seeing(points: Float[np.ndarray, "n 3"], views: Sequence[DepthView], margin: float) -> Int[np.ndarray, " n"]:
    """How many ``views`` see each point (:func:`seen_pixels`)."""
    counts = np.zeros(len(points), np.int32)
    for view in views:
        counts += seen_pixels(points, view, margin)[0]
    return counts


MIN_ON_OBJECT_SHARE = 0.5
"""A view shows an object when its rays stop on the object (:func:`pixels_on_object`) in at least this share of the
pixels the object's seen points cover: most of it is in sight, not a rim beside an occluder."""


MIN_BODY_WEIGHT = 0.5
"""A view sees a body when its ray through the body's centre puts at least this rendering weight within the body
(:func:`body_weights`): the body stops at least half of the ray, as a fruit in sight does."""


def views_showing_pixels(
    points: Float[np.ndarray, "n 3"],
    views: Sequence[DepthView],
    margin: float,
    min_pixels: float,
    field: Any = None,
    device: Any = "cpu",
) -> int:
    """In how many ``views`` the seen ``points`` (one object's voxels) cover at least ``min_pixels`` pixels of the
    dataset's images (distinct pixels of the view times its ``pixel_area``; one pixel of a coarser view counts
    its area at most once) on which the view renders the object itself (:func:`pixels_on_object`), when those are at
    least :data:`MIN_ON_OBJECT_SHARE` of the pixels its seen points cover; with the ``field``, only views whose ray
    through the object's centre puts :data:`MIN_BODY_WEIGHT` of its weight on it (:func:`body_weights`)."""
    showing = []
    for view in views:
        seen, pixel = seen_pixels(points, view, margin)
        if not seen.any():
            continue
        covered = len(np.unique(pixel[seen]))
        on = len(pixels_on_object(points[seen], pixel[seen], view, margin))
        if on * view.pixel_area >= min_pixels and on >= MIN_ON_OBJECT_SHARE * covered:
            showing.append(view)
    if field is None or not showing:
        return len(showing)
    variance = float(np.linalg.eigvalsh(np.atleast_2d(np.cov(points.T))).max()) if len(points) > 1 else 0.0
    radius = max(float(np.sqrt(5.0 * variance)), margin)  # a solid ball's radius from its variance, as components
    weights = body_weights(field, showing, points.mean(0), radius, device)
    return int(np.count_nonzero(weights >= MIN_BODY_WEIGHT))


BODY_SAMPLES_PER_RADIUS = 4
"""Density samples per body radius along a ray marched by :func:`body_weights`."""


def body_weights(
    field: Any, views: Sequence[DepthView], centre: Float[np.ndarray, "3"], radius: float, device: Any = "cpu"
) -> Float[np.ndarray, " v"]:
    """For each view, the rendering weight its ray through ``centre`` (Nerfstudio frame) puts within ``radius`` of it
    (0 to 1): the field's density marched from the camera (transmittance to the body times its opacity).

    Near 1 for a dense body in sight; low for one hidden behind leaves or the canopy's edge (the ray stopped before
    it: the sky painted on fog behind the canopy's top, in the dark demo) and for a translucent floater (the ray
    passes through it)."""
    step = radius / BODY_SAMPLES_PER_RADIUS
    distances = [float(np.linalg.norm(centre - view.centre)) for view in views]
    count = int(np.ceil((max(distances) + radius) / step))
    t = (np.arange(count) + 0.5) * step
    rays = []
    for view, distance in zip(views, distances, strict=True):
        direction = (centre - view.centre) / max(distance, 1e-9)
        rays.append(view.centre + t[:, None] * direction)
    density = field_density(field, np.concatenate(rays), device).reshape(len(views), count).astype(np.float64)
    distance_of = np.asarray(distances)[:, None]
    density = np.where(t[None] <= distance_of + radius, density, 0.0)
    alpha = 1.0 - np.exp(-density * step)
    transmittance = np.cumprod(np.concatenate([np.ones((len(views), 1)), 1.0 - alpha[:, :-1]], axis=1), axis=1)
    within = np.abs(t[None] - distance_of) <= radius
    return (transmittance * alpha * within).sum(1)


def pixels_on_object(
    points: Float[np.ndarray, "n 3"], pixel: Int[np.ndarray, " n"], view: DepthView, margin: float
) -> Int[np.ndarray, " m"]:
    """The pixels (flat indices) of ``view`` whose rendered surface lies on the object of ``points`` (projecting to
    ``pixel``): the pixel's own depth is within ``margin`` of the span of distances of the object's points in it.

    A body the camera sees stops the pixel's ray. Where the ray stops well in front of the object (a leaf, or the
    canopy's edge hiding what lies behind it: the 3x3 rim allowance of :func:`seen_pixels` lets such points count as
    seen) or passes through it to a surface behind (a translucent floater), the camera does not see the object
    there; nor where nothing is rendered (sky)."""
    if len(points) == 0:
        return np.zeros(0, np.int64)
    distance = np.linalg.norm(points - view.centre, axis=1)
    pixels, index = np.unique(pixel, return_inverse=True)
    near = np.full(len(pixels), np.inf)
    far = np.full(len(pixels), -np.inf)
    np.minimum.at(near, index, distance)
    np.maximum.at(far, index, distance)
    depth = view.depth.reshape(-1)[pixels]
    on = np.isfinite(depth) & (depth >= near - margin) & (depth <= far + margin)
    return pixels[on]


def field_features(
    model: Any, points: Float[np.ndarray, "n 3"], source: str, eye: Float[np.ndarray, "3"], device: Any = "cpu"
) -> Tuple[Float[np.ndarray, "n c"], Optional[Float[np.ndarray, " n"]]]:
    """The ``source`` output of the model's heads at ``points`` (``appearance_at``; RGB viewed from ``eye``), sampled
    as the source's row says (:mod:`agrinerf_ns.count.source_table`), and the temperature in degrees C where the model
    has a temperature head (else None)."""
    import torch

    row = source_row(source)
    if row.sample is None:
        raise ValueError(f"the '{source}' source is counted in rendered views only (--path views)")
    field = model.field
    values: List[np.ndarray] = []
    temperatures: List[np.ndarray] = []
    has_temperature = field.temperature_head is not None
    with torch.no_grad():
        for start in range(0, len(points), CHUNK):
            part = torch.as_tensor(points[start : start + CHUNK], dtype=torch.float32, device=device)
            coords, _ = field.to_grid(part)
            directions = part - torch.as_tensor(eye, dtype=torch.float32, device=device)
            directions = directions / directions.norm(dim=-1, keepdim=True).clamp_min(1e-9)
            heads = field.appearance_at(coords, directions)
            values.append(row.sample(model, coords, heads).float().cpu().numpy())
            if has_temperature:
                temperatures.append(sample_temperature(model, coords, heads)[..., 0].float().cpu().numpy())
    feature = np.concatenate(values) if values else np.zeros((0, row.channels), np.float32)
    temperature = (
        (np.concatenate(temperatures) if temperatures else np.zeros(0, np.float32)) if has_temperature else None
    )
    return feature, temperature


@dataclass
class SampledField:
    """The seen, dense voxels of a grid with their feature (and temperature)."""

    grid: VoxelGrid
    flat: np.ndarray
    """Flat indices of the seen, dense voxels."""
    feature: Float[np.ndarray, "n c"]
    temperature: Optional[Float[np.ndarray, " n"]]
    seen_by: np.ndarray
    """Views that see each voxel."""
    dense: int
    """Dense voxels before the visibility test."""
    source: str
    source_note: str
    frame: WorldFrame

    eye: Float[np.ndarray, "3"] = dataclasses.field(default_factory=lambda: np.zeros(3))
    """Where RGB is viewed from (the training cameras' mean centre)."""
    views: Sequence[DepthView] = ()
    """The depth views that decided what is seen."""
    seen_margin: float = 0.0
    """Their margin (Nerfstudio units)."""
    field: Any = None
    """The field sampled (its density marched by :func:`body_weights`); None: not marched."""

    def points(self) -> Float[np.ndarray, "n 3"]:
        return self.grid.centres(self.flat)

    def with_source(self, model: Any, source: str, note: str = "") -> "SampledField":
        """The same voxels with the ``source`` feature of ``model`` instead."""
        feature, _ = field_features(model, self.points(), source, self.eye, getattr(model, "device", "cpu"))
        return dataclasses.replace(self, feature=feature, source=source, source_note=note)


def sample_field(
    model: Any,
    views: Sequence[DepthView],
    frame: WorldFrame,
    source: str,
    config: VolumeConfig,
    seen_margin: float,
    pad: float,
    box: Optional[Float[np.ndarray, "2 3"]] = None,
    source_note: str = "",
) -> SampledField:
    """Sample ``model.field`` on the grid over ``box`` (Nerfstudio frame; None: :func:`occupied_box` of ``views``
    padded by ``pad``): dense voxels, those the views see (``seen_margin`` behind the rendered depth; all of them when
    no views are given), and their ``source`` feature. ``seen_margin`` and ``pad`` are in Nerfstudio units."""
    device = getattr(model, "device", "cpu")
    if box is None:
        box = occupied_box(views, config, pad, model.field)
    grid = VoxelGrid.over(np.asarray(box, np.float64), config.voxel_size * frame.scale, config.max_voxels)
    flat = dense_voxels(model.field, grid, config.density_threshold, device)
    dense = len(flat)
    points = grid.centres(flat)
    seen_by = views_seeing(points, views, seen_margin) if views else np.ones(len(flat), np.int32)
    keep = seen_by > 0
    flat, points, seen_by = flat[keep], points[keep], seen_by[keep]
    middle = points.mean(0) if len(points) else np.asarray(box, np.float64).mean(0)  # no dense voxel: the box's
    eye = np.mean([v.centre for v in views], axis=0) if views else middle - np.array([0.0, 0.0, 1.0])
    feature, temperature = field_features(model, points, source, eye, device)
    return SampledField(grid, flat, feature, temperature, seen_by, dense, source, source_note, frame, eye, views,
                        seen_margin, model.field)  # fmt: skip


def mask_of(grid: VoxelGrid, flat: np.ndarray) -> Bool[np.ndarray, "i j k"]:
    """A boolean volume of the grid that is True at ``flat``."""
    mask = np.zeros(int(np.prod(grid.shape)), bool)
    mask[flat] = True
    return mask.reshape(grid.shape)
