"""The model's parts in one table (`PARTS`: each part's name and how it is built from the plan), and what the
model builds beside them: the field, the ray samplers and the collider. A part is a `model_part.ModelPart`; the
model sets each as its attribute of the same name (None where the plan leaves it off) and loops over them for their
renders, loss terms, parameter groups and metrics, in the table's order."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Dict, Optional, Tuple

import torch
from nerfstudio.data.scene_box import SceneBox
from nerfstudio.model_components.ray_samplers import PDFSampler, Sampler, UniformLinDispPiecewiseSampler, UniformSampler
from nerfstudio.model_components.scene_colliders import AABBBoxCollider, NearFarCollider, SceneCollider
from torch import Tensor

from agrinerf_ns.model.blur_term import BlurTerm
from agrinerf_ns.model.box_sampler import BoxPiecewiseSampler
from agrinerf_ns.model.event_crf import EventCRF
from agrinerf_ns.model.event_settings import EventSettings
from agrinerf_ns.model.event_term import EventTerm
from agrinerf_ns.model.field import AgriNeRFField
from agrinerf_ns.model.fruit_head import FruitHead
from agrinerf_ns.model.loss_routing import FieldTerms
from agrinerf_ns.model.model_config import AgriNeRFSettings, part_settings
from agrinerf_ns.model.model_part import ModelPart
from agrinerf_ns.model.plan import ModelPlan
from agrinerf_ns.model.rig import SIDE_STREAM_SEED, Rig
from agrinerf_ns.model.rigid_blur import RigidBlurKernel
from agrinerf_ns.model.thermal_view import ThermalView


@dataclass(frozen=True)
class PartContext:
    """What a part is built from: the settings, the plan, the rig, the field and the optional weights the model owns
    (`side_modules`)."""

    config: AgriNeRFSettings
    plan: ModelPlan
    rig: Rig
    field: AgriNeRFField
    blur_kernel: Optional[RigidBlurKernel] = None
    event_crf: Optional[EventCRF] = None


def side_modules(
    config: AgriNeRFSettings, plan: ModelPlan, num_frames: int
) -> Tuple[Optional[RigidBlurKernel], Optional[EventCRF]]:
    """EvDeblurNeRF's learnt blur kernel (config `blur_kernel`) and event response (config `event_crf`), where the
    plan has them, drawn from the side stream: optional parts leave the field's (and the batches') draws alone."""
    kernel: Optional[RigidBlurKernel] = None
    crf: Optional[EventCRF] = None
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(SIDE_STREAM_SEED)
        if plan.blur == "learnt":
            kernel = RigidBlurKernel(num_frames, num_motions=config.blur_samples - 1)
        if plan.event_supervision == "pairs" and config.event_crf:
            crf = EventCRF()
    return kernel, crf


def build_field(
    config: AgriNeRFSettings, plan: ModelPlan, aabb: Tensor, temperature_stats: Optional[Dict[str, float]]
) -> AgriNeRFField:
    """The TensoRF field with the heads the plan builds (`temperature_stats`: the dataset's, in degrees C)."""
    return AgriNeRFField(
        aabb,
        contraction=config.scene_contraction,
        resolution=config.init_resolution,
        num_density_components=config.num_density_components,
        with_rgb=plan.use_rgb,
        with_thermal=plan.has_thermal_head,
        num_rgb_components=config.num_rgb_components,
        rgb_appearance_dim=config.rgb_appearance_dim,
        num_thermal_components=config.num_thermal_components,
        thermal_appearance_dim=config.thermal_appearance_dim,
        thermal_view_dependent=config.thermal_view_dependent,
        thermal_channels=2 if plan.has_thermal_camera else 1,
        temperature_stats=(temperature_stats["mean_c"], temperature_stats["std_c"])
        if plan.has_temperature and temperature_stats is not None
        else None,
        temperature_mlp_width=config.temperature_mlp_width,
        mlp_width=config.mlp_width,
        thermal_mlp_width=config.thermal_mlp_width,
        density_shift=config.density_shift,
        max_density=config.max_density,
        occupancy_resolution=config.occupancy_resolution,
        vm_lookup=config.vm_lookup,
    )


def ray_samplers(config: AgriNeRFSettings, box: Callable[[], Tensor]) -> Tuple[Sampler, PDFSampler]:
    """The coarse sampler (scene contraction: uniform up to where a ray leaves the full-resolution `box`, then in
    disparity; `coarse_sampler` lindisp: Nerfstudio's, up to distance 1) and the fine samples' PDF sampler."""
    coarse: Sampler
    if config.scene_contraction and config.coarse_sampler == "box":
        coarse = BoxPiecewiseSampler(config.num_coarse_samples, box=box)
    elif config.scene_contraction:
        coarse = UniformLinDispPiecewiseSampler(num_samples=config.num_coarse_samples, single_jitter=False)
    else:
        coarse = UniformSampler(num_samples=config.num_coarse_samples, single_jitter=False)
    fine = PDFSampler(
        num_samples=config.num_fine_samples, single_jitter=False, include_original=config.fine_include_coarse
    )
    return coarse, fine


def collider(config: AgriNeRFSettings, scene_box: SceneBox) -> SceneCollider:
    """Near to far plane with scene contraction, else the rays clipped to the scene box (as Nerfstudio's tensorf)."""
    if config.scene_contraction:
        return NearFarCollider(near_plane=config.near_plane, far_plane=config.far_plane)
    return AABBBoxCollider(scene_box=scene_box, near_plane=config.near_plane)


def _blur(c: PartContext) -> Optional[ModelPart]:
    if not c.plan.use_blur:
        return None
    return BlurTerm(c.rig, c.config.blur_samples, c.config.blur_start_step, c.blur_kernel)


def _thermal_view(c: PartContext) -> Optional[ModelPart]:
    if not c.plan.thermal_camera_rays:
        return None
    return ThermalView(c.rig, c.config.thermal_rays_per_batch, c.plan.thermal_view, c.plan.fruit_thermal_view)


def _events(c: PartContext) -> Optional[ModelPart]:
    if not (c.plan.use_event_loss or c.plan.edi_prior):
        return None
    return EventTerm(part_settings(EventSettings, c.config), c.plan, c.rig, c.event_crf)


def _fruit_head(c: PartContext) -> Optional[ModelPart]:
    """Where the frames have fruit masks; drawn from the side stream (the field's and the batches' draws stay)."""
    if not c.plan.has_fruit_head:
        return None
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(SIDE_STREAM_SEED)
        features = c.field.density_encoding.get_out_dim()
        cfg = c.config
        return FruitHead(features, cfg.fruit_mlp_width, cfg.fruit_shapes_geometry, cfg.fruit_position_octaves)


PartBuilder = Callable[[PartContext], Optional[ModelPart]]
"""A part from the context, or None where the plan leaves it off."""

PARTS: Dict[str, PartBuilder] = {
    "field_terms": lambda c: FieldTerms(c.field),
    "blur": _blur,
    "thermal_view": _thermal_view,
    "events": _events,
    "fruit_head": _fruit_head,
}
"""Every part by its name (the model's attribute and a `loss_routing.TERMS` row's `part`), in the order the model asks
them: the side renders (blur model, thermal camera's view, event samples), the loss terms' weighting, the parameter
groups and the metrics."""
