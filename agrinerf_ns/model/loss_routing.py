"""The loss terms in one table (`TERMS`: each term, the output it compares with its target and the part that computes
it), how each reaches the shared density (the routed copies of outputs whose density gradient is scaled,
`density_gradient_scales`), and the field's own terms: the frames' data terms and the TensoRF regularisers
(`FieldTerms`).

Adding a loss term is one part (`model_part.ModelPart`, built by a row of `parts.PARTS`) and one row here; the plan
switches it on where it has a weight (`plan.resolve_plan`), and the model computes it, weighs it and sums it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Dict, List, Mapping, Optional, Tuple, cast

from jaxtyping import Float
from torch import Tensor
from torch.nn import Parameter

from agrinerf_ns.model import losses, thermal_view
from agrinerf_ns.model.field import AgriNeRFField
from agrinerf_ns.model.model_part import ModelPart, TermInputs
from agrinerf_ns.model.plane_tv import plane_tv


@dataclass(frozen=True)
class Term:
    """A row of the term table."""

    output: Optional[str]
    """The output the term compares with its target (its routed copies: "<output>/<term>"); None: a regulariser."""
    part: str
    """The part (a name in `parts.PARTS`) whose `loss` computes its raw value and whose `weigh` weighs it."""


TERMS: Dict[str, Term] = {
    "rgb_loss": Term("rgb", "field_terms"),
    "edi_prior_loss": Term("rgb", "events"),
    "event_loss": Term("rgb", "events"),
    "fruit_loss": Term("fruit", "fruit_head"),
    "thermal_loss": Term("thermal", "field_terms"),
    "thermal_camera_loss": Term("thermal_camera", "field_terms"),
    "temperature_loss": Term("temperature", "field_terms"),
    "reg_rgb_loss": Term("thermal", "field_terms"),
    "reg_event_loss": Term("thermal", "field_terms"),
    "l1_reg": Term(None, "field_terms"),
    "tv_reg_density": Term(None, "field_terms"),
    "tv_reg_appearance": Term(None, "field_terms"),
}
"""Every loss term, in the order the model computes them and sums them."""

TERM_OUTPUTS: Dict[str, str] = {
    term: row.output for term, row in TERMS.items() if row.output is not None and row.output != "fruit"
}
"""Each data loss term of the field's outputs and the output it compares with its target (the fruit head's term
reaches the density by its own switch, `fruit_shapes_geometry`)."""

PAPER_DENSITY_GRADIENT_SCALES: Dict[str, float] = {term: 1.0 for term in TERM_OUTPUTS}
"""Every term moves the shared density at full strength: the paper's loss as written, with one thermal output."""


def pred(inputs: TermInputs, term: str, prefix: str = "") -> Tensor:
    """The output `term` reads (`prefix`: of the thermal camera's view): its routed copy where training made one."""
    output = TERMS[term].output
    assert output is not None, f"{term} reads no output"
    name = prefix + output
    return inputs.outputs.get(f"{name}/{term}", inputs.outputs[name])


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
    for term, row in TERMS.items():  # the table itself: a term added to it is routed too
        name, scale = row.output, scales.get(term, 1.0)
        if name is None or name not in dense or scale == 1.0:
            continue
        if scale not in scaled:
            w = losses.scale_gradient(weights, scale)
            scaled[scale] = (w, w.sum(dim=-2).clamp(0.0, 1.0))  # Nerfstudio's AccumulationRenderer, clamped
        if (name, scale) not in composites:
            composites[(name, scale)] = composite(*scaled[scale], dense[name])
        routed[f"{name}/{term}"] = composites[(name, scale)]
    return routed


class FieldTerms(ModelPart):
    """The field's part: the frames' data terms of its heads (RGB, thermal, thermal camera, temperature, the
    cross-spectral L_reg), the TensoRF regularisers (training only) and its parameter groups. A thermal frame's
    terms are computed on the first rays of the batch seen from the thermal camera where training rendered them so
    (`thermal_view.py`), else on the RGB rays."""

    def __init__(self, field: AgriNeRFField) -> None:
        self.field = field

    def loss(self, term: str, inputs: TermInputs) -> Optional[Tensor]:
        return getattr(self, term)(inputs)

    def rgb_loss(self, inputs: TermInputs) -> Optional[Tensor]:
        image = _image(inputs)
        if image is None:
            return None
        return losses.rgb_loss(inputs.outputs.get("rgb_blurred", pred(inputs, "rgb_loss")), image)

    def thermal_loss(self, inputs: TermInputs, term: str = "thermal_loss") -> Optional[Tensor]:
        if "thermal" not in inputs.batch:
            return None
        view, rows = _thermal_view(inputs)
        return losses.thermal_loss(
            pred(inputs, term, view), _rows(inputs, "thermal", rows), _rows(inputs, "thermal_mask", rows)
        )

    def thermal_camera_loss(self, inputs: TermInputs) -> Optional[Tensor]:
        return self.thermal_loss(inputs, "thermal_camera_loss")

    def temperature_loss(self, inputs: TermInputs) -> Optional[Tensor]:
        head = self.field.temperature_head
        if "temperature" not in inputs.batch:
            return None
        assert head is not None
        view, rows = _thermal_view(inputs)
        return losses.thermal_loss(
            head.normalise(pred(inputs, "temperature_loss", view)),
            head.normalise(_rows(inputs, "temperature", rows)),
            _rows(inputs, "temperature_mask", rows),
        )

    def reg_rgb_loss(self, inputs: TermInputs) -> Optional[Tensor]:
        image = _image(inputs)
        return None if image is None else losses.cross_spectral_rgb_term(pred(inputs, "reg_rgb_loss"), image)

    def reg_event_loss(self, inputs: TermInputs) -> Optional[Tensor]:
        if "event" not in inputs.batch:
            return None
        event = inputs.batch["event"].to(inputs.device)
        return losses.cross_spectral_event_term(pred(inputs, "reg_event_loss"), event, inputs.target("event_mask"))

    def l1_reg(self, inputs: TermInputs) -> Optional[Tensor]:
        if not inputs.training:
            return None
        density = self.field.volumes()["density"]
        return losses.l1_volume_loss(density.plane_table, density.line_table)

    def tv_reg_density(self, inputs: TermInputs) -> Optional[Tensor]:
        return plane_tv(self.field.volumes()["density"]) if inputs.training else None

    def tv_reg_appearance(self, inputs: TermInputs) -> Optional[Tensor]:
        if not inputs.training:
            return None
        return cast(Tensor, sum(plane_tv(v) for name, v in self.field.volumes().items() if name != "density"))

    def param_groups(self) -> Dict[str, List[Parameter]]:
        """ "fields" (the heads' MLPs and the temperature head) and "encodings" (every TensoRF volume)."""
        field = self.field
        heads = [h for h in (field.rgb_head, field.thermal_head) if h is not None]
        temperature = list(field.temperature_head.parameters()) if field.temperature_head is not None else []
        return {
            "fields": [p for h in heads for p in h.mlp_parameters()] + temperature,
            "encodings": [p for vol in field.volumes().values() for p in vol.parameters()],
        }


def _image(inputs: TermInputs) -> Optional[Tensor]:
    image = inputs.batch.get("image")
    return None if image is None else image[..., :3].to(inputs.device)


def _thermal_view(inputs: TermInputs) -> Tuple[str, Optional[int]]:
    """The prefix of the thermal outputs the thermal frames' terms read and the batch rows they cover (None: all):
    the thermal camera's view where training rendered it, else the RGB rays."""
    if thermal_view.PREFIX + "thermal" not in inputs.outputs:
        return "", None
    return thermal_view.PREFIX, inputs.outputs[thermal_view.PREFIX + "thermal"].shape[0]


def _rows(inputs: TermInputs, key: str, rows: Optional[int]) -> Any:
    value = inputs.target(key)
    return None if value is None else value[:rows]
