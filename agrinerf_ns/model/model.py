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
from nerfstudio.cameras.rays import RayBundle
from nerfstudio.data.scene_box import OrientedBox
from nerfstudio.engine.callbacks import TrainingCallback, TrainingCallbackAttributes, TrainingCallbackLocation
from nerfstudio.field_components.field_heads import FieldHeadNames
from nerfstudio.model_components.ray_samplers import PDFSampler, UniformLinDispPiecewiseSampler, UniformSampler
from nerfstudio.model_components.renderers import AccumulationRenderer, DepthRenderer
from nerfstudio.model_components.scene_colliders import AABBBoxCollider, NearFarCollider, SceneCollider
from nerfstudio.models.base_model import Model
from nerfstudio.utils import colormaps
from nerfstudio.utils.rich_utils import CONSOLE
from torch import Tensor
from torch.nn import Parameter

from agrinerf_ns import cpu_memory
from agrinerf_ns.model import display, edi_prior, eval_metrics, losses
from agrinerf_ns.model.blur_term import BlurTerm
from agrinerf_ns.model.box_sampler import BoxPiecewiseSampler
from agrinerf_ns.model.device_sync import prune_on
from agrinerf_ns.model.event_crf import EventCRF
from agrinerf_ns.model.event_term import EventTerm
from agrinerf_ns.model.field import AgriNeRFField
from agrinerf_ns.model.field_heads import AgriNeRFFieldHeadNames
from agrinerf_ns.model.fruit_head import FruitHead
from agrinerf_ns.model.grid_mapping import fit_box as fit_box_to_points
from agrinerf_ns.model.grid_schedule import GridSchedule
from agrinerf_ns.model.loss_routing import DataTerms, regularisers, routed_outputs
from agrinerf_ns.model.model_config import AgriNeRFSettings
from agrinerf_ns.model.plan import ModelPlan, resolve_plan
from agrinerf_ns.model.rig import SIDE_STREAM_SEED, Rig, side_stream
from agrinerf_ns.model.rigid_blur import RigidBlurKernel
from agrinerf_ns.model.thermal_view import ThermalView

DENSE_HEADS_FRACTION = 0.85
"""When at least this fraction of the fine samples passes the weight threshold (usual: the PDF samples sit where the
weights are), the heads run on every sample and the others are masked: gathering the selected ones would cost a copy of
their lookup corners and a second transposed lookup for the backward pass, more than the few extra samples."""


OLD_STATE_NAMES = {"log_event_threshold": "events.log_threshold", "event_crf.": "events.crf."}
"""State-dict names of runs before the event term became a part (old prefix -> new)."""


class AgriNeRFModel(Model):
    """AgriNeRF: shared TensoRF geometry, RGB and cross-spectral thermal heads, built for the scene's modalities.

    Its optional terms are parts built from the plan (`plan.py`), each given the render call (`render_rays`) and the
    field, not the model: the blur model (`blur_term.BlurTerm`), the event loss and EDI prior
    (`event_term.EventTerm`), the thermal camera's view (`thermal_view.ThermalView`), the fruit head
    (`fruit_head.FruitHead`), the grid schedule (`grid_schedule.GridSchedule`) and the data terms
    (`loss_routing.DataTerms`).

    Args:
        config: model config.
        metadata (kwarg): the train dataset's metadata; its "modalities" (from the dataparser) are intersected with
            `config.modalities`. Without it the dataset is taken to be RGB only.
    """

    config: AgriNeRFSettings
    collider: SceneCollider

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
        self._register_load_state_dict_pre_hook(_load_old_state, with_module=True)
        self.display = display.DisplayOutputs.of(self, metadata)  # rgb_display, temperature_display, viewer controls

    # ------------------------------------------------------------------ setup
    def populate_modules(self) -> None:
        """Fields, samplers, renderers, colliders, metrics, and the parts the plan switches on."""
        super().populate_modules()
        cfg, plan = self.config, self.plan

        self.blur_kernel: Optional[RigidBlurKernel] = None  # EvDeblurNeRF's learnt kernel (config `blur_kernel`)
        crf: Optional[EventCRF] = None  # EvDeblurNeRF's learnt event response (config `event_crf`)
        with torch.random.fork_rng(devices=[]):  # optional parts leave the field's (and the batches') draws alone
            torch.manual_seed(SIDE_STREAM_SEED)
            if plan.blur == "learnt":
                self.blur_kernel = RigidBlurKernel(self.num_train_data, num_motions=cfg.blur_samples - 1)
            if plan.event_supervision == "pairs" and cfg.event_crf:
                crf = EventCRF()
        self.events: Optional[EventTerm] = None
        if plan.use_event_loss or plan.edi_prior:
            self.events = EventTerm(cfg, plan, self.rig, crf)

        # fields
        self.field = AgriNeRFField(
            self.scene_box.aabb,
            contraction=cfg.scene_contraction,
            resolution=cfg.init_resolution,
            num_density_components=cfg.num_density_components,
            with_rgb=plan.use_rgb,
            with_thermal=plan.has_thermal_head,
            num_rgb_components=cfg.num_rgb_components,
            rgb_appearance_dim=cfg.rgb_appearance_dim,
            num_thermal_components=cfg.num_thermal_components,
            thermal_appearance_dim=cfg.thermal_appearance_dim,
            thermal_view_dependent=cfg.thermal_view_dependent,
            thermal_channels=2 if plan.has_thermal_camera else 1,
            temperature_stats=(self.temperature_stats["mean_c"], self.temperature_stats["std_c"])
            if plan.has_temperature and self.temperature_stats is not None
            else None,
            temperature_mlp_width=cfg.temperature_mlp_width,
            mlp_width=cfg.mlp_width,
            thermal_mlp_width=cfg.thermal_mlp_width,
            density_shift=cfg.density_shift,
            max_density=cfg.max_density,
            occupancy_resolution=cfg.occupancy_resolution,
            vm_lookup=cfg.vm_lookup,
        )

        self.fruit_head: Optional[FruitHead] = None  # where the frames have fruit masks (fruit_head.py)
        if plan.has_fruit_head:
            # an optional part leaves the field's (and the batches') draws alone
            with torch.random.fork_rng(devices=[]):
                torch.manual_seed(SIDE_STREAM_SEED)
                features = self.field.density_encoding.get_out_dim()
                self.fruit_head = FruitHead(
                    features, cfg.fruit_mlp_width, cfg.fruit_shapes_geometry, cfg.fruit_position_octaves
                )

        # the first full-resolution box: around the dataset's SfM points where it has them (refitted in training)
        points = (self.kwargs.get("metadata") or {}).get("points3D_xyz")
        if self.field.mapping is not None and points is not None:
            box = fit_box_to_points(torch.as_tensor(points, dtype=torch.float32))  # cpu: before model.to(device)
            if box is not None:
                self.field.refit_box(box, cfg.box_grid_fraction, cfg.init_resolution)

        # the parts that are no modules: each given the field or the render call, not the model
        self.grid = GridSchedule(cfg, self.field, self.metres_per_unit)
        self.blur = (
            None if not plan.use_blur else BlurTerm(self.rig, cfg.blur_samples, cfg.blur_start_step, self.blur_kernel)
        )
        self.thermal_view = ThermalView(self.rig, cfg.thermal_rays_per_batch) if plan.thermal_camera_rays else None
        self.data_terms = DataTerms(plan, cfg.loss_coefficients, self.events, self.field.temperature_head)

        # samplers
        if cfg.scene_contraction and cfg.coarse_sampler == "box":
            self.sampler_coarse = BoxPiecewiseSampler(cfg.num_coarse_samples, box=self.field.full_resolution_box)
        elif cfg.scene_contraction:
            self.sampler_coarse = UniformLinDispPiecewiseSampler(
                num_samples=cfg.num_coarse_samples, single_jitter=False
            )
        else:
            self.sampler_coarse = UniformSampler(num_samples=cfg.num_coarse_samples, single_jitter=False)
        self.sampler_pdf = PDFSampler(
            num_samples=cfg.num_fine_samples, single_jitter=False, include_original=cfg.fine_include_coarse
        )

        # renderers
        self.renderer_accumulation = AccumulationRenderer()
        self.renderer_depth = DepthRenderer(method="median")

        # colliders
        if cfg.scene_contraction:
            self.collider = NearFarCollider(near_plane=cfg.near_plane, far_plane=cfg.far_plane)
        else:
            self.collider = AABBBoxCollider(scene_box=self.scene_box, near_plane=cfg.near_plane)

        # metrics
        from torchmetrics.functional import structural_similarity_index_measure
        from torchmetrics.image import PeakSignalNoiseRatio

        self.psnr = PeakSignalNoiseRatio(data_range=1.0)
        self.ssim = structural_similarity_index_measure
        self._lazy_metrics: Dict[str, torch.nn.Module] = {}  # a plain dict: not a submodule, not in checkpoints

        self.camera_optimizer: CameraOptimizer = cfg.camera_optimizer.setup(
            num_cameras=self.num_train_data, device="cpu"
        )

    def get_param_groups(self) -> Dict[str, List[Parameter]]:
        """Groups "fields" (MLPs and bases) and "encodings" (every TensoRF volume), plus camera_opt when enabled."""
        heads = [h for h in (self.field.rgb_head, self.field.thermal_head) if h is not None]
        groups: Dict[str, List[Parameter]] = {
            "fields": [p for h in heads for p in h.mlp_parameters()]
            + (list(self.field.temperature_head.parameters()) if self.field.temperature_head is not None else []),
            "encodings": [p for vol in self.field.volumes().values() for p in vol.parameters()],
        }
        if self.events is not None and self.events.log_threshold is not None:
            groups["fields"].append(self.events.log_threshold)
        if self.fruit_head is not None:
            groups["fields"] += list(self.fruit_head.parameters())
        if self.blur_kernel is not None:
            groups["blur_kernel"] = list(self.blur_kernel.parameters())
        if self.events is not None and self.events.crf is not None:
            groups["event_crf"] = list(self.events.crf.parameters())
        self.camera_optimizer.get_param_groups(param_groups=groups)
        return groups

    def get_training_callbacks(
        self, training_callback_attributes: TrainingCallbackAttributes
    ) -> List[TrainingCallback]:
        """The step kept for the parts that start late, then the grid schedule's upsampling, box fits and occupancy
        updates (`GridSchedule.callbacks`)."""

        def keep_step(step: int) -> None:
            self.step = step

        before = [TrainingCallbackLocation.BEFORE_TRAIN_ITERATION]
        keep = TrainingCallback(where_to_run=before, update_every_num_iters=1, func=keep_step)
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
                if self.blur is not None:
                    sharp = outputs.get("rgb/rgb_loss", outputs["rgb"])  # the frame ray's render for the RGB loss
                    outputs.update(self.blur.outputs(self.render_rays, ray_bundle, sharp, self.step))
                if self.thermal_view is not None and self.plan.thermal_view:
                    fruit = self.plan.fruit_thermal_view
                    outputs.update(self.thermal_view.outputs(self.render_rays, ray_bundle, fruit))
                if self.events is not None:
                    outputs.update(self.events.outputs(self.render_rays, ray_bundle, self.step))
        return outputs

    def render_rays(self, bundle: RayBundle, heads: Tuple[str, ...], term: Optional[str] = None) -> Dict[str, Tensor]:
        """A part's render of a side bundle (`rig.RenderRays`): collided, then rendered with `term`'s density
        gradient scale and no routed copies, or (term None) at full scale with them."""
        if term is None:
            return self.render(self.collider(bundle), heads=heads)
        scale = self.density_gradient_scale(term)
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

        dense: Dict[str, Tensor] = {}  # per output: the head's values at every sample (zero where not selected)
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
            positions = samples.frustums.get_positions()
            inside = self.field.full_resolution(positions).to(weights.dtype)[..., None]
            outputs["full_resolution_weight"] = (weights * inside).sum(dim=-2)
            surface = ray_bundle.origins + ray_bundle.directions * outputs["depth"]
            outputs["voxel_size"] = self.field.voxel_size(surface).amax(dim=-1, keepdim=True)
            final = self.field.axis_resolution(self.config.final_resolution)
            outputs["voxel_size_final"] = self.field.voxel_size(surface, final).amax(dim=-1, keepdim=True)
        if routed and self.training and torch.is_grad_enabled():
            outputs.update(routed_outputs(self.plan.density_gradient_scales, weights, dense, self.composite))
        if not self.training:
            for name in dense:
                if name != "temperature":
                    outputs[name] = outputs[name].clamp(0.0, 1.0)
        return outputs

    def composite(
        self,
        weights: Float[Tensor, "rays samples 1"],
        accumulation: Float[Tensor, "rays 1"],
        values: Float[Tensor, "rays samples c"],
    ) -> Float[Tensor, "rays c"]:
        """Alpha compositing of per-sample values (`accumulation`: of these `weights`, clamped to [0, 1]), with the
        background behind the last sample."""
        return (weights * values).sum(dim=-2) + self._background(values) * (1.0 - accumulation)

    def density_gradient_scale(self, term: str) -> float:
        """The scale of `term`'s gradient into the density (1 when not configured; `low_light_level` raises the
        thermal-camera term's to 1 in low light)."""
        return self.plan.density_gradient_scales.get(term, 1.0)

    # --------------------------------------------------------------- losses (loss_routing.py)
    def get_metrics_dict(self, outputs, batch) -> Dict[str, Tensor]:
        """PSNR of RGB (and thermal) plus the raw loss terms (weighted only in `get_loss_dict`)."""
        metrics: Dict[str, Tensor] = {}
        if self.plan.use_rgb and "image" in batch:
            metrics["psnr"] = self.psnr(outputs["rgb"].detach(), batch["image"][..., :3].to(self.device).float())
        metrics.update(self.data_terms(outputs, batch, self.device))
        for term, name in (("thermal_loss", "thermal_psnr"), ("thermal_camera_loss", "thermal_camera_psnr")):
            if term in metrics:
                metrics[name] = -10.0 * torch.log10(metrics[term].detach().clamp(min=1e-10))
        if self.training:
            metrics.update(regularisers(self.field, self.config.loss_coefficients))
        if self.events is not None:
            metrics.update(self.events.metrics(self.training))
        self.camera_optimizer.get_metrics_dict(metrics)
        return metrics

    def get_loss_dict(self, outputs, batch, metrics_dict=None) -> Dict[str, Tensor]:
        """Weighted loss terms: loss_coefficients x raw terms (from `metrics_dict` when given), with the EDI prior's
        decay and the event term's `noise` weighting."""
        raw = dict(metrics_dict) if metrics_dict is not None else {}
        if not any(k in raw for k in ("rgb_loss", "thermal_loss")):
            raw.update(self.data_terms(outputs, batch, self.device))
            if self.training:
                raw.update(regularisers(self.field, self.config.loss_coefficients))
        coef = self.config.loss_coefficients  # out of place below: misc.scale_dict would scale the raw metrics too
        loss_dict = {k: v * coef[k] for k, v in raw.items() if coef.get(k, 0.0) > 0}
        if "edi_prior_loss" in loss_dict:  # EvDeblurNeRF's cosine-decayed weight
            loss_dict["edi_prior_loss"] = loss_dict["edi_prior_loss"] * edi_prior.cosine_weight(self.step)
        if "event_loss" in loss_dict and self.events is not None:  # the `noise` weighting and the data gate
            loss_dict["event_loss"] = self.events.weighted_loss(loss_dict["event_loss"], raw, outputs)
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
        """Degrees C -> [0, 1] over the dataset's temperature range (colours of the `temperature` output)."""
        stats = self.temperature_stats or {"min_c": 0.0, "max_c": 1.0}
        low, high = stats["min_c"], max(stats["max_c"], stats["min_c"] + 1e-3)
        return ((celsius - low) / (high - low)).clamp(0.0, 1.0)

    # ----------------------------------------------------------- exporters
    def get_rgba_image(self, outputs: Dict[str, Tensor], output_name: str = "rgb") -> Float[Tensor, "*bs 4"]:
        """RGB plus alpha of an output, for Nerfstudio's exporters (`ns-export pointcloud`, `tsdf`, `poisson`).

        Alpha is the accumulation, so a ray that hits nothing (accumulation below 0.5, where the median depth is
        not a surface) gives no point. A single-channel output (`thermal`) is coloured by Nerfstudio's colormap for
        one channel (turbo, unnormalised: colours mean the same value in every export). Replaces the base method,
        which reads a `renderer_rgb` this model does not have.
        """
        image = outputs[output_name]
        if output_name == "temperature":
            image = self.temperature_unit(image)
        if image.shape[-1] not in (1, 3):
            raise ValueError(f"Output '{output_name}' has {image.shape[-1]} channels; an RGBA export needs 1 or 3")
        colours = colormaps.apply_colormap(image.clamp(0.0, 1.0))
        return torch.cat([colours, outputs["accumulation"].to(colours.dtype)], dim=-1)


def _load_old_state(model: AgriNeRFModel, state_dict: Dict[str, Any], prefix: str, *args: Any) -> None:
    """Load the checkpoint of a run before the event term became a part: its learnt thresholds and event response
    under their new names, and the `noise` weighting's running means (not saved then) at their start."""
    for key in list(state_dict):
        for old, new in OLD_STATE_NAMES.items():
            if key.startswith(prefix + old):
                state_dict[prefix + new + key[len(prefix + old) :]] = state_dict.pop(key)
    if model.events is not None:
        for name, buffer in model.events.named_buffers():
            state_dict.setdefault(f"{prefix}events.{name}", buffer.clone())


@dataclass
class AgriNeRFModelConfig(AgriNeRFSettings):
    """AgriNeRF model config: the settings (`model_config.AgriNeRFSettings`, defaults: the paper's) and the model
    they build."""

    _target: Type = field(default_factory=lambda: AgriNeRFModel)
    """target class to instantiate"""
