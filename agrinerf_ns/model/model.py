"""AgriNeRF model: coarse uniform + fine PDF samples through a shared-density TensoRF with RGB and thermal heads.

Paper: ../shared/paper/agrinerf_paper.tex (Method; Implementation Details). Losses: L = L_rgb + L_th + L_reg
(+ TensoRF L1 and TV regularisers), weights in `loss_coefficients`, raw terms in the metrics (as `depth_nerfacto`).
Its settings are `model_config.AgriNeRFSettings`; `AgriNeRFModelConfig` (below) adds the model they build. Its parts
are listed on the class.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Dict, List, Optional, Tuple, Type

import torch
from jaxtyping import Float
from nerfstudio.cameras.camera_optimizers import CameraOptimizer
from nerfstudio.cameras.cameras import Cameras
from nerfstudio.cameras.rays import RayBundle, RaySamples
from nerfstudio.data.scene_box import OrientedBox
from nerfstudio.engine.callbacks import TrainingCallback, TrainingCallbackAttributes, TrainingCallbackLocation
from nerfstudio.field_components.field_heads import FieldHeadNames
from nerfstudio.model_components.renderers import AccumulationRenderer, DepthRenderer
from nerfstudio.model_components.scene_colliders import SceneCollider
from nerfstudio.models.base_model import Model
from nerfstudio.utils.rich_utils import CONSOLE
from torch import Tensor
from torch.nn import Parameter

from agrinerf_ns import cpu_memory
from agrinerf_ns.model import display, eval_metrics, losses, parts
from agrinerf_ns.model.blur_term import BlurTerm
from agrinerf_ns.model.device_sync import prune_on
from agrinerf_ns.model.event_term import EventTerm
from agrinerf_ns.model.field_heads import AgriNeRFFieldHeadNames
from agrinerf_ns.model.fruit_head import FruitHead
from agrinerf_ns.model.grid_mapping import fit_box as fit_box_to_points
from agrinerf_ns.model.grid_schedule import GridSchedule, GridSettings, grid_diagnostics, rgb_fruit_masks
from agrinerf_ns.model.loss_routing import TERMS, FieldTerms, routed_outputs
from agrinerf_ns.model.model_config import AgriNeRFSettings, part_settings
from agrinerf_ns.model.model_part import ModelPart, TermInputs
from agrinerf_ns.model.old_state import load_old_state
from agrinerf_ns.model.plan import ModelPlan, resolve_plan
from agrinerf_ns.model.rig import Rig, side_stream
from agrinerf_ns.model.rigid_blur import RigidBlurKernel
from agrinerf_ns.model.thermal_view import ThermalView
from agrinerf_ns.model.vm_encoding import VMCorners

DENSE_HEADS_FRACTION = 0.85
"""When at least this fraction of the fine samples passes the weight threshold (usual: the PDF samples sit where the
weights are), the heads run on every sample and the others are masked: gathering the selected ones would cost a copy of
their lookup corners and a second transposed lookup for the backward pass, more than the few extra samples."""


class AgriNeRFModel(Model):
    """AgriNeRF: shared TensoRF geometry, RGB and cross-spectral thermal heads, built for the scene's modalities.

    Its parts (`parts.PARTS`: the field's terms, the blur model, the thermal camera's view, the event term, the fruit
    head) are built from the plan (`plan.py`) and given the render call (`render_rays`) and the field, not the model;
    it loops over them for their side renders, loss terms (`loss_routing.TERMS`), parameter groups and metrics. The
    grid schedule (`grid_schedule.GridSchedule`) runs in its training callbacks.

    Args:
        config: model config.
        metadata (kwarg): the train dataset's metadata; its "modalities" (from the dataparser) are intersected with
            `config.modalities`. Without it the dataset is taken to be RGB only.
    """

    config: AgriNeRFSettings
    collider: SceneCollider
    field_terms: FieldTerms  # the parts (`parts.PARTS`), each None where the plan leaves it off
    blur: Optional[BlurTerm]
    thermal_view: Optional[ThermalView]
    events: Optional[EventTerm]
    fruit_head: Optional[FruitHead]
    blur_kernel: Optional[RigidBlurKernel]  # the learnt blur kernel's weights (the blur model's), a module of the model

    def __init__(self, config: AgriNeRFSettings, **kwargs) -> None:
        metadata = kwargs.get("metadata") or {}
        self.plan: ModelPlan = resolve_plan(config, metadata)  # every on/off decision, made once (plan.py)
        for note in self.plan.notes:
            CONSOLE.print(note)
        # dataset temperatures in degrees C (mean_c, std_c, min_c, max_c): only with a radiometric calibration
        self.temperature_stats: Optional[Dict[str, float]] = metadata.get("temperature_stats")
        # metres per scene unit, where the dataset's poses are metric (dataparser metadata; None: unknown scale)
        self.metres_per_unit: Optional[float] = metadata.get("metres_per_unit")
        self.rig = Rig.from_metadata(metadata)  # the frames' timing and the rig's other cameras
        self.eval_camera: Optional[Cameras] = None
        self.step = 0  # training step, kept by a callback (the blur model starts at blur_start_step)
        super().__init__(config=config, **kwargs)
        self._register_load_state_dict_pre_hook(load_old_state, with_module=True)
        self.display = display.DisplayOutputs.of(self, metadata)  # rgb_display, temperature_display, viewer controls

    # ------------------------------------------------------------------ setup
    def populate_modules(self) -> None:
        """The field and the parts the plan switches on (`parts.PARTS`), samplers, renderers, colliders, metrics."""
        super().populate_modules()
        cfg, plan = self.config, self.plan
        # EvDeblurNeRF's learnt kernel (`blur_kernel`, a module of the model) and event response (the event term's)
        self.blur_kernel, crf = parts.side_modules(cfg, plan, self.num_train_data)
        self.field = parts.build_field(cfg, plan, self.scene_box.aabb, self.temperature_stats)
        context = parts.PartContext(cfg, plan, self.rig, self.field, self.blur_kernel, crf)
        self.parts: Dict[str, ModelPart] = {}
        for name, build in parts.PARTS.items():  # each also the attribute of its name (None where off)
            part = build(context)
            setattr(self, name, part)
            if part is not None:
                self.parts[name] = part

        # the first full-resolution box: around the dataset's SfM points where it has them (refitted in training)
        metadata = self.kwargs.get("metadata") or {}
        points = metadata.get("points3D_xyz")
        if self.field.mapping is not None and points is not None:
            box = fit_box_to_points(torch.as_tensor(points, dtype=torch.float32))  # cpu: before model.to(device)
            if box is not None:
                self.field.refit_box(box, cfg.box_grid_fraction, cfg.init_resolution)
        masks = rgb_fruit_masks(metadata)  # the box fits' fruit, from the dataparser's metadata
        self.grid = GridSchedule(part_settings(GridSettings, cfg), self.field, self.metres_per_unit, masks)

        self.sampler_coarse, self.sampler_pdf = parts.ray_samplers(cfg, self.field.full_resolution_box)
        self.collider = parts.collider(cfg, self.scene_box)
        self.renderer_accumulation = AccumulationRenderer()
        self.renderer_depth = DepthRenderer(method="median")

        from torchmetrics.functional import structural_similarity_index_measure
        from torchmetrics.image import PeakSignalNoiseRatio

        self.psnr = PeakSignalNoiseRatio(data_range=1.0)
        self.ssim = structural_similarity_index_measure
        self._lazy_metrics: Dict[str, torch.nn.Module] = {}  # a plain dict: not a submodule, not in checkpoints
        self.camera_optimizer: CameraOptimizer = cfg.camera_optimizer.setup(
            num_cameras=self.num_train_data, device="cpu"
        )

    def get_param_groups(self) -> Dict[str, List[Parameter]]:
        """The parts' groups, merged in their order ("fields": MLPs, "encodings": every TensoRF volume, the learnt
        blur kernel's and event response's own), plus camera_opt when enabled."""
        groups: Dict[str, List[Parameter]] = {}
        for part in self.parts.values():
            for name, params in part.param_groups().items():
                groups.setdefault(name, []).extend(params)
        self.camera_optimizer.get_param_groups(param_groups=groups)
        return groups

    def get_training_callbacks(
        self, training_callback_attributes: TrainingCallbackAttributes
    ) -> List[TrainingCallback]:
        """The step kept for the parts that start late, then the grid schedule's upsampling, box fits and occupancy
        updates (`GridSchedule.callbacks`)."""

        before = [TrainingCallbackLocation.BEFORE_TRAIN_ITERATION]
        keep = TrainingCallback(
            where_to_run=before, update_every_num_iters=1, func=lambda step: setattr(self, "step", step)
        )
        return [keep, *self.grid.callbacks(training_callback_attributes, self.get_param_groups, self.surface_points)]

    # -------------------------------------------------------------- forward
    def _background(self, values: Float[Tensor, "rays samples c"]) -> Float[Tensor, "rays c"]:
        if self.config.background_color == "last_sample":
            return values[:, -1, :]
        fill = 1.0 if self.config.background_color == "white" else 0.0
        return torch.full_like(values[:, -1, :], fill)

    def get_outputs(self, ray_bundle: RayBundle) -> Dict[str, Tensor]:
        """Renders the rays; in training also the parts' renders of the same pixels at other times or from other
        cameras ("rgb_blurred", "thermal_view/...", "event_log_start", "event_log_end") where they are on."""
        if self.training:
            self.camera_optimizer.apply_to_raybundle(ray_bundle)
            if self.config.keep_freed_memory:
                cpu_memory.keep_freed_memory(ray_bundle.origins.device)
        training = self.training and torch.is_grad_enabled()
        heads = None  # all; where the thermal camera's rays carry the temperature term, the RGB rays skip it
        if training and self.plan.thermal_view:
            heads = ("rgb", "thermal", "fruit") if self.fruit_head is not None else ("rgb", "thermal")
        outputs = self.render(ray_bundle, heads=heads)
        if training:
            with side_stream(self.device, self.step):
                for part in self.parts.values():
                    outputs.update(part.outputs(self.render_rays, ray_bundle, outputs, self.step))
        return outputs

    def render_rays(self, bundle: RayBundle, heads: Tuple[str, ...], term: Optional[str] = None) -> Dict[str, Tensor]:
        """A part's render of a side bundle (`rig.RenderRays`): collided, then rendered with `term`'s density
        gradient scale and no routed copies, or (term None) at full scale with them."""
        if term is None:
            return self.render(self.collider(bundle), heads=heads)
        scale = self.plan.density_gradient_scales.get(term, 1.0)  # 1 where not configured
        return self.render(self.collider(bundle), routed=False, density_scale=scale, heads=heads)

    @torch.no_grad()
    def surface_points(self, bundle: RayBundle) -> Tuple[Tensor, Tensor, Tensor]:
        """Median-depth points, accumulations and origins of `bundle`'s rays rendered as in evaluation, in chunks
        (the grid schedule's box fits: `grid_schedule.SurfaceRender`)."""
        bundle = bundle.to(self.device)
        chunk = self.config.eval_num_rays_per_chunk
        points, weights, origins = [], [], []
        was_training = self.training
        self.eval()
        try:
            for start in range(0, bundle.shape[0], chunk):
                part = self.collider(bundle[start : start + chunk])
                out = self.render(part, routed=False, heads=())
                points.append(part.origins + part.directions * out["depth"])
                weights.append(out["accumulation"][:, 0])
                origins.append(part.origins)
        finally:
            self.train(was_training)
        return torch.cat(points), torch.cat(weights), torch.cat(origins)

    def render(
        self,
        ray_bundle: RayBundle,
        routed: bool = True,
        density_scale: float = 1.0,
        heads: Optional[Tuple[str, ...]] = None,
    ) -> Dict[str, Tensor]:
        """Coarse density pass (no gradient) -> PDF fine samples -> heads on samples with weight > threshold.
        `routed`: add the training-only routed copies of the outputs (`density_gradient_scales`). `density_scale`:
        scale of the gradient every output sends the density (the renders of one loss term: blur, events). `heads`:
        the heads to evaluate ("rgb", "thermal", "temperature"; None: all; a side render whose loss reads only "rgb"
        skips the others)."""
        with torch.no_grad():
            samples_coarse = self.sampler_coarse(ray_bundle)
            density_coarse, _ = self.field.get_density(samples_coarse)
            weights_coarse = torch.nan_to_num(samples_coarse.get_weights(density_coarse))
        samples = self.sampler_pdf(ray_bundle, samples_coarse, weights_coarse)
        coords, inside = self.field.to_grid(samples.frustums.get_positions())
        corners = self.field.corners(coords.reshape(-1, 3))  # shared by the density and both appearance volumes
        density = self.field.density_at(coords, inside, corners)
        weights = torch.nan_to_num(samples.get_weights(density))  # [rays, samples, 1]
        if density_scale != 1.0:
            weights = losses.scale_gradient(weights, density_scale)
        dense = self.head_values(samples, coords, corners, weights, heads)
        accumulation = self.renderer_accumulation(weights).clamp(0.0, 1.0)
        # "rgb" first: the viewer shows the first output when it opens
        outputs: Dict[str, Tensor] = {
            name: self.composite(weights, accumulation, values) for name, values in dense.items()
        }
        fruit_depth: Optional[Tensor] = None
        if self.fruit_head is not None and (heads is None or "fruit" in heads):
            features = self.field.density_encoding.features(corners)
            fruit_weights = weights
            if self.config.fruit_in_box_only:  # fruit only where the grids have their full resolution
                in_box = self.field.full_resolution(samples.frustums.get_positions())
                fruit_weights = weights * in_box[..., None]
            distances = None if self.training else (samples.frustums.starts + samples.frustums.ends) / 2
            outputs["fruit"], fruit_depth = self.fruit_head.render(
                features, coords.reshape(-1, 3), fruit_weights, distances
            )
        outputs["depth"] = self.renderer_depth(weights, samples)
        if fruit_depth is not None:  # eval: where along the ray the head puts the fruit (counting lifts by it)
            outputs["fruit_depth"] = torch.where(fruit_depth.isnan(), outputs["depth"], fruit_depth)
        outputs["accumulation"] = accumulation
        if not self.training:  # where the weight falls and how fine the grid is there (`grid_diagnostics`)
            final = self.config.final_resolution
            outputs.update(grid_diagnostics(self.field, final, ray_bundle, samples, weights, outputs["depth"]))
        if routed and self.training and torch.is_grad_enabled():
            outputs.update(routed_outputs(self.plan.density_gradient_scales, weights, dense, self.composite))
        if not self.training:
            for name in dense:
                if name != "temperature":
                    outputs[name] = outputs[name].clamp(0.0, 1.0)
        return outputs

    def head_values(
        self,
        samples: RaySamples,
        coords: Float[Tensor, "rays samples 3"],
        corners: VMCorners,
        weights: Float[Tensor, "rays samples 1"],
        heads: Optional[Tuple[str, ...]],
    ) -> Dict[str, Tensor]:
        """Per output, the heads' values at every fine sample: evaluated where the weight passes the threshold
        (TensoRF's app mask; every sample where most do, `DENSE_HEADS_FRACTION`), zero elsewhere."""
        num_rays, num_samples = weights.shape[:2]
        selected = weights[..., 0] > self.config.weight_threshold
        if self.config.background_color == "last_sample":
            selected[:, -1] = True
        directions = samples.frustums.directions.expand(num_rays, num_samples, 3)
        every_sample = not prune_on(weights) or float(selected.float().mean()) >= DENSE_HEADS_FRACTION
        if heads is not None and not heads:
            flat_values = {}
        elif every_sample:  # heads on all samples, masked after: the volumes reuse the density's transposed lookups
            flat_values = self.field.appearance_at(coords.reshape(-1, 3), directions.reshape(-1, 3), corners, heads)
        else:
            flat_values = self.field.appearance_at(
                coords[selected], directions[selected], corners.select(selected.reshape(-1)), heads
            )
        dense: Dict[str, Tensor] = {}
        for head, values in flat_values.items():
            if every_sample:
                full = values.to(weights.dtype).view(num_rays, num_samples, values.shape[-1])
                full = torch.where(selected[..., None], full, 0.0)
            else:
                full = weights.new_zeros(num_rays, num_samples, values.shape[-1])
                full[selected] = values.to(full.dtype)
            if head == FieldHeadNames.RGB:
                dense["rgb"] = full
            elif head == AgriNeRFFieldHeadNames.TEMPERATURE:  # degrees C (an unselected sample: the dataset's mean)
                assert self.field.temperature_head is not None
                dense["temperature"] = self.field.temperature_head.to_celsius(full)
            else:
                dense["thermal"] = full[..., :1]
                if self.plan.has_thermal_camera:
                    dense["thermal_camera"] = full[..., 1:2]
        return dense

    def composite(
        self,
        weights: Float[Tensor, "rays samples 1"],
        accumulation: Float[Tensor, "rays 1"],
        values: Float[Tensor, "rays samples c"],
    ) -> Float[Tensor, "rays c"]:
        """Alpha compositing of per-sample values (`accumulation`: of these `weights`, clamped to [0, 1]), with the
        background behind the last sample."""
        return (weights * values).sum(dim=-2) + self._background(values) * (1.0 - accumulation)

    # --------------------------------------------------------------- losses (loss_routing.py)
    def raw_terms(self, outputs: Dict[str, Tensor], batch: Dict[str, Any]) -> Dict[str, Tensor]:
        """The raw (unweighted) value of every term the plan measures, in the term table's order, each computed by
        its part (`loss_routing.TERMS`); a term without a sample this step is left out."""
        inputs = TermInputs(outputs, batch, self.device, self.training, self.step, raw={})
        for term, row in TERMS.items():
            if term in self.plan.measured:
                value = self.parts[row.part].loss(term, inputs)
                if value is not None:
                    inputs.raw[term] = value
        return inputs.raw

    def get_metrics_dict(self, outputs, batch) -> Dict[str, Tensor]:
        """PSNR of RGB (and thermal) plus the raw loss terms (weighted only in `get_loss_dict`) and the parts'."""
        metrics: Dict[str, Tensor] = {}
        if self.plan.use_rgb and "image" in batch:
            metrics["psnr"] = self.psnr(outputs["rgb"].detach(), batch["image"][..., :3].to(self.device).float())
        metrics.update(self.raw_terms(outputs, batch))
        for term, name in (("thermal_loss", "thermal_psnr"), ("thermal_camera_loss", "thermal_camera_psnr")):
            if term in metrics:
                metrics[name] = -10.0 * torch.log10(metrics[term].detach().clamp(min=1e-10))
        for part in self.parts.values():
            metrics.update(part.metrics(self.training))
        self.camera_optimizer.get_metrics_dict(metrics)
        return metrics

    def get_loss_dict(self, outputs, batch, metrics_dict=None) -> Dict[str, Tensor]:
        """The plan's weighted terms: loss_coefficients x raw terms (from `metrics_dict` when given), then each
        part's own weighting (`ModelPart.weigh`: the EDI prior's decay, the event term's `noise` weighting)."""
        raw = dict(metrics_dict) if metrics_dict is not None else {}
        if not any(k in raw for k in ("rgb_loss", "thermal_loss")):
            raw.update(self.raw_terms(outputs, batch))
        coef = self.config.loss_coefficients  # out of place below: misc.scale_dict would scale the raw metrics too
        loss_dict = {k: v * coef[k] for k, v in raw.items() if k in self.plan.terms}
        inputs = TermInputs(outputs, batch, self.device, self.training, self.step, raw)
        for term, weighted in loss_dict.items():
            loss_dict[term] = self.parts[TERMS[term].part].weigh(term, weighted, inputs)
        self.camera_optimizer.get_loss_dict(loss_dict)
        return loss_dict

    # ----------------------------------------------------------- evaluation (eval_metrics.py)
    def get_outputs_for_camera(self, camera: Cameras, obb_box: Optional[OrientedBox] = None) -> Dict[str, Tensor]:
        """Nerfstudio's render of `camera` and its display outputs; the camera is kept for the thermal metrics."""
        self.eval_camera = camera
        return self.display.add(super().get_outputs_for_camera(camera, obb_box))

    def get_image_metrics_and_images(
        self, outputs: Dict[str, Tensor], batch: Dict[str, Any]
    ) -> Tuple[Dict[str, float], Dict[str, Tensor]]:
        """Held-out metrics and side-by-side images (`eval_metrics.image_metrics_and_images`), the thermal ones as
        the thermal camera saw the held-out view where training used that camera."""
        thermal_outputs = outputs
        if self.thermal_view is not None and self.eval_camera is not None:
            render = self.get_outputs_for_camera_ray_bundle
            fruit = self.plan.fruit_thermal_view
            thermal_outputs = self.thermal_view.eval_outputs(render, self.eval_camera, outputs, fruit)
        return eval_metrics.image_metrics_and_images(self, outputs, thermal_outputs, batch)

    def lpips(self) -> torch.nn.Module:
        """LPIPS (torchmetrics), built on first use: construction loads (or tries to fetch) AlexNet weights, which
        training never needs. Kept out of the module tree, so checkpoints do not carry its weights."""
        if "lpips" not in self._lazy_metrics:
            from torchmetrics.image.lpip import LearnedPerceptualImagePatchSimilarity

            self._lazy_metrics["lpips"] = LearnedPerceptualImagePatchSimilarity(normalize=True).to(self.device)
        return self._lazy_metrics["lpips"]

    def temperature_unit(self, celsius: Tensor) -> Tensor:
        """Degrees C -> [0, 1] over the dataset's temperature range (`display.temperature_unit`)."""
        return display.temperature_unit(celsius, self.temperature_stats)

    def get_rgba_image(self, outputs: Dict[str, Tensor], output_name: str = "rgb") -> Float[Tensor, "*bs 4"]:
        """RGB plus alpha of an output, for Nerfstudio's exporters (`display.rgba_image`). Replaces the base method,
        which reads a `renderer_rgb` this model does not have."""
        return display.rgba_image(outputs, output_name, self.temperature_unit)


@dataclass
class AgriNeRFModelConfig(AgriNeRFSettings):
    """AgriNeRF model config: the settings (`model_config.AgriNeRFSettings`, defaults: the paper's) and the model
    they build."""

    _target: Type = field(default_factory=lambda: AgriNeRFModel)
    """target class to instantiate"""
