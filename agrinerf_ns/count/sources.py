"""Which output of a run ``agrinerf-count`` tells fruit apart by: one type (:data:`CountSource`), one description of what
a run has (:class:`RunOutputs`) and one resolver (:func:`resolve_source`) that both paths use.

``auto`` is resolved in these orders, from the counts of results/count-seeds (F1 at 0.05 m):

- the view path on a run with a fruit head (trained from the frames' fruit masks): ``fruit``, its rendered regions
  (F1 0.35 against 0.20 from fruit colour on the same renders, four bright runs on reporting seeds:
  results/count-fruit-seeds; chosen on tuning seed 0, results/count-fruit);
- the view path on a run whose RGB frames are lit: ``rgb``. Fruit colour in the RGB views counted best in light
  (0.18-0.29; every thermal output 0.05 or less), so ``--path views`` counts a lit run as ``--path auto`` does;
- the view path otherwise (RGB frames dark by the model's low-light rule, no RGB output, or the light not known: a
  render folder written without it): ``temperature``, ``thermal``, ``rgb``. The thermal outputs do not fade in the
  dark; YOLO reads 8-bit images, so for it ``thermal``, ``rgb``;
- the field path: ``temperature``, ``thermal_camera``, ``thermal``, ``rgb``. ``--path auto`` takes it for dark or
  RGB-less runs, where the field's temperature counted best (0.04 against 0.02 from the RGB views); RGB only where the
  run has no thermal output, and the note says so.

The field path takes ``fruit`` only when asked for (``--path fruit``): sampled in 3D it counted far worse there (0.02).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal, Optional, Tuple

from agrinerf_ns.count.errors import CountInputError
from agrinerf_ns.model.plan import ModelPlan

CountSource = Literal["auto", "fruit", "temperature", "thermal_camera", "thermal", "rgb"]
"""``fruit``: the fruit head's probability (learnt from the frames' fruit masks); ``temperature``: degrees C (a
radiometric thermal camera); ``thermal_camera``: the thermal camera's channel (field only); ``thermal``: the
cross-spectral channel; ``rgb``: fruit colour; ``auto``: :func:`resolve_source` picks."""
CountPath = Literal["views", "field"]

VIEW_ORDER: Tuple[CountSource, ...] = ("temperature", "thermal", "rgb")
YOLO_ORDER: Tuple[CountSource, ...] = ("thermal", "rgb")
FIELD_ORDER: Tuple[CountSource, ...] = ("temperature", "thermal_camera", "thermal", "rgb")
SOURCES: Tuple[CountSource, ...] = ("fruit", *FIELD_ORDER)
"""Every source but ``auto``, in the order :meth:`RunOutputs.available` lists them."""


@dataclass(frozen=True)
class RunOutputs:
    """The sources a run gives on one path (its field's heads, or its rendered views), and whether its RGB frames are
    dark by the model's low-light rule (None: not known)."""

    fruit: bool = False
    temperature: bool = False
    thermal_camera: bool = False
    thermal: bool = False
    rgb: bool = False
    dark: Optional[bool] = None

    def has(self, source: str) -> bool:
        return source in SOURCES and bool(getattr(self, source))

    def available(self) -> Tuple[CountSource, ...]:
        """The sources it has, in the order fruit, temperature, thermal_camera, thermal, rgb."""
        return tuple(source for source in SOURCES if getattr(self, source))

    @property
    def thermal_any(self) -> bool:
        """It has a thermal output (temperature, the thermal camera's channel or the cross-spectral one)."""
        return self.temperature or self.thermal_camera or self.thermal


def model_plan(model: Any) -> Optional[ModelPlan]:
    """The plan an AgriNeRF model was built from (`agrinerf_ns.model.plan`); None for a stock Nerfstudio model."""
    plan = getattr(model, "plan", None)
    return plan if isinstance(plan, ModelPlan) else None


def rgb_frames_dark(model: Any) -> bool:
    """Whether the model's low-light rule called its RGB frames dark (a stock model has no such rule: False)."""
    plan = model_plan(model)
    return plan is not None and plan.low_light


def field_outputs(model: Any) -> RunOutputs:
    """What the field of ``model`` (an AgriNeRF model; a stock one has none of these heads) can be sampled for."""
    plan = model_plan(model)
    if plan is None:
        return RunOutputs(dark=False)
    return RunOutputs(
        fruit=plan.has_fruit_head,
        temperature=plan.has_temperature,
        thermal_camera=plan.has_thermal_camera,
        thermal=plan.has_thermal_head,
        rgb=plan.use_rgb,
        dark=plan.low_light,
    )


def resolve_source(
    wanted: str, path: CountPath, outputs: RunOutputs, detector: str = "blobs"
) -> Tuple[CountSource, str]:
    """(source, why) for ``path``: ``wanted`` when the run has it, else a :class:`CountInputError` naming what it has;
    ``auto``: the first the run has in the order the module docstring gives (RGB views first on a lit run)."""
    if wanted != "auto":
        if not outputs.has(wanted):
            have = ", ".join(outputs.available()) or "none"
            raise CountInputError(f"the run's model has no '{wanted}' output to count fruit from (it has: {have})")
        return wanted, "asked for"  # type: ignore[return-value]
    if path == "views" and outputs.fruit:
        return "fruit", "the run has a fruit head: its rendered fruit regions counted best (tuning seed 0)"
    if path == "views" and outputs.rgb and outputs.dark is False:
        return "rgb", "the run's RGB frames are lit: fruit colour counted best in light (results/count-seeds)"
    order = FIELD_ORDER if path == "field" else YOLO_ORDER if detector == "yolo" else VIEW_ORDER
    for source in order:
        if outputs.has(source):
            if source == "rgb":
                return source, "the run has no thermal output (trained without thermal frames): fruit colour in RGB"
            return source, f"the run's first thermal output ({', '.join(order[:-1])})"
    raise CountInputError("the run's model has none of the outputs fruit are counted from")
