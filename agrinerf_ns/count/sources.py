"""Which output of a run ``agrinerf-count`` tells fruit apart by: one type (:data:`CountSource`), one description of what
a run has (:class:`RunOutputs`) and one resolver (:func:`resolve_source`) that both paths use. What each source is (its
outputs, how its fruit are found, its ranks in the orders below) is its row in
:mod:`agrinerf_ns.count.source_table`.

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

from typing import Annotated, Any, FrozenSet, Literal, Optional, Tuple

import tyro

from agrinerf_ns.count.errors import CountInputError
from agrinerf_ns.count.source_table import SOURCE_TABLE, auto_order
from agrinerf_ns.model.plan import ModelPlan

CountSource = Literal["auto", "fruit", "temperature", "thermal_camera", "thermal", "rgb"]
"""``fruit``: the fruit head's probability (learnt from the frames' fruit masks); ``temperature``: degrees C (a
radiometric thermal camera); ``thermal_camera``: the thermal camera's channel (field only); ``thermal``: the
cross-spectral channel; ``rgb``: fruit colour; ``auto``: :func:`resolve_source` picks. The command line's choices; a
source added to :data:`agrinerf_ns.count.source_table.SOURCE_TABLE` is counted by name from Python."""
SourceChoice = Annotated[str, tyro.conf.arg(constructor=CountSource, help_behavior_hint="(default: auto)")]
"""A settings field naming a source: the command line offers :data:`CountSource`; in Python any source of the table
(one added too)."""
CountPath = Literal["views", "field"]

VIEW_ORDER: Tuple[CountSource, ...] = auto_order("views")  # type: ignore[assignment]
"""The built-in sources of the view path's ``auto`` order (temperature, thermal, rgb)."""


class RunOutputs:
    """The sources a run gives on one path (its field's heads, or its rendered views), and whether its RGB frames are
    dark by the model's low-light rule (None: not known). ``RunOutputs(thermal=True, rgb=True)``; a source's name is
    also an attribute that says whether it has it."""

    __slots__ = ("sources", "dark")

    def __init__(self, dark: Optional[bool] = None, **has: bool) -> None:
        unknown = sorted(set(has) - set(SOURCE_TABLE))
        if unknown:
            raise TypeError(f"unknown counting sources {unknown} ({', '.join(SOURCE_TABLE)})")
        self.sources: FrozenSet[str] = frozenset(name for name, on in has.items() if on)
        self.dark = dark

    def __getattr__(self, name: str) -> bool:
        if name in SOURCE_TABLE:
            return name in self.sources
        raise AttributeError(name)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, RunOutputs) and (self.sources, self.dark) == (other.sources, other.dark)

    def __hash__(self) -> int:
        return hash((self.sources, self.dark))

    def __repr__(self) -> str:
        return f"RunOutputs({', '.join(self.available())}, dark={self.dark})"

    def has(self, source: str) -> bool:
        return source in self.sources

    def available(self) -> Tuple[str, ...]:
        """The sources it has, in the table's order (fruit, temperature, thermal_camera, thermal, rgb, then added)."""
        return tuple(name for name in SOURCE_TABLE if name in self.sources)

    @property
    def thermal_any(self) -> bool:
        """It has a thermal output (temperature, the thermal camera's channel or the cross-spectral one)."""
        return any(SOURCE_TABLE[name].thermal for name in self.sources if name in SOURCE_TABLE)


def model_plan(model: Any) -> Optional[ModelPlan]:
    """The plan an AgriNeRF model was built from (`agrinerf_ns.model.plan`); None for a stock Nerfstudio model."""
    plan = getattr(model, "plan", None)
    return plan if isinstance(plan, ModelPlan) else None


def rgb_frames_dark(model: Any) -> bool:
    """Whether the model's low-light rule called its RGB frames dark (a stock model has no such rule: False)."""
    plan = model_plan(model)
    return plan is not None and plan.low_light


def field_outputs(model: Any) -> RunOutputs:
    """What the field of ``model`` (an AgriNeRF model; a stock one has none of these heads) can be sampled for: the
    sources whose row samples the field and whose plan test the model's plan passes."""
    plan = model_plan(model)
    if plan is None:
        return RunOutputs(dark=False)
    return RunOutputs(
        dark=plan.low_light, **{n: row.sample is not None and row.has(plan) for n, row in SOURCE_TABLE.items()}
    )


def resolve_source(wanted: str, path: CountPath, outputs: RunOutputs, detector: str = "blobs") -> Tuple[str, str]:
    """(source, why) for ``path``: ``wanted`` when the run has it, else a :class:`CountInputError` naming what it has;
    ``auto``: the first the run has in the order the module docstring gives (RGB views first on a lit run), as the
    sources' rows rank them (:mod:`agrinerf_ns.count.source_table`)."""
    if wanted != "auto":
        if not outputs.has(wanted):
            have = ", ".join(outputs.available()) or "none"
            raise CountInputError(f"the run's model has no '{wanted}' output to count fruit from (it has: {have})")
        return wanted, "asked for"
    if path == "views":
        for lead in ("present", "lit"):
            for name, row in SOURCE_TABLE.items():
                if row.lead == lead and outputs.has(name) and (lead == "present" or outputs.dark is False):
                    return name, row.lead_why
    order = auto_order("field" if path == "field" else "yolo" if detector == "yolo" else "views")
    thermal = ", ".join(name for name in order if SOURCE_TABLE[name].thermal)
    for source in order:
        if outputs.has(source):
            return source, SOURCE_TABLE[source].fallback_why or f"the run's first thermal output ({thermal})"
    raise CountInputError("the run's model has none of the outputs fruit are counted from")
