"""Where and how finely the AgriNeRF volumes resolve the scene over training: the upsampling schedule, the box fits
that move the full-resolution box onto the scene (TensoRF's alpha-mask shrink), the occupancy updates, and the
optimizers re-pointed at the Parameters these replace."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Callable, List, Optional, Sequence

import numpy as np
import torch
from jaxtyping import Float
from nerfstudio.engine.callbacks import TrainingCallback, TrainingCallbackAttributes, TrainingCallbackLocation
from nerfstudio.engine.optimizers import Optimizers
from torch import Tensor

from agrinerf_ns.model.grid_mapping import box_voxel
from agrinerf_ns.model.grid_mapping import fit_box as fit_box_to_points
from agrinerf_ns.model.model_config import SIDE_STREAM_SEED

if TYPE_CHECKING:
    from agrinerf_ns.model.model import AgriNeRFModel


def upsampling_resolutions(init: int, final: int, iters: Sequence[int]) -> List[int]:
    """Resolution after each upsampling step: log-spaced from `init` to `final` (TensoRF's schedule)."""
    levels = np.exp(np.linspace(np.log(init), np.log(final), len(iters) + 1))
    return np.round(levels).astype(int).tolist()[1:]


def resolution_at_step(model: AgriNeRFModel, step: int) -> int:
    """Grid resolution after training step `step` has run (upsampling happens after its iteration)."""
    done = sum(1 for it in model.config.upsampling_iters if it <= step)
    return model.config.init_resolution if done == 0 else model.upsampling_resolutions[done - 1]


def upsample_volumes(model: AgriNeRFModel, resolution: int) -> None:
    """Resample every volume to the per-axis resolution of a `resolution`^3 budget (new Parameters)."""
    target = model.field.axis_resolution(resolution)
    for volume in model.field.volumes().values():
        if volume.resolution != target:
            volume.upsample_grid(target)


@torch.no_grad()
def fit_box(model: AgriNeRFModel, cameras: Any, step: int) -> Optional[Tensor]:
    """Fit the full-resolution box to the median-depth points of `box_fit_rays` training rays of `cameras` (drawn
    with a generator seeded by `step`, so the global random stream is untouched) and resample the volumes into it
    at the current resolution; returns the new box, or None when too few rays hit anything (box kept)."""
    if model.field.mapping is None:
        return None
    gen = torch.Generator().manual_seed(SIDE_STREAM_SEED + step)
    n = model.config.box_fit_rays
    # cpu: a CPU generator draws the same rays on every device; Nerfstudio's training cameras stay on the CPU
    index = torch.randint(0, cameras.shape[0], (n,), generator=gen)  # cpu: see above
    heights, widths = cameras.height[index, 0].float(), cameras.width[index, 0].float()
    rows = (torch.rand(n, generator=gen) * heights).floor() + 0.5  # cpu: see above
    cols = (torch.rand(n, generator=gen) * widths).floor() + 0.5  # cpu: see above
    bundle = cameras.generate_rays(camera_indices=index[:, None], coords=torch.stack([rows, cols], -1))
    bundle = bundle.to(model.device)
    points, weights, origins = [], [], []
    was_training = model.training
    model.eval()
    try:
        for start in range(0, n, model.config.eval_num_rays_per_chunk):
            part = model.collider(bundle[start : start + model.config.eval_num_rays_per_chunk])
            out = model.render(part, routed=False, heads=())
            points.append(part.origins + part.directions * out["depth"])
            weights.append(out["accumulation"][:, 0])
            origins.append(part.origins)
    finally:
        model.train(was_training)
    box = box_for_surface(model, torch.cat(points), torch.cat(weights), torch.cat(origins))
    if box is None:
        return None
    old = model.field.full_resolution_box()
    first = not model.config.box_fit_iters or step <= min(model.config.box_fit_iters)
    growth = model.config.box_fit_growth if first else model.config.box_refit_growth
    centre, reach = old.mean(dim=0), (old[1] - old[0]) / 2 * growth
    box = torch.stack([torch.maximum(box[0], centre - reach), torch.minimum(box[1], centre + reach)])
    if not bool((box[1] > box[0]).all()):
        return None
    model.field.refit_box(box, model.config.box_grid_fraction, resolution_at_step(model, step))
    if occupancy_updated(model, step):
        model.field.update_occupancy(model.config.occupancy_density_threshold)
    return box


def box_for_surface(
    model: AgriNeRFModel,
    points: Float[Tensor, "n 3"],
    weights: Optional[Float[Tensor, " n"]],
    origins: Float[Tensor, "n 3"],
) -> Optional[Float[Tensor, "2 3"]]:
    """The box the model's fit rules give surface points seen from `origins`: towards `box_voxel_target_m` keeping
    at least `box_min_share` where that reaches it, else `box_surface_share` (`fine_enough`); None: too few points."""
    cfg = model.config
    small_enough = fine_enough(model)
    if small_enough is not None:
        box = fit_box_to_points(
            points, weights, origins, cfg.box_depth_cut, cfg.box_min_share, small_enough=small_enough
        )
        if box is not None and small_enough(box):
            return box  # else the preset's grids cannot resolve fruit here: hold the scene
    return fit_box_to_points(points, weights, origins, cfg.box_depth_cut, cfg.box_surface_share)


def fine_enough(model: AgriNeRFModel) -> Optional[Callable[[Tensor], bool]]:
    """Whether a box's voxels at the preset's final grids are at most `box_voxel_target_m`; None where the dataset's
    scale is unknown or the target is off (the fit then holds `box_surface_share`)."""
    target, scale = model.config.box_voxel_target_m, model.metres_per_unit
    if target <= 0 or scale is None:
        return None
    inner, cube = model.config.box_grid_fraction, int(model.config.final_resolution)
    return lambda box: box_voxel(box, inner, cube) * float(scale) <= target * (1.0 + 1e-5)  # float32 corners


def occupancy_updated(model: AgriNeRFModel, step: int) -> bool:
    """Whether the occupancy grid has been computed after training step `step` (an update step has run)."""
    return model.config.occupancy_resolution > 0 and any(it <= step for it in model.config.occupancy_update_iters)


def sync_optimizers(model: AgriNeRFModel, optimizers: Optimizers, keep_moments: bool = True) -> int:
    """Point every optimizer at the model's current Parameters (upsampling and box fits replace them); returns how
    many were replaced. Adam moments move with a Parameter when their shape still fits (a checkpoint loaded into
    volumes its pre-hooks resized) and `keep_moments`, and are dropped otherwise (after an upsampling step or a box
    fit, whose moments belong to other places: Adam re-initialises them).
    """
    current = model.get_param_groups()
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


def training_callbacks(
    model: AgriNeRFModel, training_callback_attributes: TrainingCallbackAttributes
) -> List[TrainingCallback]:
    """Upsampling of all volumes (optimizers re-pointed) and occupancy updates.

    Called after a checkpoint has loaded: the optimizers, built before the checkpoint's load hooks resized the
    volumes' Parameters, are re-pointed here first (their loaded moments already have the new size).
    """
    optimizers = training_callback_attributes.optimizers
    if optimizers is not None:
        sync_optimizers(model, optimizers)

    def upsample(step: int) -> None:
        upsample_volumes(model, resolution_at_step(model, step))
        if optimizers is not None:
            sync_optimizers(model, optimizers)

    def update_occupancy(step: int) -> None:
        del step
        model.field.update_occupancy(model.config.occupancy_density_threshold)

    def refit_box(step: int) -> None:
        pipeline = training_callback_attributes.pipeline
        dataset = getattr(getattr(pipeline, "datamanager", None), "train_dataset", None)
        if dataset is None or fit_box(model, dataset.cameras, step) is None:
            return
        if optimizers is not None:
            sync_optimizers(model, optimizers, keep_moments=False)

    def keep_step(step: int) -> None:
        model.step = step

    callbacks = [
        TrainingCallback(
            where_to_run=[TrainingCallbackLocation.BEFORE_TRAIN_ITERATION], update_every_num_iters=1, func=keep_step
        ),  # fmt: skip
        TrainingCallback(
            where_to_run=[TrainingCallbackLocation.AFTER_TRAIN_ITERATION],
            iters=tuple(model.config.upsampling_iters),
            func=upsample,
        ),
    ]
    if model.field.mapping is not None and model.config.box_fit_iters:
        callbacks.append(
            TrainingCallback(
                where_to_run=[TrainingCallbackLocation.AFTER_TRAIN_ITERATION],
                iters=tuple(model.config.box_fit_iters),
                func=refit_box,
            )
        )
    if model.config.occupancy_resolution > 0 and model.config.occupancy_update_iters:
        callbacks.append(
            TrainingCallback(
                where_to_run=[TrainingCallbackLocation.AFTER_TRAIN_ITERATION],
                iters=tuple(model.config.occupancy_update_iters),
                func=update_occupancy,
            )
        )
    return callbacks
