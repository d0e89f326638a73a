"""The data loss terms and how each reaches the shared density: every term, the output it compares with its target
(`TERM_OUTPUTS`), the routed copies of outputs whose density gradient is scaled (`density_gradient_scales`), and the
TensoRF regularisers."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Dict, Tuple, cast

from jaxtyping import Float
from torch import Tensor

from agrinerf_ns import colour
from agrinerf_ns.model import event_supervision, losses, thermal_view
from agrinerf_ns.model.fruit_head import fruit_loss
from agrinerf_ns.model.plane_tv import plane_tv

if TYPE_CHECKING:
    from agrinerf_ns.model.model import AgriNeRFModel

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


def routed_outputs(
    model: AgriNeRFModel, weights: Float[Tensor, "rays samples 1"], dense: Dict[str, Tensor]
) -> Dict[str, Tensor]:
    """Training only: for each data term whose density gradient scale is not 1, its output composited with weights
    whose gradient is scaled (same values), under the key "<output>/<term>"."""
    routed: Dict[str, Tensor] = {}
    scaled: Dict[float, Tuple[Tensor, Tensor]] = {}  # scale -> (weights, their accumulation)
    composites: Dict[Tuple[str, float], Tensor] = {}
    for term, name in TERM_OUTPUTS.items():
        scale = model.density_gradient_scale(term)
        if name not in dense or scale == 1.0:
            continue
        if scale not in scaled:
            w = losses.scale_gradient(weights, scale)
            scaled[scale] = (w, model.renderer_accumulation(w).clamp(0.0, 1.0))
        if (name, scale) not in composites:
            composites[(name, scale)] = model.composite(*scaled[scale], dense[name])
        routed[f"{name}/{term}"] = composites[(name, scale)]
    return routed


def data_terms(model: AgriNeRFModel, outputs: Dict[str, Tensor], batch: Dict[str, Any]) -> Dict[str, Tensor]:
    """Raw (unweighted) data loss terms for the modalities this model uses and the batch carries; each term reads
    its routed output ("<output>/<term>", training) where there is one."""
    coef = model.config.loss_coefficients

    def pred(term: str, prefix: str = "") -> Tensor:
        name = prefix + TERM_OUTPUTS[term]
        return outputs.get(f"{name}/{term}", outputs[name])

    def optional(key: str) -> Any:
        value = batch.get(key)
        return None if value is None else value.to(model.device)

    terms: Dict[str, Tensor] = {}
    image = batch["image"][..., :3].to(model.device) if "image" in batch else None
    if model.use_rgb and image is not None:
        terms["rgb_loss"] = losses.rgb_loss(outputs.get("rgb_blurred", pred("rgb_loss")), image)
    if "edi_factor" in outputs and image is not None:  # EvDeblurNeRF's EDI prior on the frame ray
        sharp = colour.linear_to_srgb(colour.srgb_to_linear(image) / outputs["edi_factor"])
        terms["edi_prior_loss"] = losses.masked_mse(pred("edi_prior_loss"), sharp, outputs["edi_valid"])
    mode = model.plan.event_supervision
    if mode == "pairs" and "event_target" in outputs:  # EvDeblurNeRF's event-to-event samples (none: no pair)
        terms["event_loss"] = losses.event_pair_loss(
            outputs["event_log_start"], outputs["event_log_end"], outputs["event_target"]
        )
    elif mode == "stream" and "event_on" in outputs:  # the stream's event pixels carry their own counts
        terms["event_loss"] = losses.event_loss(
            outputs["event_log_start"],
            outputs["event_log_end"],
            outputs["event_on"],
            outputs["event_off"],
            *event_supervision.event_thresholds(model),
            lower_bound=model.config.event_loss_bound,
        )
    elif mode == "frames" and "event_log_start" in outputs and "event_on" in batch:
        m = outputs["event_log_start"].shape[0]
        mask = optional("event_mask")
        terms["event_loss"] = losses.event_loss(
            outputs["event_log_start"],
            outputs["event_log_end"],
            batch["event_on"][:m].to(model.device),
            batch["event_off"][:m].to(model.device),
            *event_supervision.event_thresholds(model),
            None if mask is None else mask[:m],
            lower_bound=model.config.event_loss_bound,
        )
    if "fruit" in outputs and "fruit" in batch:  # the fruit head against the frames' masks (fruit_head.py)
        terms["fruit_loss"] = fruit_loss(outputs["fruit"], optional("fruit"), optional("fruit_known"))
    if not model.has_thermal_head:
        return terms
    # the thermal frames' terms: on the first rays of the batch seen from the thermal camera, where training rendered
    # them so (thermal_view.py), else on the RGB rays
    view = thermal_view.PREFIX if thermal_view.PREFIX + "thermal" in outputs else ""
    rows = outputs[view + "thermal"].shape[0] if view else None

    def thermal_pred(term: str) -> Tensor:
        return pred(term, view)

    def thermal_target(key: str) -> Any:
        value = optional(key)
        return None if value is None else value[:rows]

    if model.use_thermal and "thermal" in batch:
        thermal, thermal_mask = thermal_target("thermal"), thermal_target("thermal_mask")
        terms["thermal_loss"] = losses.thermal_loss(thermal_pred("thermal_loss"), thermal, thermal_mask)
        if model.has_thermal_camera:
            terms["thermal_camera_loss"] = losses.thermal_loss(
                thermal_pred("thermal_camera_loss"), thermal, thermal_mask
            )
    if model.has_temperature and "temperature" in batch:
        head = model.field.temperature_head
        assert head is not None
        terms["temperature_loss"] = losses.thermal_loss(
            head.normalise(thermal_pred("temperature_loss")),
            head.normalise(thermal_target("temperature")),
            thermal_target("temperature_mask"),
        )
    if model.use_rgb and image is not None and coef.get("reg_rgb_loss", 0.0) > 0:
        terms["reg_rgb_loss"] = losses.cross_spectral_rgb_term(pred("reg_rgb_loss"), image)
    if model.use_events and "event" in batch and coef.get("reg_event_loss", 0.0) > 0:
        terms["reg_event_loss"] = losses.cross_spectral_event_term(
            pred("reg_event_loss"), batch["event"].to(model.device), optional("event_mask")
        )
    return terms


def regularisers(model: AgriNeRFModel) -> Dict[str, Tensor]:
    """TensoRF L1 (density volume) and TV (density / appearance planes) for the terms with a weight."""
    coef = model.config.loss_coefficients
    terms: Dict[str, Tensor] = {}
    volumes = model.field.volumes()
    if coef.get("l1_reg", 0.0) > 0:
        density = volumes["density"]
        terms["l1_reg"] = losses.l1_volume_loss(density.plane_table, density.line_table)
    if coef.get("tv_reg_density", 0.0) > 0:
        terms["tv_reg_density"] = plane_tv(volumes["density"])
    if coef.get("tv_reg_appearance", 0.0) > 0:
        terms["tv_reg_appearance"] = cast(Tensor, sum(plane_tv(v) for name, v in volumes.items() if name != "density"))
    return terms
