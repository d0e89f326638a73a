"""The AgriNeRF model's settings (defaults: the paper's), apart from the model so that method configs and tools read
them without building one."""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any, Dict, Literal, Tuple, Type, TypeVar

from nerfstudio.cameras.camera_optimizers import CameraOptimizerConfig
from nerfstudio.configs.config_utils import to_immutable_dict
from nerfstudio.models.base_model import ModelConfig

from agrinerf_ns.modalities import ALL_MODALITIES, DARK_RGB_LEVEL, Modality
from agrinerf_ns.model.vm_encoding import VMLookup


class _SettingsBuildNoModel:
    def __init__(self, *args: Any, **kwargs: Any) -> None:
        raise TypeError(
            "AgriNeRFSettings are the model's settings and build no model: use agrinerf_ns.model.AgriNeRFModelConfig"
        )


@dataclass
class AgriNeRFSettings(ModelConfig):
    """AgriNeRF model settings (defaults: the paper's). `agrinerf_ns.model.AgriNeRFModelConfig` adds the model they
    build; the model's parts read these."""

    _target: Type = field(default_factory=lambda: _SettingsBuildNoModel)
    """What `setup()` builds: nothing here (`AgriNeRFModelConfig` builds the model)."""
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
    low_light_level: float = DARK_RGB_LEVEL
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
    thermal_rays_per_batch: int = 256
    """Rays of each batch (the first ones) along which the thermal terms (L_th, the thermal-camera and temperature
    terms) are rendered from the thermal camera's centre through their points on the alignment plane, where the
    dataset records the thermal camera's place and the rig's trajectory (`model/thermal_view.py`): the warped thermal
    frames were taken from there, a few centimetres beside the RGB camera. 0: on the RGB rays, the paper's
    pixel-aligned ray, which smears the temperatures by the cameras' parallax. 256 of 1024 sample the thermal frames
    (a quarter of the RGB pixels at half the width) about as densely as the batch samples the RGB frames; 1024 gave a
    little more per fruit at a higher step cost (results/thermal-rays)."""
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
    box_fit_growth: float = 16.0
    """The first fit (at the first of `box_fit_iters`) may grow the box to at most this many times its size about its
    centre (an early, still blurry field cannot throw the box far out). 8 cut the quick profile's orchards at 8 units
    from the cameras, leaving 17% of the visible surfaces within `box_depth_cut` outside (results/box-fit)."""
    box_refit_growth: float = 1.0
    """Each later fit may grow the box at most this many times (1: shrink only, as TensoRF's `shrink`). Floaters that a
    dark, noisy capture grows before its field settles would otherwise widen the box and coarsen its voxels."""
    box_depth_cut: float = 2.5
    """Surface points farther from their camera than this times the median distance are background, outside the box
    (sky, hedges, far rows)."""
    box_surface_share: float = 0.95
    """Share of the (accumulation-weighted) surface points within `box_depth_cut` that the fitted box holds where the
    dataset's scale is not metric (`grid_mapping.smallest_box`: the box shrinks where that costs the least weight per
    volume). Higher holds more of the scene at full resolution, at a larger voxel (results/box-fit)."""
    box_voxel_target_m: float = 0.02
    """Where the dataset's scale is metric: the fit shrinks the box until its voxels at `final_resolution` are at most
    this many metres (a 5 cm fruit spans 2.5 of them), keeping at least `box_min_share`; where that cannot reach it
    (small grids, a wide scene), and for 0, the box holds `box_surface_share` as without a metric scale."""
    box_min_share: float = 0.8
    """The least share of the surface weight that a fit towards `box_voxel_target_m` keeps in the box."""
    box_fruit_share: float = 0.0
    """With a fruit head: each box fit also holds this share of the surface points of the training frames' fruit-mask
    pixels (RGB-camera masks; `grid_schedule.fruit_pixel_rays`), so that the fruit the head is taught keep the
    full resolution (the box grows over them, at a larger voxel). 0: off, the fit sees the scene only."""
    keep_freed_memory: bool = True
    """Training on a CPU: keep freed memory in the process for the next step (glibc serves large blocks from its heap
    and does not trim it) rather than fault fresh pages in every step; about half as long a step at the paper's final
    grids, for a higher resident peak (`agrinerf_ns/cpu_memory.py`, docs/benchmark.md). No effect on a GPU."""
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
            "fruit_loss": 1.0,
            "l1_reg": 5.0e-4,
            "tv_reg_density": 1.0e-3,
            "tv_reg_appearance": 1.0e-4,
        }
    )
    """Weights: paper L = L_rgb + L_th + L_reg (reg_rgb_loss + reg_event_loss), plus the thermal-camera term and TensoRF
    L1/TV; 0 disables a term."""
    fruit_output: bool = True
    """The fruit head and its `fruit` output (`model/fruit_head.py`), where the dataset's frames have fruit masks."""
    fruit_mlp_width: int = 32
    fruit_position_octaves: int = 6
    """Octaves of the sinusoidal encoding of a sample's grid position that the fruit head reads beside the density
    features (`model/fruit_head.py`)."""
    fruit_shapes_geometry: bool = False
    """Let the fruit loss's gradient reach the density (off: FruitNeRF's choice, the masks cannot bend the geometry)."""
    fruit_in_box_only: bool = False
    """Render fruit only inside the fitted full-resolution box (off: wherever the field has density, as FruitNeRF). The
    box fit keeps about two thirds of the scene's weight, so fruit at a tree's top, bottom and the row's ends fall
    outside it: on the realistic bright orchard (tuning seed 0) 30% of the visible fruit lay inside, and off found 59%
    of the fruit of at least 20 px in each training view against 48% (results/count-fruit)."""
    blur_samples: int = 1
    """Blur model: a training frame's pixel is compared with the mean, in linear radiance, of this many renders at
    poses spread over the frame's exposure (the dataset's exposure intervals and camera trajectory). 1: the frame's
    own pose only (no blur model). Evaluation always renders the sharp frame pose."""
    blur_start_step: int = 0
    """Training step from which the blur model runs (EvDeblurNeRF starts it after about 1200 steps)."""
    event_rays_per_batch: int = 512
    """Event samples per batch for the event loss (`event_supervision`), each rendered at the start and end of its
    window."""
    event_threshold: float = 0.2
    """Contrast threshold C (ON and OFF) of the event loss: 0.2 is the synthetic camera's mean (and EvDeblurNeRF's
    synthetic setting); real Prophesee/DAVIS captures are nearer 0.25."""
    event_supervision: Literal["off", "pairs", "stream", "frames"] = "off"
    """The event loss's one switch, and what it reads (`plan.resolve_plan` checks it against the data). off: no event
    loss (the default; the `agrinerf` and `evdeblurnerf` presets turn it on). pairs: EvDeblurNeRF's event-to-event samples: an event that has a successor at its
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
    event_start_step: int = 0
    """Training step from which the event term renders and weighs its samples (a warm-up: 0 from the start)."""
    event_gate: bool = False
    """The event term's data gate (`event_term.EventGate`): a fixed held-out share of the event samples (drawn once,
    never trained on) is scored every `event_gate_every` steps without gradient. The term starts off; once the residual
    is below 0.95 x the smaller of its value at the gate's first check and its 'no change' loss, and not above 1.15 x
    its lowest, the term's weight opens at 1/16 and doubles every check up to 1; otherwise it is halved (0 below
    1/64). Metrics `event_gate`, `event_gate_residual`. For the stream and pairs supervisions; a dataset without the
    event stream, or `event_supervision` frames, cannot give it: the event loss is then off (`plan.py`)."""
    event_gate_every: int = 50
    """Steps between the gate's checks of its held-out event samples."""
    event_gate_samples: int = 1024
    """Held-out event samples of the gate (stream and pairs: their pixels are never drawn for training)."""
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

    def __setstate__(self, state: Dict[str, Any]) -> None:
        """Load the settings of an older run's ``config.yml`` (PyYAML calls this): fields added since take their
        defaults, and the event loss's old switches (0 event rays, a zero `event_loss` coefficient, the mode's
        absence before pairs and stream existed) become `event_supervision`."""
        state = dict(state)
        coefficients = state.get("loss_coefficients") or {}
        old_switch_off = state.get("event_rays_per_batch", 1) <= 0 or coefficients.get("event_loss", 1.0) <= 0
        if "event_supervision" not in state:  # before the stream and pairs supervisions: the frames' windows
            state["event_supervision"] = "off" if state.get("event_rays_per_batch", 0) <= 0 else "frames"
        elif old_switch_off:
            state["event_supervision"] = "off"
        if state["event_supervision"] == "off" and state.get("event_rays_per_batch", 1) <= 0:
            state.pop("event_rays_per_batch")  # today's default: the count is not a switch any more
        fresh = type(self)()
        defaults = {f.name: getattr(fresh, f.name) for f in fields(self) if f.name not in state}
        self.__dict__.update({**defaults, **state})


def __getattr__(name: str) -> Any:
    """Older runs' ``config.yml`` name the settings ``model_config.AgriNeRFModelConfig`` (their `_target` names the
    model)."""
    if name == "AgriNeRFModelConfig":
        return AgriNeRFSettings
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


PartSettings = TypeVar("PartSettings")


def part_settings(cls: Type[PartSettings], config: AgriNeRFSettings) -> PartSettings:
    """A part's own settings dataclass `cls` (`grid_schedule.GridSettings`, `event_settings.EventSettings`), each
    field taken from the flat settings' field of the same name, as Splatfacto builds gsplat's `DefaultStrategy` from
    its flat config: the flat fields stay the ones that command-line flags and older runs' ``config.yml`` set."""
    return cls(**{f.name: getattr(config, f.name) for f in fields(cls)})  # type: ignore[arg-type]
