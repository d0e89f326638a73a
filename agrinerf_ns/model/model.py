"""AgriNeRF model: coarse uniform + fine PDF samples through a shared-density TensoRF with RGB and thermal heads.

Paper: ../shared/paper/agrinerf_paper.tex (Method; Implementation Details). Losses: L = L_rgb + L_th + L_reg
(+ TensoRF L1 and TV regularisers), weights in `loss_coefficients`, raw terms in the metrics (as `depth_nerfacto`).
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass, field
from typing import Any, Dict, Iterator, List, Literal, Optional, Tuple, Type

import numpy as np
import torch
from jaxtyping import Float
from nerfstudio.cameras.camera_optimizers import CameraOptimizer, CameraOptimizerConfig
from nerfstudio.cameras.rays import RayBundle
from nerfstudio.configs.config_utils import to_immutable_dict
from nerfstudio.engine.callbacks import TrainingCallback, TrainingCallbackAttributes, TrainingCallbackLocation
from nerfstudio.engine.optimizers import Optimizers
from nerfstudio.field_components.field_heads import FieldHeadNames
from nerfstudio.model_components.ray_samplers import PDFSampler, UniformLinDispPiecewiseSampler, UniformSampler
from nerfstudio.model_components.renderers import AccumulationRenderer, DepthRenderer
from nerfstudio.model_components.scene_colliders import AABBBoxCollider, NearFarCollider
from nerfstudio.models.base_model import Model, ModelConfig
from nerfstudio.utils import colormaps
from nerfstudio.utils.rich_utils import CONSOLE
from torch import Tensor
from torch.nn import Parameter

from agrinerf_ns.modalities import ALL_MODALITIES, Modality, normalise_modalities
from agrinerf_ns.model import edi_prior, losses
from agrinerf_ns.model.box_sampler import BoxPiecewiseSampler
from agrinerf_ns.model.event_crf import EventCRF
from agrinerf_ns.model.event_pairs import EventPairs
from agrinerf_ns.model.event_stream import EventCamera, EventStream
from agrinerf_ns.model.field import AgriNeRFField
from agrinerf_ns.model.field_heads import AgriNeRFFieldHeadNames
from agrinerf_ns.model.grid_mapping import fit_box
from agrinerf_ns.model.rigid_blur import RigidBlurKernel
from agrinerf_ns.model.vm_encoding import VMLookup, plane_tv

TERM_OUTPUTS: Dict[str, str] = {
    "rgb_loss": "rgb",
    "thermal_loss": "thermal",
    "reg_rgb_loss": "thermal",
    "reg_event_loss": "thermal",
    "thermal_camera_loss": "thermal_camera",
    "event_loss": "rgb",
    "temperature_loss": "temperature",
    "edi_prior_loss": "rgb",
}
"""Each data loss term and the output it compares with its target."""

PAPER_DENSITY_GRADIENT_SCALES: Dict[str, float] = {term: 1.0 for term in TERM_OUTPUTS}
"""Every term moves the shared density at full strength: the paper's loss as written, with one thermal output."""

SIDE_STREAM_SEED = 20_261_202
"""Seed of the blur and event renders' random stream at step 0 (`AgriNeRFModel._side_stream`)."""

DENSE_HEADS_FRACTION = 0.85
"""When at least this fraction of the fine samples passes the weight threshold (usual: the PDF samples sit where the
weights are), the heads run on every sample and the others are masked: gathering the selected ones would cost a copy of
their lookup corners and a second transposed lookup for the backward pass, more than the few extra samples."""


@dataclass
class AgriNeRFModelConfig(ModelConfig):
    """AgriNeRF model config (defaults: the paper's settings)."""

    _target: Type = field(default_factory=lambda: AgriNeRFModel)
    """target class to instantiate"""
    modalities: Tuple[Modality, ...] = ALL_MODALITIES
    """Modalities to model; intersected with the dataset's. "rgb" builds the RGB head and L_rgb; "thermal" builds the
    thermal head and L_th; "events" adds the event term of L_reg. The thermal (cross-spectral) head is also built for
    "events" without "thermal" (Table IV "RGB+Events": it is then learnt from L_reg alone). Table IV rows:
    rgb | rgb events | rgb thermal | thermal | thermal events | rgb thermal events."""
    init_resolution: int = 128
    """Initial resolution (per axis) of every TensoRF volume."""
    final_resolution: int = 300
    """Resolution after the last upsampling step."""
    upsampling_iters: Tuple[int, ...] = (2000, 3000, 4000, 5500, 7000)
    """Steps after which all volumes are upsampled (log-spaced resolutions from init to final, as TensoRF)."""
    num_coarse_samples: int = 64
    """Coarse samples per ray (density only, no gradient)."""
    coarse_sampler: Literal["box", "lindisp"] = "box"
    """Spacing of the coarse samples (scene contraction only). box: half uniform up to where the ray leaves the
    full-resolution box, half linear in disparity beyond (`BoxPiecewiseSampler`). lindisp: Nerfstudio's
    `UniformLinDispPiecewiseSampler` (half uniform up to distance 1)."""
    num_fine_samples: int = 64
    """Fine samples per ray drawn from the coarse weights (PDF)."""
    fine_include_coarse: bool = False
    """Render from coarse + fine samples (NeRF style) instead of the fine samples alone (faster)."""
    num_density_components: int = 16
    """VM components of the shared density volume."""
    num_rgb_components: int = 48
    """VM components of the RGB appearance volume."""
    rgb_appearance_dim: int = 27
    """Feature size fed to MLP_RGB."""
    num_thermal_components: int = 16
    """VM components of the thermal appearance volume."""
    thermal_appearance_dim: int = 12
    """Feature size fed to MLP_THERMAL."""
    thermal_view_dependent: bool = False
    """Feed the viewing direction to MLP_THERMAL."""
    cross_spectral_output: bool = True
    """Build the cross-spectral `thermal` head (and L_reg) for a scene with events but no thermal frames (Table IV
    "RGB+Events"); False: such a scene gets no thermal head (the EvDeblurNeRF baseline). With thermal frames the head
    is always built."""
    thermal_camera_output: bool = True
    """Give MLP_THERMAL a second channel, the output `thermal_camera`, fit to the thermal frames alone by
    `thermal_camera_loss` (built only when the scene has thermal frames). The cross-spectral `thermal` output cannot
    match thermal frames, RGB luma and event frames at once, so its residual never falls; this channel's target can be
    met, so it is the thermal term that can carry geometry (`density_gradient_scales`; docs/model.md, Loss routing)."""
    density_gradient_scales: Dict[str, float] = to_immutable_dict(
        {
            "rgb_loss": 1.0,
            "thermal_loss": 0.0,
            "reg_rgb_loss": 0.0,
            "reg_event_loss": 0.0,
            "thermal_camera_loss": 0.0,
            "temperature_loss": 0.0,
        }
    )
    """How strongly each data term's gradient reaches the shared density through the rendering weights (1: fully,
    0: not at all; the term still trains its head's appearance volume and MLP either way). Default: only the RGB
    frames shape the geometry; the thermal terms (L_th, L_reg, the thermal-camera term) train the thermal appearance
    on it, since the thermal routes into the density lowered the RGB reconstruction in most scenes measured
    (docs/model.md, Loss routing). All 1 with `thermal_camera_output` False is the paper's loss as written. A term left out of the dict
    counts as 1."""
    low_light_level: float = 0.04
    """Low-light routing: where the training RGB frames' mean value is below this fraction of full scale (dataparser
    metadata `rgb_level`; 0.04 is about 10 DN of 255), the thermal-camera term moves the density at full strength,
    whatever `density_gradient_scales` says of it: frames of a few DN are mostly noise and give the density little,
    while the thermal frames see the scene at any light (docs/model.md, Loss routing). 0: never (the geometry then
    follows `density_gradient_scales` in any light)."""
    low_light_event_loss: bool = False
    """Keep the event loss where the training RGB frames are below `low_light_level`. Off by default: there the event
    loss lowered the RGB reconstruction, most at short budgets (the render's log luminance of a few DN is dominated
    by the log offset, and the events by noise; docs/model.md, Low light)."""
    temperature_output: bool = True
    """A `temperature` output in degrees C, where the dataset has temperature images (its thermal camera has a
    radiometric calibration): a small head on the thermal appearance (`temperature_head.*`, none without them), trained
    by `temperature_loss` (MSE in units of the dataset's temperature standard deviation over the thermal mask), not by
    L_reg, and by default not moving the density (docs/model.md)."""
    temperature_mlp_width: int = 32
    """Hidden width of the temperature head."""
    mlp_width: int = 128
    """Hidden width of MLP_RGB (TensoRF's)."""
    thermal_mlp_width: int = 64
    """Hidden width of MLP_THERMAL (one view-independent channel: half of MLP_RGB's width costs half as much)."""
    density_shift: float = -4.0
    """Added to the summed density features before the softplus: zero features (where the L1 regulariser drives
    empty space) give softplus(-4) = 0.018, below `occupancy_density_threshold`, so empty cells can be pruned."""
    max_density: float = 1.0e4
    """Densities are clamped here (no Inf in alpha compositing)."""
    scene_contraction: bool = True
    """Contract unbounded space (L-inf SceneContraction) so sky and far trees fit in the volumes; rays then run from
    near_plane to far_plane. False: bounded scene box (rays clipped to it, like Nerfstudio's tensorf)."""
    near_plane: float = 0.05
    """Near plane of every ray."""
    far_plane: float = 1000.0
    """Far plane of every ray (scene contraction only)."""
    background_color: Literal["last_sample", "black", "white"] = "last_sample"
    """Colour (and thermal value) behind the last sample; "last_sample" uses the last sample's value."""
    weight_threshold: float = 1.0e-4
    """Fine samples whose rendering weight is below this skip the appearance heads (TensoRF's app mask)."""
    box_fit_iters: Tuple[int, ...] = (100, 300, 1000)
    """Steps after which the full-resolution box is fitted to the scene (`grid_mapping.fit_box` on the median-depth
    points of `box_fit_rays` rendered training rays) and every volume resampled into it; () keeps the first box (the
    SfM points' box where the dataset has them, else the scene box around the cameras). Contraction only."""
    box_fit_rays: int = 8192
    """Training rays rendered for each box fit."""
    box_grid_fraction: float = 0.8
    """Fraction of each grid axis that the fitted box spans (the rest holds the contracted sky and far background)."""
    box_fit_growth: float = 8.0
    """The first fit (at the first of `box_fit_iters`) may grow the box to at most this many times its size about its
    centre (an early, still blurry field cannot throw the box far out)."""
    box_refit_growth: float = 1.0
    """Each later fit may grow the box at most this many times (1: shrink only, as TensoRF's `shrink`). Floaters that a
    dark, noisy capture grows before its field settles would otherwise widen the box and coarsen its voxels."""
    box_depth_cut: float = 2.5
    """Surface points farther from their camera than this times the median distance are background, outside the box
    (sky, hedges, far rows)."""
    occupancy_resolution: int = 64
    """Cells per axis of the occupancy grid that prunes empty space (0: no pruning)."""
    occupancy_update_iters: Tuple[int, ...] = (2000, 4000, 6000)
    """Steps after which the occupancy grid is recomputed from the density volume."""
    occupancy_density_threshold: float = 0.1
    """A cell whose density (centre and a jittered point) stays below this is empty (then dilated by one cell)."""
    vm_lookup: VMLookup = "auto"
    """How the TensoRF volumes are sampled: "rows" (weighted row sums, cheaper to train on a CPU: docs/model.md),
    "grid_sample" (Nerfstudio's lookup), "auto" (rows on a CPU, grid_sample on a GPU, where rows are unmeasured)."""
    loss_coefficients: Dict[str, float] = to_immutable_dict(
        {
            "rgb_loss": 1.0,
            "thermal_loss": 1.0,
            "reg_rgb_loss": 1.0,
            "reg_event_loss": 1.0,
            "thermal_camera_loss": 1.0,
            "event_loss": 0.1,
            "temperature_loss": 1.0,
            "edi_prior_loss": 1.0,
            "l1_reg": 5.0e-4,
            "tv_reg_density": 1.0e-3,
            "tv_reg_appearance": 1.0e-4,
        }
    )
    """Weights: paper L = L_rgb + L_th + L_reg (reg_rgb_loss + reg_event_loss), plus the thermal-camera term and TensoRF
    L1/TV; 0 disables a term."""
    blur_samples: int = 1
    """Blur model: a training frame's pixel is compared with the mean, in linear radiance, of this many renders at
    poses spread over the frame's exposure (the dataset's exposure intervals and camera trajectory). 1: the frame's
    own pose only (no blur model). Evaluation always renders the sharp frame pose."""
    blur_start_step: int = 0
    """Training step from which the blur model runs (EvDeblurNeRF starts it after about 1200 steps)."""
    event_rays_per_batch: int = 0
    """Event samples per batch for the event loss (`event_supervision`), each rendered at the start and end of its
    window; 0: no event loss (the default; the `agrinerf` and `evdeblurnerf` presets turn it on)."""
    event_threshold: float = 0.2
    """Contrast threshold C (ON and OFF) of the event loss: 0.2 is the synthetic camera's mean (and EvDeblurNeRF's
    synthetic setting); real Prophesee/DAVIS captures are nearer 0.25."""
    event_supervision: Literal["pairs", "stream", "frames"] = "stream"
    """What the event loss reads. pairs: EvDeblurNeRF's event-to-event samples: an event that has a successor at its
    pixel, drawn uniformly over the stream, rendered along the event pixel's ray at both events' times, target C times
    the successor's polarity, response log(BT.601 luma of the linear render (after the learnt `event_crf`) + eps)
    (`model/event_pairs.py`). stream: the events at the event camera's own pixels in random sub-windows of the frames'
    windows, target C (N_on - N_off), pixels without events included, response log(Rec. 709 luminance + eps). Both
    read the dataset's ``events/stream.h5`` (datasets without one fall back to frames). frames: the per-frame counts
    warped into the RGB pixels, on the batch's RGB pixels."""
    event_window_min_fraction: float = 0.25
    """stream: each event pixel's window is a random sub-window of its frame's event window, its length uniform in
    [this, 1] of the window (1: whole frame windows)."""
    event_threshold_learnt: bool = False
    """Learn the contrast thresholds (one for ON, one for OFF, scene-wide, from `event_threshold`) with the field.
    Where the sensor under-reports large changes (refractory period, bandwidth), fixed thresholds pull the
    reconstruction towards less contrast; learnt ones follow the contrast the frames give, and the events then say
    where and when the log luminance changes (E-NeRF and Robust e-NeRF treat unknown thresholds this way)."""
    event_loss_bound: bool = False
    """Read each event count as a lower bound on the change in its direction (`losses.event_loss`, `lower_bound`):
    the sensor drops events at large, fast changes (refractory period), so a squared loss on the count pulls strong
    edges towards less contrast."""
    event_loss_weighting: Literal["fixed", "noise"] = "fixed"
    """fixed: the event term weighs loss_coefficients["event_loss"] (EvDeblurNeRF's 0.1). noise: that coefficient times
    (event pixels / RGB rays) x (running mean RGB loss / running mean event loss), the maximum-likelihood balance of
    two Gaussian terms whose variances are their running losses (at most 1: an event sample never counts more than an
    RGB ray): noisy RGB (the dark) gives the events more weight, noisy events (refractory losses, noise events)
    less."""
    event_log_eps: float = 1.0e-4
    """Offset of the event response log(Y + eps), in the linear units of the rendered colour."""
    camera_optimizer: CameraOptimizerConfig = field(default_factory=lambda: CameraOptimizerConfig(mode="off"))
    """Camera pose refinement (off by default)."""
    blur_kernel: Literal["trajectory", "learnt"] = "trajectory"
    """The blur model's kernel (`blur_samples` rays per blurred pixel, from `blur_start_step`). trajectory: poses from
    the rig's known trajectory at equal parts of the exposure, equal weights (what a rig with poses can afford).
    learnt: EvDeblurNeRF's (DP-NeRF's) rigid blur kernel, the frame ray and `blur_samples` - 1 copies moved by learnt
    SE(3) motions, blended with learnt weights, from a per-image latent code (`model/rigid_blur.py`; EvDeblurNeRF: 10
    rays from step 1200); needs no trajectory. Its adaptive weight proposal is not reproduced."""
    event_crf: bool = False
    """Pairs supervision: learn EvDeblurNeRF's event camera response (`model/event_crf.py`; an MLP on each linear
    channel and the successor's polarity, fit to the identity first) from `event_crf_start_step`."""
    event_crf_start_step: int = 1200
    """Step from which the event response is learnt (the identity before; EvDeblurNeRF: 1200)."""
    edi_prior: bool = False
    """EvDeblurNeRF's EDI prior: the frame ray's colour against the event-deblurred frame (`model/edi_prior.py`:
    events at the event camera's pixel that sees the RGB pixel on the alignment plane, 9 times across the exposure),
    weight 0.01 decayed on a cosine to 1e-5 over 10k steps (times `loss_coefficients.edi_prior_loss`), from step 0.
    Needs the event stream, its calibration and the frames' exposures."""


class AgriNeRFModel(Model):
    """AgriNeRF: shared TensoRF geometry, RGB and cross-spectral thermal heads, built for the scene's modalities.

    Args:
        config: model config.
        metadata (kwarg): the train dataset's metadata; its "modalities" (from the dataparser) are intersected with
            `config.modalities`. Without it the dataset is taken to be RGB only.
    """

    config: AgriNeRFModelConfig

    def __init__(self, config: AgriNeRFModelConfig, **kwargs) -> None:
        metadata = kwargs.get("metadata") or {}
        dataset_modalities = normalise_modalities(metadata.get("modalities", ("rgb",)))
        wanted = normalise_modalities(config.modalities)
        self.modalities: Tuple[str, ...] = tuple(m for m in wanted if m in dataset_modalities)
        self.use_rgb = "rgb" in self.modalities
        self.use_thermal = "thermal" in self.modalities
        self.use_events = "events" in self.modalities
        self.has_thermal_head = self.use_thermal or (self.use_events and config.cross_spectral_output)
        self.has_thermal_camera = self.use_thermal and config.thermal_camera_output
        rgb_level = float(metadata.get("rgb_level", float("nan")))
        # NaN (no level recorded) compares False: no low-light rule
        dark = rgb_level < config.low_light_level
        self.low_light = self.has_thermal_camera and dark
        # the density gradient scales in force: the configured ones, the thermal-camera term at full strength in low light
        self.density_gradient_scales: Dict[str, float] = {
            k: float(v) for k, v in config.density_gradient_scales.items()
        }
        if self.low_light:
            camera_scale = self.density_gradient_scales.get("thermal_camera_loss", 1.0)
            self.density_gradient_scales["thermal_camera_loss"] = max(camera_scale, 1.0)
            CONSOLE.print(
                f"Low light: the RGB frames average {rgb_level:.3f} of full scale (below low_light_level "
                f"{config.low_light_level}), so the thermal-camera term shapes the geometry too."
            )
        # dataset temperatures in degrees C (mean_c, std_c, min_c, max_c): only with a radiometric calibration
        self.temperature_stats: Optional[Dict[str, float]] = metadata.get("temperature_stats")
        # metres per scene unit, where the dataset's poses are metric (dataparser metadata; None: unknown scale)
        self.metres_per_unit: Optional[float] = metadata.get("metres_per_unit")
        self.has_temperature = self.use_thermal and config.temperature_output and self.temperature_stats is not None
        # timing of the training frames (dataparser metadata): what the blur model and the event loss need
        self.frame_times: Optional[Tensor] = metadata.get("times")
        self.exposure: Optional[Tensor] = metadata.get("exposure")
        self.trajectory = metadata.get("trajectory")
        self.event_windows: Optional[Tensor] = metadata.get("event_windows")
        # the event camera's `camera_centre` and `plane_depth` (timed_rays.reposed_rays), where the dataset records them
        self.event_camera: Dict[str, Any] = metadata.get("event_camera") or {}
        self.event_camera_native: Optional[EventCamera] = metadata.get("event_stream")
        timed = self.trajectory is not None and self.frame_times is not None
        self.use_blur = (
            self.use_rgb
            and config.blur_samples > 1
            and (config.blur_kernel == "learnt" or (timed and self.exposure is not None))
        )
        self.use_event_loss = (
            self.use_rgb
            and self.use_events
            and timed
            and self.event_windows is not None
            and config.event_rays_per_batch > 0
            and config.loss_coefficients.get("event_loss", 0.0) > 0
        )
        if self.use_event_loss and dark and not config.low_light_event_loss:
            self.use_event_loss = False
            CONSOLE.print(
                f"Low light: the RGB frames average {rgb_level:.3f} of full scale (below low_light_level "
                f"{config.low_light_level}), so the event loss is off (--pipeline.model.low-light-event-loss True "
                "keeps it)."
            )
        self.event_stream: Optional[EventStream] = None
        if self.use_event_loss and config.event_supervision == "stream" and self.event_camera_native is not None:
            self.event_stream = self.event_camera_native.stream()
        self.event_pairs: Optional[EventPairs] = None
        if self.use_event_loss and config.event_supervision == "pairs" and self.event_camera_native is not None:
            native = self.event_camera_native
            self.event_pairs = EventPairs.from_h5(native.path, native.width, native.height)
        # the EDI prior's counts at the event pixels (EventStream), where its inputs are all there
        self.edi_stream: Optional[EventStream] = None
        if (
            config.edi_prior
            and self.use_rgb
            and self.use_events
            and timed
            and self.exposure is not None
            and self.event_camera_native is not None
        ):
            self.edi_stream = self.event_stream or self.event_camera_native.stream()
        self.step = 0  # training step, kept by a callback (the blur model starts at blur_start_step)
        self._loss_means: Optional[Tuple[float, float]] = None  # running RGB and event losses (`noise` weighting)
        self.event_weight = 0.0  # the `noise` weighting's last factor, logged as a metric
        if not (self.use_rgb or self.use_thermal):
            raise ValueError(
                f"AgriNeRF needs RGB or thermal supervision: config modalities {wanted}, dataset modalities "
                f"{dataset_modalities} leave {self.modalities}."
            )
        self.upsampling_resolutions: List[int] = (
            np.round(
                np.exp(
                    np.linspace(
                        np.log(config.init_resolution),
                        np.log(config.final_resolution),
                        len(config.upsampling_iters) + 1,
                    )
                )
            )
            .astype(int)
            .tolist()[1:]
        )
        super().__init__(config=config, **kwargs)

    # ------------------------------------------------------------------ setup
    def populate_modules(self) -> None:
        """Fields, samplers, renderers, colliders, metrics."""
        super().populate_modules()
        cfg = self.config

        self.log_event_threshold: Optional[Parameter] = None  # ON, OFF (config `event_threshold_learnt`)
        if self.use_event_loss and cfg.event_threshold_learnt:
            self.log_event_threshold = Parameter(torch.full((2,), math.log(cfg.event_threshold)))
        self.blur_kernel: Optional[RigidBlurKernel] = None  # EvDeblurNeRF's learnt kernel (config `blur_kernel`)
        self.event_crf: Optional[EventCRF] = None  # EvDeblurNeRF's learnt event response (config `event_crf`)
        with torch.random.fork_rng(devices=[]):  # optional parts leave the field's (and the batches') draws alone
            torch.manual_seed(SIDE_STREAM_SEED)
            if self.use_blur and cfg.blur_kernel == "learnt":
                self.blur_kernel = RigidBlurKernel(self.num_train_data, num_motions=cfg.blur_samples - 1)
            if self.event_pairs is not None and cfg.event_crf:
                self.event_crf = EventCRF()

        # fields
        self.field = AgriNeRFField(
            self.scene_box.aabb,
            contraction=cfg.scene_contraction,
            resolution=cfg.init_resolution,
            num_density_components=cfg.num_density_components,
            with_rgb=self.use_rgb,
            with_thermal=self.has_thermal_head,
            num_rgb_components=cfg.num_rgb_components,
            rgb_appearance_dim=cfg.rgb_appearance_dim,
            num_thermal_components=cfg.num_thermal_components,
            thermal_appearance_dim=cfg.thermal_appearance_dim,
            thermal_view_dependent=cfg.thermal_view_dependent,
            thermal_channels=2 if self.has_thermal_camera else 1,
            temperature_stats=(self.temperature_stats["mean_c"], self.temperature_stats["std_c"])
            if self.has_temperature and self.temperature_stats is not None
            else None,
            temperature_mlp_width=cfg.temperature_mlp_width,
            mlp_width=cfg.mlp_width,
            thermal_mlp_width=cfg.thermal_mlp_width,
            density_shift=cfg.density_shift,
            max_density=cfg.max_density,
            occupancy_resolution=cfg.occupancy_resolution,
            vm_lookup=cfg.vm_lookup,
        )

        # the first full-resolution box: around the dataset's SfM points where it has them (refitted in training)
        points = (self.kwargs.get("metadata") or {}).get("points3D_xyz")
        if self.field.mapping is not None and points is not None:
            box = fit_box(torch.as_tensor(points, dtype=torch.float32))
            if box is not None:
                self.field.refit_box(box, cfg.box_grid_fraction, cfg.init_resolution)

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
        if self.log_event_threshold is not None:
            groups["fields"].append(self.log_event_threshold)
        if self.blur_kernel is not None:
            groups["blur_kernel"] = list(self.blur_kernel.parameters())
        if self.event_crf is not None:
            groups["event_crf"] = list(self.event_crf.parameters())
        self.camera_optimizer.get_param_groups(param_groups=groups)
        return groups

    # --------------------------------------------------- resolution schedule
    def resolution_at_step(self, step: int) -> int:
        """Grid resolution after training step `step` has run (upsampling happens after its iteration)."""
        done = sum(1 for it in self.config.upsampling_iters if it <= step)
        return self.config.init_resolution if done == 0 else self.upsampling_resolutions[done - 1]

    def upsample_volumes(self, resolution: int) -> None:
        """Resample every volume to the per-axis resolution of a `resolution`^3 budget (new Parameters)."""
        target = self.field.axis_resolution(resolution)
        for volume in self.field.volumes().values():
            if volume.resolution != target:
                volume.upsample_grid(target)

    @torch.no_grad()
    def fit_box(self, cameras: Any, step: int) -> Optional[Tensor]:
        """Fit the full-resolution box to the median-depth points of `box_fit_rays` training rays of `cameras` (drawn
        with a generator seeded by `step`, so the global random stream is untouched) and resample the volumes into it
        at the current resolution; returns the new box, or None when too few rays hit anything (box kept)."""
        if self.field.mapping is None:
            return None
        gen = torch.Generator().manual_seed(SIDE_STREAM_SEED + step)
        n = self.config.box_fit_rays
        index = torch.randint(0, cameras.shape[0], (n,), generator=gen)
        heights, widths = cameras.height[index, 0].float(), cameras.width[index, 0].float()
        rows = (torch.rand(n, generator=gen) * heights).floor() + 0.5
        cols = (torch.rand(n, generator=gen) * widths).floor() + 0.5
        bundle = cameras.generate_rays(camera_indices=index[:, None], coords=torch.stack([rows, cols], -1))
        bundle = bundle.to(self.device)
        points, weights, origins = [], [], []
        was_training = self.training
        self.eval()
        try:
            for start in range(0, n, self.config.eval_num_rays_per_chunk):
                part = self.collider(bundle[start : start + self.config.eval_num_rays_per_chunk])
                out = self._render(part, routed=False, heads=())
                points.append(part.origins + part.directions * out["depth"])
                weights.append(out["accumulation"][:, 0])
                origins.append(part.origins)
        finally:
            self.train(was_training)
        box = fit_box(torch.cat(points), torch.cat(weights), torch.cat(origins), depth_cut=self.config.box_depth_cut)
        if box is None:
            return None
        old = self.field.full_resolution_box()
        first = not self.config.box_fit_iters or step <= min(self.config.box_fit_iters)
        growth = self.config.box_fit_growth if first else self.config.box_refit_growth
        centre, reach = old.mean(dim=0), (old[1] - old[0]) / 2 * growth
        box = torch.stack([torch.maximum(box[0], centre - reach), torch.minimum(box[1], centre + reach)])
        if not bool((box[1] > box[0]).all()):
            return None
        self.field.refit_box(box, self.config.box_grid_fraction, self.resolution_at_step(step))
        if self.occupancy_updated(step):
            self.field.update_occupancy(self.config.occupancy_density_threshold)
        return box

    def occupancy_updated(self, step: int) -> bool:
        """Whether the occupancy grid has been computed after training step `step` (an update step has run)."""
        return self.config.occupancy_resolution > 0 and any(it <= step for it in self.config.occupancy_update_iters)

    def sync_optimizers(self, optimizers: Optimizers, keep_moments: bool = True) -> int:
        """Point every optimizer at this model's current Parameters (upsampling and box fits replace them); returns how
        many were replaced. Adam moments move with a Parameter when their shape still fits (a checkpoint loaded into
        volumes its pre-hooks resized) and `keep_moments`, and are dropped otherwise (after an upsampling step or a box
        fit, whose moments belong to other places: Adam re-initialises them).
        """
        current = self.get_param_groups()
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

    def get_training_callbacks(
        self, training_callback_attributes: TrainingCallbackAttributes
    ) -> List[TrainingCallback]:
        """Upsampling of all volumes (optimizers re-pointed) and occupancy updates.

        Called after a checkpoint has loaded: the optimizers, built before the checkpoint's load hooks resized the
        volumes' Parameters, are re-pointed here first (their loaded moments already have the new size).
        """
        optimizers = training_callback_attributes.optimizers
        if optimizers is not None:
            self.sync_optimizers(optimizers)

        def upsample(step: int) -> None:
            self.upsample_volumes(self.resolution_at_step(step))
            if optimizers is not None:
                self.sync_optimizers(optimizers)

        def update_occupancy(step: int) -> None:
            del step
            self.field.update_occupancy(self.config.occupancy_density_threshold)

        def refit_box(step: int) -> None:
            pipeline = training_callback_attributes.pipeline
            dataset = getattr(getattr(pipeline, "datamanager", None), "train_dataset", None)
            if dataset is None or self.fit_box(dataset.cameras, step) is None:
                return
            if optimizers is not None:
                self.sync_optimizers(optimizers, keep_moments=False)

        def keep_step(step: int) -> None:
            self.step = step

        callbacks = [
            TrainingCallback(
                where_to_run=[TrainingCallbackLocation.BEFORE_TRAIN_ITERATION], update_every_num_iters=1, func=keep_step
            ),  # fmt: skip
            TrainingCallback(
                where_to_run=[TrainingCallbackLocation.AFTER_TRAIN_ITERATION],
                iters=tuple(self.config.upsampling_iters),
                func=upsample,
            ),
        ]
        if self.field.mapping is not None and self.config.box_fit_iters:
            callbacks.append(
                TrainingCallback(
                    where_to_run=[TrainingCallbackLocation.AFTER_TRAIN_ITERATION],
                    iters=tuple(self.config.box_fit_iters),
                    func=refit_box,
                )
            )
        if self.config.occupancy_resolution > 0 and self.config.occupancy_update_iters:
            callbacks.append(
                TrainingCallback(
                    where_to_run=[TrainingCallbackLocation.AFTER_TRAIN_ITERATION],
                    iters=tuple(self.config.occupancy_update_iters),
                    func=update_occupancy,
                )
            )
        return callbacks

    # -------------------------------------------------------------- forward
    def _background(self, values: Float[Tensor, "rays samples c"]) -> Float[Tensor, "rays c"]:
        if self.config.background_color == "last_sample":
            return values[:, -1, :]
        fill = 1.0 if self.config.background_color == "white" else 0.0
        return torch.full_like(values[:, -1, :], fill)

    def get_outputs(self, ray_bundle: RayBundle) -> Dict[str, Tensor]:
        """Renders the rays; in training also the blur model's and the event loss's renders of the same pixels at other
        times ("rgb_blurred", "event_log_start", "event_log_end") where they are on."""
        if self.training:
            self.camera_optimizer.apply_to_raybundle(ray_bundle)
        outputs = self._render(ray_bundle)
        if self.training and torch.is_grad_enabled():
            with self._side_stream():
                if self.use_blur and self.step >= self.config.blur_start_step and self.blur_kernel is not None:
                    outputs["rgb_blurred"] = self._kernel_rgb(ray_bundle, outputs.get("rgb/rgb_loss", outputs["rgb"]))
                elif self.use_blur and self.step >= self.config.blur_start_step:
                    outputs["rgb_blurred"] = self._blurred_rgb(ray_bundle)
                if self.edi_stream is not None:
                    outputs.update(self._edi_outputs(ray_bundle))
                if self.use_event_loss and self.event_pairs is not None:
                    outputs.update(self._pair_event_logs(ray_bundle))
                elif self.use_event_loss and self.event_stream is not None:
                    outputs.update(self._stream_event_logs(ray_bundle))
                elif self.use_event_loss:
                    outputs["event_log_start"], outputs["event_log_end"] = self._event_window_logs(ray_bundle)
        return outputs

    @contextlib.contextmanager
    def _side_stream(self) -> Iterator[None]:
        """The blur and event renders draw their pixels, windows and sample jitter from a random stream of their own
        (seeded by the step), so that turning them on leaves the draws of the RGB batches as they were: an ablation
        row and its baseline stay paired (common random numbers)."""
        devices = [self.device] if self.device.type == "cuda" else []
        with torch.random.fork_rng(devices=devices):
            torch.manual_seed(SIDE_STREAM_SEED + self.step)
            yield

    def _render_at(self, bundle: RayBundle, times: Tensor, term: str, **camera: Any) -> Float[Tensor, "n k 3"]:
        """RGB of `bundle`'s pixels rendered from the trajectory's poses at `times` [n, k] for the loss `term` (its
        density gradient scale; `camera`: the `camera_centre` and `plane_depth` of another rig camera whose frames
        were warped onto these pixels)."""
        from agrinerf_ns.model.timed_rays import camera_rows, reposed_rays

        assert self.trajectory is not None and self.frame_times is not None
        frame_times = self.frame_times[camera_rows(bundle)]
        moved = self.collider(reposed_rays(bundle, self.trajectory, frame_times, times, **camera))
        n, k = times.shape
        rendered = self._render(moved, routed=False, density_scale=self.density_gradient_scale(term), heads=("rgb",))
        return rendered["rgb"].reshape(n, k, 3)

    def _blurred_rgb(self, bundle: RayBundle) -> Float[Tensor, "n 3"]:
        """The blur model: the mean in linear radiance of `blur_samples` renders across each frame's exposure."""
        from agrinerf_ns.model.timed_rays import camera_rows, exposure_times

        assert self.exposure is not None
        times = exposure_times(self.exposure[camera_rows(bundle)], self.config.blur_samples)
        renders = self._render_at(bundle, times, "rgb_loss")
        return losses.linear_to_srgb(losses.srgb_to_linear(renders).mean(dim=1))

    def _kernel_rgb(self, bundle: RayBundle, frame_rgb: Float[Tensor, "n 3"]) -> Float[Tensor, "n 3"]:
        """The learnt blur kernel: the frame ray's colour and the renders of its learnt rigid motions, blended in linear
        radiance with the learnt weights (`model/rigid_blur.py`)."""
        from agrinerf_ns.model.rigid_blur import blend, warp_rays
        from agrinerf_ns.model.timed_rays import camera_rows

        assert self.blur_kernel is not None
        rotation, translation, weights = self.blur_kernel(camera_rows(bundle).to(frame_rgb.device))
        origins, directions = warp_rays(bundle.origins, bundle.directions, rotation, translation)
        n, m = origins.shape[:2]
        assert bundle.camera_indices is not None
        moved = RayBundle(
            origins=origins.reshape(n * m, 3),
            directions=directions.reshape(n * m, 3),
            pixel_area=bundle.pixel_area.repeat_interleave(m, dim=0),
            camera_indices=bundle.camera_indices.repeat_interleave(m, dim=0),
        )
        scale = self.density_gradient_scale("rgb_loss")
        renders = self._render(self.collider(moved), routed=False, density_scale=scale, heads=("rgb",))["rgb"].reshape(
            n, m, 3
        )
        linear = losses.srgb_to_linear(torch.cat([frame_rgb[:, None, :], renders], dim=1))
        return losses.linear_to_srgb(blend(linear, weights))

    def _edi_outputs(self, bundle: RayBundle) -> Dict[str, Tensor]:
        """The EDI prior's per-ray factor (the blurred value over it is the sharp mid-exposure value) and where the
        event camera sees the pixel (`model/edi_prior.py`)."""
        from agrinerf_ns.model.timed_rays import camera_rows

        assert self.edi_stream is not None and self.event_camera_native is not None
        assert self.trajectory is not None and self.frame_times is not None and self.exposure is not None
        rows = camera_rows(bundle)
        pose = self.trajectory.poses_at_tensor(self.frame_times[rows].double(), dtype=torch.float64)
        local = (pose[:, :3, :3].transpose(-1, -2) @ bundle.directions.double().cpu()[..., None])[..., 0]
        depth = float(self.event_camera.get("plane_depth", math.inf))
        pixel, inside = edi_prior.event_pixels(self.event_camera_native, local, depth)
        c_on, c_off = (float(c) for c in self._event_thresholds())
        factor = edi_prior.edi_factors(self.edi_stream, pixel, self.exposure[rows], c_on, c_off)
        device = bundle.origins.device
        return {"edi_factor": factor.to(device), "edi_valid": inside.float()[:, None].to(device)}

    def _pair_event_logs(self, like: RayBundle) -> Dict[str, Tensor]:
        """`event_rays_per_batch` EvDeblurNeRF event samples (`model/event_pairs.py`) rendered along the event camera's
        rays at both events' times: their log luma (after the learnt response, from its start step) and targets."""
        from agrinerf_ns.model.event_crf import event_log_luma
        from agrinerf_ns.model.event_pairs import pair_targets, polarity_features
        from agrinerf_ns.model.event_stream import event_rays

        assert self.event_pairs is not None and self.trajectory is not None and self.frame_times is not None
        assert self.event_camera_native is not None
        pixel, t0, t1, polarity = self.event_pairs.sample(self.config.event_rays_per_batch)
        m = int(pixel.shape[0])
        if m == 0:  # a stream without two events at any pixel: no sample, no loss
            return {}
        times = torch.stack([t0, t1], -1).double() * 1e-6
        origins, directions = event_rays(self.trajectory, self.event_camera_native, pixel, times)
        frames = (times[:, :1] - self.frame_times.double()[None, :]).abs().argmin(dim=-1)  # the nearest frame's camera
        device, dtype = like.origins.device, like.origins.dtype
        bundle = RayBundle(
            origins=origins.reshape(2 * m, 3).to(device=device, dtype=dtype),
            directions=directions.reshape(2 * m, 3).to(device=device, dtype=dtype),
            pixel_area=like.pixel_area[:1].expand(2 * m, 1).contiguous(),
            camera_indices=frames.repeat_interleave(2)[:, None].to(device),
        )
        scale = self.density_gradient_scale("event_loss")
        rgb = self._render(self.collider(bundle), routed=False, density_scale=scale, heads=("rgb",))["rgb"].reshape(
            m, 2, 3
        )
        crf = self.event_crf if self.step >= self.config.event_crf_start_step else None
        features = polarity_features(polarity).to(device)
        logs = event_log_luma(losses.srgb_to_linear(rgb), self.config.event_log_eps, crf, features)
        return {"event_log_start": logs[:, 0], "event_log_end": logs[:, 1],
                "event_target": pair_targets(polarity, *self._event_thresholds()).to(device)}  # fmt: skip

    def _stream_event_logs(self, like: RayBundle) -> Dict[str, Tensor]:
        """`event_rays_per_batch` random event pixels in random sub-windows of random training frames' windows,
        rendered along the event camera's rays at both ends: their log luminance and their ON / OFF counts."""
        from agrinerf_ns.model.event_stream import event_rays, sample_windows

        assert self.event_stream is not None and self.event_windows is not None and self.trajectory is not None
        assert self.event_camera_native is not None
        m = self.config.event_rays_per_batch
        frames = torch.randint(0, self.event_windows.shape[0], (m,))
        t0, t1 = sample_windows(self.event_windows, frames, self.config.event_window_min_fraction, None)
        pixel = torch.randint(0, self.event_stream.width * self.event_stream.height, (m,))
        on, off = self.event_stream.counts(pixel, t0, t1)
        origins, directions = event_rays(
            self.trajectory, self.event_camera_native, pixel, torch.stack([t0, t1], -1).double() * 1e-6
        )
        device, dtype = like.origins.device, like.origins.dtype
        bundle = RayBundle(
            origins=origins.reshape(2 * m, 3).to(device=device, dtype=dtype),
            directions=directions.reshape(2 * m, 3).to(device=device, dtype=dtype),
            pixel_area=like.pixel_area[:1].expand(2 * m, 1).contiguous(),
            camera_indices=frames.repeat_interleave(2)[:, None].to(device),
        )
        scale = self.density_gradient_scale("event_loss")
        rgb = self._render(self.collider(bundle), routed=False, density_scale=scale, heads=("rgb",))["rgb"].reshape(
            m, 2, 3
        )
        logs = losses.log_luminance(rgb, self.config.event_log_eps)
        return {"event_log_start": logs[:, 0], "event_log_end": logs[:, 1], "event_on": on.to(device),
                "event_off": off.to(device)}  # fmt: skip

    def _event_window_logs(self, bundle: RayBundle) -> Tuple[Float[Tensor, "m 1"], Float[Tensor, "m 1"]]:
        """Log luminance of the first `event_rays_per_batch` pixels at the start and end of their event windows, seen
        from the event camera (its centre and the alignment plane from the dataset's calibration, where recorded)."""
        from agrinerf_ns.model.timed_rays import camera_rows

        assert self.event_windows is not None
        m = min(self.config.event_rays_per_batch, bundle.origins.shape[0])
        head = bundle[:m]
        renders = self._render_at(
            head, self.event_windows[camera_rows(head)].double(), "event_loss", **self.event_camera
        )
        logs = losses.log_luminance(renders, self.config.event_log_eps)  # [m, 2, 1]
        return logs[:, 0], logs[:, 1]

    def _render(
        self,
        ray_bundle: RayBundle,
        routed: bool = True,
        density_scale: float = 1.0,
        heads: Optional[Tuple[str, ...]] = None,
    ) -> Dict[str, Tensor]:
        """Coarse density pass (no gradient) -> PDF fine samples -> heads on samples with weight > threshold.
        `routed`: add the training-only routed copies of the outputs (`density_gradient_scales`). `density_scale`:
        scale of the gradient every output sends the density (the renders of one loss term: blur, events). `heads`:
        the heads to evaluate ("rgb", "thermal"; None: all; a side render whose loss reads only "rgb" skips the
        others)."""
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
        every_sample = float(selected.float().mean()) >= DENSE_HEADS_FRACTION
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
                if self.has_thermal_camera:
                    dense["thermal_camera"] = full[..., 1:2]

        accumulation = self.renderer_accumulation(weights).clamp(0.0, 1.0)
        # "rgb" first: the viewer shows the first output when it opens
        outputs: Dict[str, Tensor] = {
            name: self._composite(weights, accumulation, values) for name, values in dense.items()
        }
        outputs["depth"] = self.renderer_depth(weights, samples)
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
            outputs.update(self._routed_outputs(weights, dense))
        if not self.training:
            for name in dense:
                if name != "temperature":
                    outputs[name] = outputs[name].clamp(0.0, 1.0)
        return outputs

    def _composite(
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
        return self.density_gradient_scales.get(term, 1.0)

    def _routed_outputs(self, weights: Float[Tensor, "rays samples 1"], dense: Dict[str, Tensor]) -> Dict[str, Tensor]:
        """Training only: for each data term whose density gradient scale is not 1, its output composited with weights
        whose gradient is scaled (same values), under the key "<output>/<term>"."""
        routed: Dict[str, Tensor] = {}
        scaled: Dict[float, Tuple[Tensor, Tensor]] = {}  # scale -> (weights, their accumulation)
        composites: Dict[Tuple[str, float], Tensor] = {}
        for term, name in TERM_OUTPUTS.items():
            scale = self.density_gradient_scale(term)
            if name not in dense or scale == 1.0:
                continue
            if scale not in scaled:
                w = losses.scale_gradient(weights, scale)
                scaled[scale] = (w, self.renderer_accumulation(w).clamp(0.0, 1.0))
            if (name, scale) not in composites:
                composites[(name, scale)] = self._composite(*scaled[scale], dense[name])
            routed[f"{name}/{term}"] = composites[(name, scale)]
        return routed

    # --------------------------------------------------------------- losses
    def _data_terms(self, outputs: Dict[str, Tensor], batch: Dict[str, Any]) -> Dict[str, Tensor]:
        """Raw (unweighted) data loss terms for the modalities this model uses and the batch carries; each term reads
        its routed output ("<output>/<term>", training) where there is one."""
        coef = self.config.loss_coefficients

        def pred(term: str) -> Tensor:
            name = TERM_OUTPUTS[term]
            return outputs.get(f"{name}/{term}", outputs[name])

        def optional(key: str) -> Any:
            value = batch.get(key)
            return None if value is None else value.to(self.device)

        terms: Dict[str, Tensor] = {}
        image = batch["image"][..., :3].to(self.device) if "image" in batch else None
        if self.use_rgb and image is not None:
            terms["rgb_loss"] = losses.rgb_loss(outputs.get("rgb_blurred", pred("rgb_loss")), image)
        if "edi_factor" in outputs and image is not None:  # EvDeblurNeRF's EDI prior on the frame ray
            sharp = losses.linear_to_srgb(losses.srgb_to_linear(image) / outputs["edi_factor"])
            terms["edi_prior_loss"] = losses.masked_mse(pred("edi_prior_loss"), sharp, outputs["edi_valid"])
        if "event_target" in outputs:  # EvDeblurNeRF's event-to-event samples
            terms["event_loss"] = losses.event_pair_loss(
                outputs["event_log_start"], outputs["event_log_end"], outputs["event_target"]
            )
        elif "event_on" in outputs:  # the stream's event pixels carry their own counts
            terms["event_loss"] = losses.event_loss(
                outputs["event_log_start"],
                outputs["event_log_end"],
                outputs["event_on"],
                outputs["event_off"],
                *self._event_thresholds(),
                lower_bound=self.config.event_loss_bound,
            )
        elif "event_log_start" in outputs and "event_on" in batch:
            m = outputs["event_log_start"].shape[0]
            mask = optional("event_mask")
            terms["event_loss"] = losses.event_loss(
                outputs["event_log_start"],
                outputs["event_log_end"],
                batch["event_on"][:m].to(self.device),
                batch["event_off"][:m].to(self.device),
                *self._event_thresholds(),
                None if mask is None else mask[:m],
                lower_bound=self.config.event_loss_bound,
            )
        if not self.has_thermal_head:
            return terms
        if self.use_thermal and "thermal" in batch:
            thermal, thermal_mask = batch["thermal"].to(self.device), optional("thermal_mask")
            terms["thermal_loss"] = losses.thermal_loss(pred("thermal_loss"), thermal, thermal_mask)
            if self.has_thermal_camera:
                terms["thermal_camera_loss"] = losses.thermal_loss(pred("thermal_camera_loss"), thermal, thermal_mask)
        if self.has_temperature and "temperature" in batch:
            head = self.field.temperature_head
            assert head is not None
            terms["temperature_loss"] = losses.thermal_loss(
                head.normalise(pred("temperature_loss")),
                head.normalise(batch["temperature"].to(self.device)),
                optional("temperature_mask"),
            )
        if self.use_rgb and image is not None and coef.get("reg_rgb_loss", 0.0) > 0:
            terms["reg_rgb_loss"] = losses.cross_spectral_rgb_term(pred("reg_rgb_loss"), image)
        if self.use_events and "event" in batch and coef.get("reg_event_loss", 0.0) > 0:
            terms["reg_event_loss"] = losses.cross_spectral_event_term(
                pred("reg_event_loss"), batch["event"].to(self.device), optional("event_mask")
            )
        return terms

    def _regularisers(self) -> Dict[str, Tensor]:
        """TensoRF L1 (density volume) and TV (density / appearance planes) for the terms with a weight."""
        coef = self.config.loss_coefficients
        terms: Dict[str, Tensor] = {}
        volumes = self.field.volumes()
        if coef.get("l1_reg", 0.0) > 0:
            density = volumes["density"]
            terms["l1_reg"] = losses.l1_volume_loss(density.plane_table, density.line_table)
        if coef.get("tv_reg_density", 0.0) > 0:
            terms["tv_reg_density"] = plane_tv(volumes["density"])
        if coef.get("tv_reg_appearance", 0.0) > 0:
            terms["tv_reg_appearance"] = sum(plane_tv(v) for name, v in volumes.items() if name != "density")
        return terms

    def get_metrics_dict(self, outputs, batch) -> Dict[str, Tensor]:
        """PSNR of RGB (and thermal) plus the raw loss terms (weighted only in `get_loss_dict`)."""
        metrics: Dict[str, Tensor] = {}
        if self.use_rgb and "image" in batch:
            metrics["psnr"] = self.psnr(outputs["rgb"].detach(), batch["image"][..., :3].to(self.device).float())
        metrics.update(self._data_terms(outputs, batch))
        for term, name in (("thermal_loss", "thermal_psnr"), ("thermal_camera_loss", "thermal_camera_psnr")):
            if term in metrics:
                metrics[name] = -10.0 * torch.log10(metrics[term].detach().clamp(min=1e-10))
        if self.training:
            metrics.update(self._regularisers())
        if self.training and self._loss_means is not None:
            metrics["event_loss_weight"] = self.event_weight
        if self.log_event_threshold is not None:
            metrics["event_threshold_on"], metrics["event_threshold_off"] = self.log_event_threshold.detach().exp()
        self.camera_optimizer.get_metrics_dict(metrics)
        return metrics

    def get_loss_dict(self, outputs, batch, metrics_dict=None) -> Dict[str, Tensor]:
        """Weighted loss terms: loss_coefficients x raw terms (from `metrics_dict` when given)."""
        raw = dict(metrics_dict) if metrics_dict is not None else {}
        if not any(k in raw for k in ("rgb_loss", "thermal_loss")):
            raw.update(self._data_terms(outputs, batch))
            if self.training:
                raw.update(self._regularisers())
        coef = self.config.loss_coefficients
        # out of place (misc.scale_dict multiplies in place, which would also scale the raw terms in the metrics)
        loss_dict = {k: v * coef[k] for k, v in raw.items() if coef.get(k, 0.0) > 0}
        if "edi_prior_loss" in loss_dict:  # EvDeblurNeRF's cosine-decayed weight
            loss_dict["edi_prior_loss"] = loss_dict["edi_prior_loss"] * edi_prior.cosine_weight(self.step)
        if "event_loss" in loss_dict and "rgb_loss" in raw and self.config.event_loss_weighting == "noise":
            loss_dict["event_loss"] = loss_dict["event_loss"] * self._event_noise_weight(raw, outputs)
        self.camera_optimizer.get_loss_dict(loss_dict)
        return loss_dict

    def _event_thresholds(self) -> Tuple[Any, Any]:
        """C_on, C_off of the event loss: learnt (config `event_threshold_learnt`) or the configured one."""
        if self.log_event_threshold is None:
            return self.config.event_threshold, self.config.event_threshold
        c = self.log_event_threshold.exp()
        return c[0], c[1]

    def _event_noise_weight(self, raw: Dict[str, Tensor], outputs: Dict[str, Tensor]) -> float:
        """The `noise` weighting's factor (config `event_loss_weighting`), from running means of the RGB and event
        losses (updated in training; 0.99 per step)."""
        rgb, event = float(raw["rgb_loss"].detach()), float(raw["event_loss"].detach())
        if self.training and math.isfinite(rgb) and math.isfinite(event):
            old = self._loss_means or (rgb, event)
            self._loss_means = (0.99 * old[0] + 0.01 * rgb, 0.99 * old[1] + 0.01 * event)
        if self._loss_means is None:
            return 0.0
        mean_rgb, mean_event = self._loss_means
        samples = outputs["event_log_start"].shape[0] / outputs["rgb"].shape[0]
        self.event_weight = samples * min(mean_rgb / max(mean_event, 1e-12), 1.0)  # never above an RGB ray's
        return self.event_weight

    # ----------------------------------------------------------- evaluation
    @property
    def lpips(self) -> torch.nn.Module:
        """LPIPS (torchmetrics), built on first use: construction loads (or tries to fetch) AlexNet weights, which
        training never needs. Kept out of the module tree, so checkpoints do not carry its weights."""
        if "lpips" not in self._lazy_metrics:
            from torchmetrics.image.lpip import LearnedPerceptualImagePatchSimilarity

            self._lazy_metrics["lpips"] = LearnedPerceptualImagePatchSimilarity(normalize=True).to(self.device)
        return self._lazy_metrics["lpips"]

    def get_image_metrics_and_images(
        self, outputs: Dict[str, Tensor], batch: Dict[str, Any]
    ) -> Tuple[Dict[str, float], Dict[str, Tensor]]:
        """RGB: psnr, ssim, lpips; thermal (and thermal_camera): <output>_psnr, <output>_ssim against the rescaled
        thermal frames, over the thermal mask. Images side by side."""
        metrics: Dict[str, float] = {}
        images: Dict[str, Tensor] = {
            "accumulation": colormaps.apply_colormap(outputs["accumulation"]),
            "depth": colormaps.apply_depth_colormap(outputs["depth"], accumulation=outputs["accumulation"]),
        }
        metrics.update(self.grid_diagnostics(outputs))
        if self.use_rgb:
            gt = batch["image"][..., :3].to(self.device).float()
            pred = outputs["rgb"]
            images["img"] = torch.cat([gt, pred], dim=1)
            gt_c, pred_c = gt.permute(2, 0, 1)[None], pred.permute(2, 0, 1)[None]
            metrics["psnr"] = float(self.psnr(pred_c, gt_c).item())
            metrics["ssim"] = float(self.ssim(pred_c, gt_c).item())  # type: ignore[union-attr]
            metrics["lpips"] = float(self.lpips(pred_c.clamp(0, 1), gt_c.clamp(0, 1)).item())
        if self.has_thermal_head:
            pred_th = outputs["thermal"]
            images["thermal"] = pred_th.expand(*pred_th.shape[:-1], 3)
            if self.use_thermal and "thermal" in batch:
                gt_th = batch["thermal"].to(self.device).float()
                mask = batch.get("thermal_mask")
                mask = torch.ones_like(gt_th) if mask is None else (mask.to(self.device).float() > 0.5).float()
                for name in ("thermal", "thermal_camera"):
                    if name in outputs:
                        metrics.update(self._thermal_metrics(name, outputs[name], gt_th, mask))
                        images[name] = torch.cat([gt_th, outputs[name]], dim=1).expand(-1, -1, 3)
        if "temperature" in outputs and "temperature" in batch:
            gt_t = batch["temperature"].to(self.device).float()
            mask_t = batch.get("temperature_mask")
            mask_t = torch.ones_like(gt_t) if mask_t is None else (mask_t.to(self.device).float() > 0.5).float()
            error = (outputs["temperature"] - gt_t).abs() * mask_t
            metrics["temperature_mae"] = float((error.sum() / mask_t.sum().clamp(min=1.0)).item())
            images["temperature"] = colormaps.apply_colormap(
                self.temperature_unit(torch.cat([gt_t * mask_t, outputs["temperature"]], dim=1))
            )
        self.camera_optimizer.get_metrics_dict(metrics)  # type: ignore[arg-type]
        return metrics, images

    def grid_diagnostics(self, outputs: Dict[str, Tensor]) -> Dict[str, float]:
        """How well the grids fit the scene in a rendered image: `fine_region_weight`, the share of its rendering
        weight inside the full-resolution box, and `voxel_size_m`, the median over the rays that hit something
        (accumulation > 0.5) of the largest side of the grid cell at the ray's median depth, in metres (NaN where the
        dataset's scale is unknown; `voxel_size_units` in scene units); `voxel_size_final_m`: the same at the
        preset's final resolution in the current box."""
        if "full_resolution_weight" not in outputs:
            return {}
        acc = outputs["accumulation"]
        share = outputs["full_resolution_weight"].sum() / acc.sum().clamp(min=1e-12)
        hits = acc[..., 0] > 0.5
        scale = float("nan") if self.metres_per_unit is None else float(self.metres_per_unit)
        metrics = {"fine_region_weight": float(share)}
        for key in ("voxel_size", "voxel_size_final"):
            sizes = outputs[key][..., 0][hits] if bool(hits.any()) else outputs[key].reshape(-1)
            metrics[f"{key}_units"] = float(sizes.median())
            metrics[f"{key}_m"] = metrics[f"{key}_units"] * scale
        return metrics

    def _thermal_metrics(
        self,
        name: str,
        pred: Float[Tensor, "h w 1"],
        gt: Float[Tensor, "h w 1"],
        mask: Float[Tensor, "h w 1"],
    ) -> Dict[str, float]:
        """`<name>_psnr` over the thermal mask and `<name>_ssim` (outside the mask the prediction is replaced by the
        truth first) of one thermal output against the rescaled thermal frame."""
        mse = losses.thermal_loss(pred, gt, mask)
        filled = pred * mask + gt * (1.0 - mask)
        ssim = self.ssim(filled.permute(2, 0, 1)[None], gt.permute(2, 0, 1)[None])  # type: ignore[operator]
        return {
            f"{name}_psnr": float((-10.0 * torch.log10(mse.clamp(min=1e-10))).item()),
            f"{name}_ssim": float(ssim.item()),  # type: ignore[union-attr]
        }

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
