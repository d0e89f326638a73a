"""Where and how finely the AgriNeRF volumes resolve the scene over training: the upsampling schedule, the box fits
that move the full-resolution box onto the scene (TensoRF's alpha-mask shrink), the occupancy updates, and the
optimizers re-pointed at the Parameters these replace."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Dict, List, Mapping, Optional, Sequence, Tuple

import numpy as np
import torch
from jaxtyping import Float
from nerfstudio.cameras.rays import RayBundle, RaySamples
from nerfstudio.engine.callbacks import TrainingCallback, TrainingCallbackAttributes, TrainingCallbackLocation
from nerfstudio.engine.optimizers import Optimizers
from torch import Tensor
from torch.nn import Parameter

from agrinerf_ns.dataset_format import FRUIT_MASK
from agrinerf_ns.model.field import AgriNeRFField
from agrinerf_ns.model.grid_mapping import box_voxel
from agrinerf_ns.model.grid_mapping import fit_box as fit_box_to_points
from agrinerf_ns.model.rig import SIDE_STREAM_SEED

SurfaceRender = Callable[[RayBundle], Tuple[Tensor, Tensor, Tensor]]
"""Training rays (on the CPU) -> their median-depth points [n, 3], accumulations [n] and origins [n, 3], rendered on
the model's device as in evaluation (no sample jitter) and collided with the scene (the model's `surface_points`)."""


def upsampling_resolutions(init: int, final: int, iters: Sequence[int]) -> List[int]:
    """Resolution after each upsampling step: log-spaced from `init` to `final` (TensoRF's schedule)."""
    levels = np.exp(np.linspace(np.log(init), np.log(final), len(iters) + 1))
    return np.round(levels).astype(int).tolist()[1:]


@dataclass(frozen=True)
class GridSettings:
    """The grid schedule's own settings, built from the flat model settings (`model_config.part_settings`); each
    field is documented on `model_config.AgriNeRFSettings`, whose field of the same name sets it."""

    init_resolution: int
    final_resolution: int
    upsampling_iters: Tuple[int, ...]
    box_fit_iters: Tuple[int, ...]
    box_fit_rays: int
    box_grid_fraction: float
    box_fit_growth: float
    box_refit_growth: float
    box_depth_cut: float
    box_surface_share: float
    box_voxel_target_m: float
    box_min_share: float
    box_fruit_share: float
    occupancy_resolution: int
    occupancy_update_iters: Tuple[int, ...]
    occupancy_density_threshold: float


def grid_diagnostics(
    field: AgriNeRFField,
    final_resolution: int,
    bundle: RayBundle,
    samples: RaySamples,
    weights: Float[Tensor, "rays samples 1"],
    depth: Float[Tensor, "rays 1"],
) -> Dict[str, Tensor]:
    """Where a render's weight falls and how fine the grid is there (evaluation outputs): the weight within the
    full-resolution box, and the voxel size at the surface now and at `final_resolution`."""
    inside = field.full_resolution(samples.frustums.get_positions()).to(weights.dtype)[..., None]
    surface = bundle.origins + bundle.directions * depth
    final = field.axis_resolution(final_resolution)
    return {
        "full_resolution_weight": (weights * inside).sum(dim=-2),
        "voxel_size": field.voxel_size(surface).amax(dim=-1, keepdim=True),
        "voxel_size_final": field.voxel_size(surface, final).amax(dim=-1, keepdim=True),
    }


class GridSchedule:
    """The volumes' schedule of one model: its settings, the field whose volumes it resamples, and the dataset's
    metres per scene unit (None: unknown scale); `fruit_masks`: the training frames' RGB-camera fruit masks, from the
    dataparser's metadata (`rgb_fruit_masks`), which the box fits hold with `box_fruit_share`."""

    def __init__(
        self,
        config: GridSettings,
        field: AgriNeRFField,
        metres_per_unit: Optional[float],
        fruit_masks: Optional[Sequence[Optional[Any]]] = None,
    ) -> None:
        self.config, self.field, self.metres_per_unit, self.fruit_masks = config, field, metres_per_unit, fruit_masks
        self._fruit_pixels: Dict[Any, Optional[Tensor]] = {}  # the masks' fruit pixels, read once (`fruit_pixels`)
        self.resolutions = upsampling_resolutions(
            config.init_resolution, config.final_resolution, config.upsampling_iters
        )

    def resolution_at_step(self, step: int) -> int:
        """Grid resolution after training step `step` has run (upsampling happens after its iteration)."""
        done = sum(1 for it in self.config.upsampling_iters if it <= step)
        return self.config.init_resolution if done == 0 else self.resolutions[done - 1]

    def upsample(self, resolution: int) -> None:
        """Resample every volume to the per-axis resolution of a `resolution`^3 budget (new Parameters)."""
        target = self.field.axis_resolution(resolution)
        for volume in self.field.volumes().values():
            if volume.resolution != target:
                volume.upsample_grid(target)

    @torch.no_grad()
    def fit_box(
        self, surfaces: SurfaceRender, cameras: Any, step: int, fruit_masks: Optional[Sequence[Any]] = None
    ) -> Optional[Tensor]:
        """Fit the full-resolution box to the median-depth points of `box_fit_rays` training rays of `cameras` (drawn
        with a generator seeded by `step`, so the global random stream is untouched) and resample the volumes into
        it at the current resolution; returns the new box, or None when too few rays hit anything (box kept).
        `fruit_masks`: per camera its fruit-mask file (None: none, or not the RGB camera's), for `box_fruit_share`."""
        field, cfg = self.field, self.config
        if field.mapping is None:
            return None
        gen = torch.Generator().manual_seed(SIDE_STREAM_SEED + step)  # cpu: see below
        n = cfg.box_fit_rays
        # cpu: a CPU generator draws the same rays on every device; Nerfstudio's training cameras stay on the CPU
        index = torch.randint(0, cameras.shape[0], (n,), generator=gen)  # cpu: see above
        heights, widths = cameras.height[index, 0].float(), cameras.width[index, 0].float()
        rows = (torch.rand(n, generator=gen) * heights).floor() + 0.5  # cpu: see above
        cols = (torch.rand(n, generator=gen) * widths).floor() + 0.5  # cpu: see above
        bundle = cameras.generate_rays(camera_indices=index[:, None], coords=torch.stack([rows, cols], -1))
        box = self.box_for_surface(*surfaces(bundle))
        if box is None:
            return None
        if cfg.box_fruit_share > 0 and fruit_masks is not None:
            fruit = fruit_pixel_rays(cameras, self.fruit_pixels(cameras, fruit_masks), n, gen)
            if fruit is not None:
                box = box_with_fruit(box, *surfaces(fruit), cfg.box_depth_cut, cfg.box_fruit_share)
        old = field.full_resolution_box()
        first = not cfg.box_fit_iters or step <= min(cfg.box_fit_iters)
        growth = cfg.box_fit_growth if first else cfg.box_refit_growth
        centre, reach = old.mean(dim=0), (old[1] - old[0]) / 2 * growth
        box = torch.stack([torch.maximum(box[0], centre - reach), torch.minimum(box[1], centre + reach)])
        if not bool((box[1] > box[0]).all()):
            return None
        field.refit_box(box, cfg.box_grid_fraction, self.resolution_at_step(step))
        if self.occupancy_updated(step):
            field.update_occupancy(cfg.occupancy_density_threshold)
        return box

    def fruit_pixels(self, cameras: Any, masks: Sequence[Optional[Any]]) -> Optional[Tensor]:
        """`fruit_pixels` of `masks` at the sizes of `cameras`, read from their files at the first fit only."""
        key = (tuple(masks), tuple(cameras.height[:, 0].tolist()), tuple(cameras.width[:, 0].tolist()))
        if key not in self._fruit_pixels:
            self._fruit_pixels[key] = fruit_pixels(cameras, masks)
        return self._fruit_pixels[key]

    def box_for_surface(
        self,
        points: Float[Tensor, "n 3"],
        weights: Optional[Float[Tensor, " n"]],
        origins: Float[Tensor, "n 3"],
    ) -> Optional[Float[Tensor, "2 3"]]:
        """The box the fit rules give surface points seen from `origins`: towards `box_voxel_target_m` keeping at
        least `box_min_share` where that reaches it, else `box_surface_share` (`fine_enough`); None: too few
        points."""
        cfg = self.config
        small_enough = self.fine_enough()
        if small_enough is not None:
            box = fit_box_to_points(
                points, weights, origins, cfg.box_depth_cut, cfg.box_min_share, small_enough=small_enough
            )
            if box is not None and small_enough(box):
                return box  # else the preset's grids cannot resolve fruit here: hold the scene
        return fit_box_to_points(points, weights, origins, cfg.box_depth_cut, cfg.box_surface_share)

    def fine_enough(self) -> Optional[Callable[[Tensor], bool]]:
        """Whether a box's voxels at the preset's final grids are at most `box_voxel_target_m`; None where the
        dataset's scale is unknown or the target is off (the fit then holds `box_surface_share`)."""
        target, scale = self.config.box_voxel_target_m, self.metres_per_unit
        if target <= 0 or scale is None:
            return None
        inner, cube = self.config.box_grid_fraction, int(self.config.final_resolution)
        return lambda box: box_voxel(box, inner, cube) * float(scale) <= target * (1.0 + 1e-5)  # float32 corners

    def occupancy_updated(self, step: int) -> bool:
        """Whether the occupancy grid has been computed after training step `step` (an update step has run)."""
        cfg = self.config
        return cfg.occupancy_resolution > 0 and any(it <= step for it in cfg.occupancy_update_iters)

    def callbacks(
        self,
        attributes: TrainingCallbackAttributes,
        param_groups: Callable[[], Dict[str, List[Parameter]]],
        surfaces: SurfaceRender,
    ) -> List[TrainingCallback]:
        """Upsampling of all volumes (optimizers re-pointed at `param_groups()`), box fits and occupancy updates.

        Called after a checkpoint has loaded: the optimizers, built before the checkpoint's load hooks resized the
        volumes' Parameters, are re-pointed here first (their loaded moments already have the new size).
        """
        cfg, field = self.config, self.field
        optimizers = attributes.optimizers
        if optimizers is not None:
            sync_optimizers(param_groups(), optimizers)

        def upsample(step: int) -> None:
            self.upsample(self.resolution_at_step(step))
            if optimizers is not None:
                sync_optimizers(param_groups(), optimizers)

        def update_occupancy(step: int) -> None:
            del step
            field.update_occupancy(cfg.occupancy_density_threshold)

        # the training cameras, taken once here (Nerfstudio's stay on the CPU); the fruit masks came with the metadata
        dataset = getattr(getattr(attributes.pipeline, "datamanager", None), "train_dataset", None)
        cameras = None if dataset is None else dataset.cameras

        def refit_box(step: int) -> None:
            if cameras is None or self.fit_box(surfaces, cameras, step, self.fruit_masks) is None:
                return
            if optimizers is not None:
                sync_optimizers(param_groups(), optimizers, keep_moments=False)

        after = [TrainingCallbackLocation.AFTER_TRAIN_ITERATION]
        callbacks = [TrainingCallback(where_to_run=after, iters=tuple(cfg.upsampling_iters), func=upsample)]
        if field.mapping is not None and cfg.box_fit_iters:
            callbacks.append(TrainingCallback(where_to_run=after, iters=tuple(cfg.box_fit_iters), func=refit_box))
        if cfg.occupancy_resolution > 0 and cfg.occupancy_update_iters:
            callbacks.append(
                TrainingCallback(where_to_run=after, iters=tuple(cfg.occupancy_update_iters), func=update_occupancy)
            )
        return callbacks


def rgb_fruit_masks(metadata: Mapping[str, Any]) -> Optional[List[Optional[Any]]]:
    """Per training camera its fruit-mask file (the dataparser's `metadata`) where the mask is the RGB camera's (None
    where it is the thermal camera's); None when the dataset has no fruit masks."""
    files = metadata.get(FRUIT_MASK.metadata)
    if not files:
        return None
    thermal = metadata.get("fruit_mask_thermal") or [False] * len(files)
    return [None if on_thermal else path for path, on_thermal in zip(files, thermal, strict=True)]


def fruit_pixels(cameras: Any, masks: Sequence[Optional[Any]]) -> Optional[Tensor]:
    """Every fruit pixel of the cameras' masks (files, None: no mask), read at each camera's size as the dataset reads
    them for the fruit loss: [m, 3] (camera index, row, column at the pixel centre); None when no mask holds fruit."""
    from agrinerf_ns.dataparsers.fruit_masks import load_fruit_mask

    pixels = []
    for index, path in enumerate(masks):
        if path is None:
            continue
        fruit, _ = load_fruit_mask(path, int(cameras.height[index, 0]), int(cameras.width[index, 0]))
        ys, xs = np.nonzero(fruit[..., 0].numpy() > 0.5)
        if ys.size:
            pixels.append(np.stack([np.full(ys.size, index), ys + 0.5, xs + 0.5], -1))
    if not pixels:
        return None
    return torch.from_numpy(np.concatenate(pixels)).float()  # cpu: the training cameras stay on the CPU


def fruit_pixel_rays(cameras: Any, every: Optional[Tensor], n: int, gen: torch.Generator) -> Optional[RayBundle]:
    """Up to `n` rays through the fruit pixels `every` (`fruit_pixels`; every one equally likely, drawn with `gen`);
    None when there are none."""
    if every is None:
        return None
    pick = torch.randint(0, every.shape[0], (min(n, every.shape[0]),), generator=gen)  # cpu: as the scene's rays
    chosen = every[pick]
    return cameras.generate_rays(camera_indices=chosen[:, :1].long(), coords=chosen[:, 1:])


def box_with_fruit(
    box: Float[Tensor, "2 3"],
    points: Float[Tensor, "n 3"],
    weights: Float[Tensor, " n"],
    origins: Float[Tensor, "n 3"],
    depth_cut: float,
    share: float,
) -> Float[Tensor, "2 3"]:
    """`box` grown to also hold the box of `share` of the fruit pixels' surface points (as the scene's: points beyond
    `depth_cut` times their median distance left out); `box` itself where too few fruit points hit anything."""
    fruit = fit_box_to_points(points, weights, origins, depth_cut, share)
    if fruit is None:
        return box
    return torch.stack([torch.minimum(box[0], fruit[0].to(box)), torch.maximum(box[1], fruit[1].to(box))])


def sync_optimizers(current: Dict[str, List[Parameter]], optimizers: Optimizers, keep_moments: bool = True) -> int:
    """Point every optimizer at the current Parameters `current` (the model's groups; upsampling and box fits replace
    them); returns how many were replaced. Adam moments move with a Parameter when their shape still fits (a checkpoint loaded into
    volumes its pre-hooks resized) and `keep_moments`, and are dropped otherwise (after an upsampling step or a box
    fit, whose moments belong to other places: Adam re-initialises them).
    """
    replaced = 0
    for name, optimizer in optimizers.optimizers.items():
        if name not in current:
            continue
        params = optimizer.param_groups[0]["params"]
        if len(optimizer.param_groups) != 1 or len(params) != len(current[name]):
            raise RuntimeError(f"Optimizer '{name}' does not match the model's '{name}' parameter group")
        for i, (old, new) in enumerate(zip(params, current[name], strict=True)):
            if old is new:
                continue
            state = optimizer.state.pop(old, None)
            moments = [v for v in (state or {}).values() if isinstance(v, Tensor) and v.dim() > 0]
            if keep_moments and state is not None and all(v.shape == new.shape for v in moments):
                optimizer.state[new] = state
            params[i] = new
            replaced += 1
        optimizers.parameters[name] = current[name]
    return replaced
