"""The data loss terms and how each reaches the shared density: every term, the output it compares with its target
(`TERM_OUTPUTS`), the routed copies of outputs whose density gradient is scaled (`density_gradient_scales`), and the
TensoRF regularisers."""

from __future__ import annotations

from typing import Any, Callable, Dict, Mapping, Optional, Tuple, cast

import torch
from jaxtyping import Float
from torch import Tensor

from agrinerf_ns import colour
from agrinerf_ns.model import losses, thermal_view
from agrinerf_ns.model.event_term import EventTerm
from agrinerf_ns.model.field import AgriNeRFField, TemperatureHead
from agrinerf_ns.model.fruit_head import fruit_loss
from agrinerf_ns.model.plan import ModelPlan
from agrinerf_ns.model.plane_tv import plane_tv

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
    scales: Mapping[str, float],
    weights: Float[Tensor, "rays samples 1"],
    dense: Dict[str, Tensor],
    composite: Callable[[Tensor, Tensor, Tensor], Tensor],
) -> Dict[str, Tensor]:
    """Training only: for each data term whose density gradient scale (`scales`, 1 where absent) is not 1, its output
    composited (`composite(weights, accumulation, values)`) with weights whose gradient is scaled (same values),
    under the key "<output>/<term>"."""
    routed: Dict[str, Tensor] = {}
    scaled: Dict[float, Tuple[Tensor, Tensor]] = {}  # scale -> (weights, their accumulation)
    composites: Dict[Tuple[str, float], Tensor] = {}
    for term, name in TERM_OUTPUTS.items():
        scale = scales.get(term, 1.0)
        if name not in dense or scale == 1.0:
            continue
        if scale not in scaled:
            w = losses.scale_gradient(weights, scale)
            scaled[scale] = (w, w.sum(dim=-2).clamp(0.0, 1.0))  # Nerfstudio's AccumulationRenderer, clamped
        if (name, scale) not in composites:
            composites[(name, scale)] = composite(*scaled[scale], dense[name])
        routed[f"{name}/{term}"] = composites[(name, scale)]
    return routed


class DataTerms:
    """The raw (unweighted) data loss terms of one model's plan, in a fixed order (the loss sums them in it), each
    reading its routed output ("<output>/<term>", training) where there is one."""

    def __init__(
        self,
        plan: ModelPlan,
        coefficients: Mapping[str, float],
        events: Optional[EventTerm] = None,
        temperature_head: Optional[TemperatureHead] = None,
    ) -> None:
        self.plan, self.coefficients, self.events, self.temperature_head = plan, coefficients, events, temperature_head

    def __call__(self, outputs: Dict[str, Tensor], batch: Dict[str, Any], device: torch.device) -> Dict[str, Tensor]:
        plan, coef = self.plan, self.coefficients

        def pred(term: str, prefix: str = "") -> Tensor:
            name = prefix + TERM_OUTPUTS[term]
            return outputs.get(f"{name}/{term}", outputs[name])

        def optional(key: str) -> Any:
            value = batch.get(key)
            return None if value is None else value.to(device)

        terms: Dict[str, Tensor] = {}
        image = batch["image"][..., :3].to(device) if "image" in batch else None
        if plan.use_rgb and image is not None:
            terms["rgb_loss"] = losses.rgb_loss(outputs.get("rgb_blurred", pred("rgb_loss")), image)
        if "edi_factor" in outputs and image is not None:  # EvDeblurNeRF's EDI prior on the frame ray
            sharp = colour.linear_to_srgb(colour.srgb_to_linear(image) / outputs["edi_factor"])
            terms["edi_prior_loss"] = losses.masked_mse(pred("edi_prior_loss"), sharp, outputs["edi_valid"])
        if self.events is not None:
            terms.update(self.events.loss(outputs, batch, device))
        if "fruit" in outputs and "fruit" in batch:  # the fruit head against the frames' masks (fruit_head.py)
            terms["fruit_loss"] = self.fruit_term(outputs, optional("fruit"), optional("fruit_known"), batch, device)
        if not plan.has_thermal_head:
            return terms
        # the thermal frames' terms: on the first rays of the batch seen from the thermal camera, where training
        # rendered them so (thermal_view.py), else on the RGB rays
        view = thermal_view.PREFIX if thermal_view.PREFIX + "thermal" in outputs else ""
        rows = outputs[view + "thermal"].shape[0] if view else None

        def thermal_pred(term: str) -> Tensor:
            return pred(term, view)

        def thermal_target(key: str) -> Any:
            value = optional(key)
            return None if value is None else value[:rows]

        if plan.use_thermal and "thermal" in batch:
            thermal, thermal_mask = thermal_target("thermal"), thermal_target("thermal_mask")
            terms["thermal_loss"] = losses.thermal_loss(thermal_pred("thermal_loss"), thermal, thermal_mask)
            if plan.has_thermal_camera:
                terms["thermal_camera_loss"] = losses.thermal_loss(
                    thermal_pred("thermal_camera_loss"), thermal, thermal_mask
                )
        if plan.has_temperature and "temperature" in batch:
            head = self.temperature_head
            assert head is not None
            terms["temperature_loss"] = losses.thermal_loss(
                head.normalise(thermal_pred("temperature_loss")),
                head.normalise(thermal_target("temperature")),
                thermal_target("temperature_mask"),
            )
        if plan.use_rgb and image is not None and coef.get("reg_rgb_loss", 0.0) > 0:
            terms["reg_rgb_loss"] = losses.cross_spectral_rgb_term(pred("reg_rgb_loss"), image)
        if plan.use_events and "event" in batch and coef.get("reg_event_loss", 0.0) > 0:
            terms["reg_event_loss"] = losses.cross_spectral_event_term(
                pred("reg_event_loss"), batch["event"].to(device), optional("event_mask")
            )
        return terms

    @staticmethod
    def fruit_term(
        outputs: Dict[str, Tensor], fruit: Tensor, known: Tensor, batch: Dict[str, Any], device: torch.device
    ) -> Tensor:
        """The fruit loss: a mask of the RGB camera's view on the RGB rays; one of the thermal camera's view on the
        first rays rendered along the thermal camera's rays (`thermal_view`), and not on the RGB rays."""
        tv = thermal_view.PREFIX + "fruit"
        if tv not in outputs or "fruit_thermal" not in batch:
            return fruit_loss(outputs["fruit"], fruit, known)
        thermal = batch["fruit_thermal"].to(device)
        m = outputs[tv].shape[0]
        rendered = torch.cat([outputs["fruit"], outputs[tv]])
        known = torch.cat([known * (1.0 - thermal), known[:m] * thermal[:m]])
        return fruit_loss(rendered, torch.cat([fruit, fruit[:m]]), known)


def regularisers(field: AgriNeRFField, coefficients: Mapping[str, float]) -> Dict[str, Tensor]:
    """TensoRF L1 (density volume) and TV (density / appearance planes) for the terms with a weight."""
    terms: Dict[str, Tensor] = {}
    volumes = field.volumes()
    if coefficients.get("l1_reg", 0.0) > 0:
        density = volumes["density"]
        terms["l1_reg"] = losses.l1_volume_loss(density.plane_table, density.line_table)
    if coefficients.get("tv_reg_density", 0.0) > 0:
        terms["tv_reg_density"] = plane_tv(volumes["density"])
    if coefficients.get("tv_reg_appearance", 0.0) > 0:
        terms["tv_reg_appearance"] = cast(Tensor, sum(plane_tv(v) for name, v in volumes.items() if name != "density"))
    return terms
