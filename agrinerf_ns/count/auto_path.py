"""``agrinerf-count --path auto`` (the default): count a trained run the way that counted best on runs of its kind.

Measured on the ``count-small`` profile (the count profile before the realistic one; ``agrinerf-lite``, garden and
orchard, four lightings, three seeds each: results/count-seeds), F1 at 0.05 m pooled per lighting:

- lit RGB frames (bright, shadowed, dusk): fruit colour in the rendered RGB views, placed by their rays, 0.18-0.29;
  every thermal path 0.05 or less;
- dark RGB frames (the model's low-light rule, ``low_light_level``): the field's temperature, 0.04 at a count error
  of -15%, against 0.02 at -91% from the RGB views;
- no RGB head (trained on thermal frames alone): the field's thermal output, the only one it has;
- a dataset with fruit bodies (``--path bodies``): since then, the bodies, which counted the dark rows best
  (results/fruit-count-dark) and, placed from the lit masks, the lit rows as the fruit head's views did on the bright
  tuning captures (results/fruit-count-lit). A dusk run whose bodies are the thermal camera's (dim frames) keeps its
  fruit head: at dusk the two were level on the reporting captures, and the thermal bodies need a thermal camera that
  resolves the fruit (the demo's 72 x 96 frames do not).

The plan picks the path; each path's source is resolved by :func:`agrinerf_ns.count.sources.resolve_source`, the same
whether the path was chosen here or asked for by name.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict, Literal, Optional

from agrinerf_ns.count.errors import CountInputError
from agrinerf_ns.count.sources import field_outputs
from agrinerf_ns.dataset_format import FRUIT_BODIES, sighting_cameras


@dataclass(frozen=True)
class CountPlan:
    """Which path counts a run, and why (printed; count.json holds the settings it leads to)."""

    path: Literal["views", "field", "bodies"]
    why: str
    triangulate: bool = False
    """The view path places its fruit by their rays."""


def body_cameras(dataset: Optional[Path]) -> Dict[str, int]:
    """The fruit-body sightings per camera of ``dataset`` (empty where it holds none or is unknown)."""
    path = None if dataset is None else Path(dataset) / FRUIT_BODIES
    if path is None or not path.is_file():
        return {}
    try:
        return sighting_cameras(json.loads(path.read_text())["sightings"])
    except (OSError, json.JSONDecodeError, KeyError, TypeError, AttributeError) as err:
        raise CountInputError(f"{path}: not a fruit bodies file ({err})") from err


def choose_plan(model: Any, dataset: Optional[Path] = None) -> CountPlan:
    """The plan for a loaded run's ``model`` (an AgriNeRF model, or a stock one such as Nerfacto: views) trained on
    ``dataset`` (its folder, where known)."""
    outputs = field_outputs(model)
    thermal_field = outputs.thermal_any
    bodies = body_cameras(dataset)
    if outputs.dark and bodies:
        return CountPlan(
            "bodies",
            "the run's RGB frames are dark and its dataset holds the thermal fruit bodies: the bodies placed by the "
            "poses, which counted best in the dark (the row's countable fruit, F1 0.63 and 0.35 against 0.31 and 0.20 "
            "from the fruit head's views, two tuning gardens: results/fruit-count-dark)",
        )
    if not outputs.dark and bodies.get("rgb", 0) > 0:
        return CountPlan(
            "bodies",
            "the run's dataset holds the fruit its lit masks placed with the poses: on the four bright tuning "
            "captures they counted the row's countable fruit as the fruit head's views did (F1 0.53 and 0.53, "
            "paired), with no render (results/fruit-count-lit)",
        )
    if outputs.fruit:
        return CountPlan(
            "views",
            "the run has a fruit head: the regions of its rendered fruit channel in its views, placed by depth, which "
            "counted best (F1 0.35 against 0.20 from fruit colour on the same renders, four bright runs on reporting "
            "seeds: results/count-fruit-seeds)",
        )
    if thermal_field and not outputs.rgb:
        return CountPlan("field", "the run has no RGB head (trained without RGB frames): its field's thermal output")
    if thermal_field and outputs.dark:
        return CountPlan(
            "field",
            "the run's RGB frames are dark (its low-light rule): the field's temperature, which counted best in the "
            "dark (F1 0.04 against 0.02 from the RGB views, results/count-seeds)",
        )
    return CountPlan(
        "views",
        "the run's RGB frames are lit (or it has no thermal field): fruit colour in its RGB views placed by their "
        "rays, which counted best in light (F1 0.18-0.29 against 0.05 or less from thermal, results/count-seeds)",
        triangulate=True,
    )
