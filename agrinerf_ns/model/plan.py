"""What a model trains, decided once: which heads, which loss terms, which event supervision, the low-light rules.

:func:`resolve_plan` is a pure function of the model config and the dataset's metadata (the dataparser's). The model
builds its parts from the plan, its forward pass and its loss terms dispatch on it, and it prints the plan's notes;
nothing else decides these things again from which objects or output keys exist. Model only what a scene requires: a
dataset without events gets no event term, one without thermal frames no thermal head.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, FrozenSet, List, Literal, Mapping, Tuple

from agrinerf_ns.dataset_format import FRUIT_MASK
from agrinerf_ns.modalities import normalise_modalities

if TYPE_CHECKING:
    from agrinerf_ns.model.model_config import AgriNeRFSettings

EventSupervision = Literal["off", "pairs", "stream", "frames"]
"""How the event loss is supervised: off; EvDeblurNeRF's event-to-event pairs; the stream's event pixels in random
windows; the frames' event windows (the dataset's per-frame ON / OFF counts)."""
BlurModel = Literal["off", "trajectory", "learnt"]
"""The RGB blur model: off; sub-poses of the rig's trajectory across each exposure; a learnt rigid kernel."""

REGULARISERS = ("l1_reg", "tv_reg_density", "tv_reg_appearance")
MEASURED_UNWEIGHTED = ("rgb_loss", "edi_prior_loss", "thermal_loss", "thermal_camera_loss", "temperature_loss")
"""Data terms computed where the plan switches them on even at weight 0: the frames' fit, a metric (and a PSNR)."""


@dataclass(frozen=True)
class ModelPlan:
    """The parts a model has and the terms it trains, for one config and one dataset."""

    modalities: Tuple[str, ...]
    """The config's modalities that the dataset has."""
    use_rgb: bool
    use_thermal: bool
    """Thermal frames supervise the model (the thermal terms)."""
    use_events: bool
    """The dataset's events reach the model (the event loss where on, the cross-spectral event term)."""
    has_thermal_head: bool
    """The cross-spectral `thermal` output: with thermal frames, or with events and `cross_spectral_output`."""
    has_thermal_camera: bool
    """The `thermal_camera` output (the thermal frames as the camera saw them)."""
    has_temperature: bool
    """The `temperature` output (degrees C): thermal frames with a radiometric calibration."""
    dark: bool
    """The RGB frames average below `low_light_level` of full scale."""
    low_light: bool
    """Dark with a thermal camera: the thermal-camera term shapes the geometry at full strength."""
    thermal_camera_rays: bool
    """The thermal terms are seen from the thermal camera: thermal frames, its place known, rays per batch > 0."""
    thermal_view: bool
    """Training renders them along its own rays: `thermal_camera_rays`, and the trajectory gives each frame's pose."""
    timed: bool
    """The dataset gives each frame's time and the rig's trajectory."""
    blur: BlurModel
    event_supervision: EventSupervision
    event_gate: bool
    """The event loss's data gate (`event_gate`, `model/event_gate.py`): held-out event-stream pixels, never trained on,
    decide its weight. On with the config's `event_gate` for the `stream` and `pairs` supervisions; `frames` cannot be
    gated (below), so a gated config's event loss is off there, with a note."""
    edi_prior: bool
    """EvDeblurNeRF's EDI prior on the frame rays."""
    has_fruit_head: bool
    """The fruit head and its `fruit` output: the frames have fruit masks (`fruit_output`, a `fruit_loss` weight)."""
    fruit_thermal_view: bool
    """Masks made on the thermal frames are supervised along the thermal camera's rays (`thermal_view`)."""
    density_gradient_scales: Mapping[str, float]
    """Per term, the scale of its gradient into the density (low light raises the thermal camera's to 1)."""
    terms: FrozenSet[str]
    """The loss terms with a weight: data terms the plan switches on, regularisers with a coefficient, and any other
    term with a coefficient (a part's own, `loss_routing.TERMS`)."""
    measured: FrozenSet[str]
    """The terms the model computes each step: `terms`, and those of `MEASURED_UNWEIGHTED` switched on at weight 0
    (raw values in the metrics only)."""
    notes: Tuple[str, ...]
    """What the model says about its decisions when it is built (low light, a supervision the data cannot give)."""

    @property
    def use_blur(self) -> bool:
        return self.blur != "off"

    @property
    def use_event_loss(self) -> bool:
        return self.event_supervision != "off"


def resolve_plan(config: AgriNeRFSettings, metadata: Mapping[str, Any]) -> ModelPlan:
    """The plan of a model with `config` on a dataset with `metadata` (the dataparser's; empty: RGB only).

    Raises:
        ValueError: when neither RGB nor thermal frames are left to supervise the model.
    """
    dataset_modalities = normalise_modalities(metadata.get("modalities", ("rgb",)))
    wanted = normalise_modalities(config.modalities)
    modalities = tuple(m for m in wanted if m in dataset_modalities)
    use_rgb, use_thermal, use_events = ("rgb" in modalities), ("thermal" in modalities), ("events" in modalities)
    if not (use_rgb or use_thermal):
        raise ValueError(
            f"AgriNeRF needs RGB or thermal supervision: config modalities {wanted}, dataset modalities "
            f"{dataset_modalities} leave {modalities}."
        )
    notes = []
    has_thermal_head = use_thermal or (use_events and config.cross_spectral_output)
    has_thermal_camera = use_thermal and config.thermal_camera_output
    rgb_level = float(metadata.get("rgb_level", math.nan))
    dark = rgb_level < config.low_light_level  # NaN (no level recorded) compares False: no low-light rule
    low_light = has_thermal_camera and dark
    scales = {k: float(v) for k, v in config.density_gradient_scales.items()}
    if low_light:
        scales["thermal_camera_loss"] = max(scales.get("thermal_camera_loss", 1.0), 1.0)
        notes.append(
            f"Low light: the RGB frames average {rgb_level:.3f} of full scale (below low_light_level "
            f"{config.low_light_level}), so the thermal-camera term shapes the geometry too."
        )
    has_temperature = use_thermal and config.temperature_output and metadata.get("temperature_stats") is not None
    timed = metadata.get("trajectory") is not None and metadata.get("times") is not None
    has_exposure = metadata.get("exposure") is not None
    thermal_camera = metadata.get("thermal_camera") or {}
    thermal_camera_rays = use_thermal and config.thermal_rays_per_batch > 0 and "camera_centre" in thermal_camera
    thermal_view = thermal_camera_rays and timed

    blur_data = config.blur_kernel == "learnt" or (timed and has_exposure)
    blur: BlurModel = config.blur_kernel if use_rgb and config.blur_samples > 1 and blur_data else "off"
    native = metadata.get("event_stream") is not None
    event_data = use_rgb and use_events and timed and metadata.get("event_windows") is not None
    supervision, gate = _event_supervision(config, event_data, native, dark, rgb_level, modalities, timed, notes)
    edi_prior = config.edi_prior and use_rgb and use_events and timed and has_exposure and native
    has_fruit_head, fruit_thermal_view = _fruit_head(config, metadata, thermal_view, notes)
    on = {
        "fruit_loss": has_fruit_head,
        "rgb_loss": use_rgb,
        "edi_prior_loss": edi_prior,
        "event_loss": supervision != "off",
        "thermal_loss": use_thermal,
        "thermal_camera_loss": has_thermal_camera,
        "temperature_loss": has_temperature,
        "reg_rgb_loss": use_rgb and has_thermal_head,
        "reg_event_loss": use_events and has_thermal_head,
        **{name: True for name in REGULARISERS},
    }
    terms = frozenset(name for name, weight in config.loss_coefficients.items() if weight > 0 and on.get(name, True))
    return ModelPlan(
        modalities=modalities,
        use_rgb=use_rgb,
        use_thermal=use_thermal,
        use_events=use_events,
        has_thermal_head=has_thermal_head,
        has_thermal_camera=has_thermal_camera,
        has_temperature=has_temperature,
        dark=dark,
        low_light=low_light,
        thermal_camera_rays=thermal_camera_rays,
        thermal_view=thermal_view,
        timed=timed,
        blur=blur,
        event_supervision=supervision,
        event_gate=gate,
        edi_prior=edi_prior,
        has_fruit_head=has_fruit_head,
        fruit_thermal_view=fruit_thermal_view,
        density_gradient_scales=scales,
        terms=terms,
        measured=terms | {name for name in MEASURED_UNWEIGHTED if on[name]},
        notes=tuple(notes),
    )


def _event_supervision(
    config: AgriNeRFSettings,
    event_data: bool,
    native: bool,
    dark: bool,
    rgb_level: float,
    modalities: Tuple[str, ...],
    timed: bool,
    notes: List[str],
) -> Tuple[EventSupervision, bool]:
    """The event loss's supervision and gate (`event_data`: the dataset gives RGB frames, events with their windows
    and the frames' times; `native`: its event stream), with notes on what the data or low light turn off.

    Raises:
        ValueError: when the config turns the event loss on without event rays or a weight.
    """
    event_loss = config.event_supervision != "off"  # the event loss's one switch, checked here alone
    if event_loss and (config.event_rays_per_batch <= 0 or config.loss_coefficients.get("event_loss", 0.0) <= 0):
        raise ValueError(
            f"event_supervision {config.event_supervision!r} turns the event loss on, but event_rays_per_batch is "
            f"{config.event_rays_per_batch} and loss_coefficients['event_loss'] is "
            f"{config.loss_coefficients.get('event_loss', 0.0)}: give both a positive value, or switch the loss off with "
            "--pipeline.model.event-supervision off."
        )
    if event_loss and not event_data:
        event_loss = False
        notes.append(
            "Events: the event loss needs RGB frames, events with their windows and the frames' times and trajectory; "
            f"this dataset and config leave modalities {modalities} (timed: {timed}), so it is off."
        )
    if event_loss and dark and not config.low_light_event_loss:
        event_loss = False
        notes.append(
            f"Low light: the RGB frames average {rgb_level:.3f} of full scale (below low_light_level "
            f"{config.low_light_level}), so the event loss is off (--pipeline.model.low-light-event-loss True "
            "keeps it)."
        )
    supervision: EventSupervision = "off"
    gate = False
    if event_loss:
        supervision = config.event_supervision if native or config.event_supervision == "frames" else "frames"
        gate = config.event_gate
        if gate and supervision == "frames":
            # the gate's held-out samples are event-stream pixels: a dataset without the stream has none, and the
            # frames' event windows (warped onto the RGB camera's pixels) cannot leave the stream's pixels out
            gate, supervision = False, "off"
            why = (
                "this dataset has no event stream (events/stream.h5) to hold them out of"
                if not native
                else "the frames' event windows (event_supervision 'frames') are warped onto the RGB camera's pixels "
                "and cannot leave them out"
            )
            notes.append(
                "Events: event_gate weights the event loss by held-out event-stream pixels that training never sees, "
                f"and {why}: the event loss is off, not ungated (--pipeline.model.event-gate False trains it ungated "
                "on the frames' event windows"
                + (")." if not native else "; event_supervision 'stream' or 'pairs' gates it).")
            )
        elif supervision != config.event_supervision:
            notes.append(
                f"Events: event_supervision {config.event_supervision!r} needs the dataset's event stream "
                "(events/stream.h5), which it lacks: the frames' event windows supervise the event loss."
            )
    return supervision, gate


def _fruit_head(
    config: AgriNeRFSettings, metadata: Mapping[str, Any], thermal_view: bool, notes: List[str]
) -> Tuple[bool, bool]:
    """Whether the model has the fruit head (the frames have fruit masks, a weight), and whether the thermal camera's
    masks are supervised along its rays (`thermal_view`)."""
    has_fruit_head = (
        metadata.get(FRUIT_MASK.metadata) is not None
        and config.fruit_output
        and config.loss_coefficients.get("fruit_loss", 0.0) > 0
    )
    thermal_masks = has_fruit_head and any(metadata.get("fruit_mask_thermal") or ())
    fruit_thermal_view = thermal_masks and thermal_view
    if thermal_masks and not thermal_view:
        notes.append(
            "Fruit: some fruit masks are the thermal camera's view, but training cannot render along its rays (it "
            "needs the thermal camera's place, the frames' times and trajectory, and thermal rays per batch > 0): "
            "they are supervised on the RGB rays, a baseline away from what the thermal camera saw."
        )
    return has_fruit_head, fruit_thermal_view
