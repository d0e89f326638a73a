"""The counting sources, one row each (:class:`SourceRow` in :data:`SOURCE_TABLE`): what a source renders, whether a run
has it (from its model plan), how its fruit are found in a rendered view, how the field is sampled for it, and its
place in the ``auto`` orders of :func:`agrinerf_ns.count.sources.resolve_source`.

The view path, the field path, the render folders and the resolver read this table and dispatch on no source name;
adding a source is adding a row (:func:`add_source`; docs/count.md, "Adding a counting source").
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Dict, List, Literal, Optional, Tuple

import numpy as np
from jaxtyping import Float

from agrinerf_ns.fruit.blobs import BlobConfig, Detection, find_blobs
from agrinerf_ns.fruit.colour_score import fruit_colour
from agrinerf_ns.fruit.regions import fruit_regions
from agrinerf_ns.fruit.view import MIN_ACCUMULATION, View
from agrinerf_ns.images import to_uint8
from agrinerf_ns.model.plan import ModelPlan

FindFruit = Callable[[View, float, BlobConfig], List[Detection]]
"""(view, dataparser scale: Nerfstudio units per dataset unit, blob settings) -> the view's fruit."""
FieldSampler = Callable[[Any, Any, Dict[Any, Any]], Any]
"""(model, the points' grid coordinates, the field's appearance heads there) -> an (n, channels) tensor."""
Order = Literal["views", "yolo", "field"]
"""The ``auto`` orders: the view path with blobs, with YOLO, and the field path."""


@dataclass(frozen=True)
class RenderedOutput:
    """A model output a rendered view keeps: its name (the model's output key, the ``.npz`` array, the view's
    attribute), how it is stored, and how the error naming a view without it calls it."""

    name: str
    dtype: Any = np.float32
    """Stored as (``.npz``); read back as float32."""
    channels: int = 1
    what: str = ""
    """How the error calls it (default: the name in quotes)."""
    missing: str = ""
    """Why a run renders none, e.g. `` (trained without fruit masks)``."""


@dataclass(frozen=True)
class SourceRow:
    """One counting source."""

    name: str
    has: Callable[[ModelPlan], bool]
    """Whether a run built from this plan has it (its field can be sampled for it; its views render it)."""
    renders: Tuple[RenderedOutput, ...] = ()
    """The outputs a rendered view keeps for it; a view holds the source where it holds the first (none: field only)."""
    image: Optional[Callable[[View], Float[np.ndarray, "h w"]]] = None
    """The image of a rendered view its fruit stand out in as fruit-sized blobs of local contrast
    (:func:`agrinerf_ns.fruit.blobs.find_blobs`)."""
    regions: Optional[FindFruit] = None
    """Instead of blobs of ``image``: how its fruit regions are found in a view (None for both: the field only)."""
    one_sided: bool = False
    """A score, not a temperature: fruit stand above their surroundings only, whatever ``--polarity`` says (the view
    path's blobs and the field path's voxels)."""
    probability: bool = False
    """The field path: its value is a fruit probability, so fruit voxels are those reaching ``--fruit-probability``
    (not those that stand out)."""
    voxel_value: Optional[Callable[[np.ndarray], Float[np.ndarray, " n"]]] = None
    """The field path: one value per voxel from its (n, channels) samples (None: the first channel)."""
    lift_depth: Optional[str] = None
    """The rendered output its view regions are lifted by with ``--fruit-depth`` (None: the rendered depth)."""
    eight_bit: Optional[Callable[[View], np.ndarray]] = None
    """The 8-bit BGR image YOLO reads (None: the RGB render)."""
    sample: Optional[FieldSampler] = None
    """How the field is sampled for it (None: the views only)."""
    channels: int = 1
    """Channels of its field samples."""
    thermal: bool = False
    """A thermal output: the note of an ``auto`` choice names it, :attr:`RunOutputs.thermal_any` counts it."""
    order: Dict[str, int] = field(default_factory=dict)
    """Its rank in each ``auto`` order it is in (:data:`Order`; lower first)."""
    lead: Optional[Literal["present", "lit"]] = None
    """The view path's ``auto`` takes it ahead of the orders where the run has it (``present``), or where the run has
    it and its RGB frames are lit (``lit``), saying ``lead_why``."""
    lead_why: str = ""
    fallback_why: str = ""
    """What ``auto`` says when it takes it from an order (default: the run's first thermal output)."""

    def finds_in_views(self) -> bool:
        return self.regions is not None or self.image is not None

    def find(self, view: View, scale: float, config: BlobConfig) -> List[Detection]:
        """The fruit of ``view``: its ``regions``, else the blobs of its ``image``; ``scale``: the dataparser scale."""
        if self.regions is not None:
            return self.regions(view, scale, config)
        if self.image is None:
            raise ValueError(f"the '{self.name}' source is counted in the field only (--path field)")
        return find_blobs(view, self.image(view), scale, config, self.one_sided)

    def value(self, samples: np.ndarray) -> Float[np.ndarray, " n"]:
        """One value per voxel of the field's (n, channels) samples."""
        if self.voxel_value is None or len(samples) == 0:
            return samples[:, 0].astype(np.float32)
        return self.voxel_value(samples)


def channel(name: str) -> Callable[[View], Float[np.ndarray, "h w"]]:
    """A view's ``name`` output itself, as the image fruit stand out in."""
    return lambda view: view.optional_output(name).astype(np.float32)


def colour_image(view: View) -> Float[np.ndarray, "h w"]:
    """A view's fruit-colour score (:func:`agrinerf_ns.fruit.colour_score.fruit_colour`)."""
    return fruit_colour(view.optional_output("rgb"), view.accumulation >= MIN_ACCUMULATION)


def colour_voxels(samples: np.ndarray) -> Float[np.ndarray, " n"]:
    """The fruit-colour score of sampled RGB."""
    rgb = samples.astype(np.float32).reshape(-1, 1, 3)
    return fruit_colour(rgb, np.ones(rgb.shape[:2], bool))[:, 0]


def rgb_eight_bit(view: View) -> np.ndarray:
    """The RGB render as 8-bit BGR (YOLO trained by agrinerf-detect reads 8-bit PNGs)."""
    return np.ascontiguousarray(to_uint8(view.optional_output("rgb"))[..., ::-1])


def thermal_eight_bit(view: View) -> np.ndarray:
    """The cross-spectral render as 8-bit gray in three channels."""
    return np.repeat(to_uint8(view.optional_output("thermal"))[..., None], 3, axis=-1)


def no_eight_bit(view: View) -> np.ndarray:
    raise ValueError("the YOLO detector reads 8-bit rgb or thermal renders; use --detector blobs on temperature")


def sample_fruit(model: Any, coords: Any, heads: Dict[Any, Any]) -> Any:
    """The fruit head's probability at the points."""
    field = model.field
    return model.fruit_head.probability(field.density_encoding.features(field.corners(coords)), coords)


def sample_rgb(model: Any, coords: Any, heads: Dict[Any, Any]) -> Any:
    from nerfstudio.field_components.field_heads import FieldHeadNames

    return heads[FieldHeadNames.RGB]


def sample_temperature(model: Any, coords: Any, heads: Dict[Any, Any]) -> Any:
    """Degrees C."""
    from agrinerf_ns.model.field_heads import AgriNeRFFieldHeadNames

    return model.field.temperature_head.to_celsius(heads[AgriNeRFFieldHeadNames.TEMPERATURE])


def thermal_channel(index: int) -> FieldSampler:
    """Channel ``index`` of the field's thermal head (0: cross-spectral, 1: the thermal camera's)."""

    def sample(model: Any, coords: Any, heads: Dict[Any, Any]) -> Any:
        from agrinerf_ns.model.field_heads import AgriNeRFFieldHeadNames

        return heads[AgriNeRFFieldHeadNames.THERMAL][..., index : index + 1]

    return sample


SOURCE_TABLE: Dict[str, SourceRow] = {
    row.name: row
    for row in (
        SourceRow(
            "fruit", lambda plan: plan.has_fruit_head,
            renders=(RenderedOutput("fruit", np.float16, missing=" (trained without fruit masks)"),
                     RenderedOutput("fruit_depth")),
            regions=fruit_regions, lift_depth="fruit_depth", sample=sample_fruit, probability=True, lead="present",
            lead_why="the run has a fruit head: its rendered fruit regions counted best (tuning seed 0)",
        ),
        SourceRow(
            "temperature", lambda plan: plan.has_temperature,
            renders=(RenderedOutput("temperature", missing=" (no radiometric thermal camera)"),),
            image=channel("temperature"), eight_bit=no_eight_bit, sample=sample_temperature, thermal=True,
            order={"views": 0, "field": 0},
        ),
        SourceRow(
            "thermal_camera", lambda plan: plan.has_thermal_camera, sample=thermal_channel(1), thermal=True,
            order={"field": 1},
        ),
        SourceRow(
            "thermal", lambda plan: plan.has_thermal_head,
            renders=(RenderedOutput("thermal", np.float16, what="cross-spectral 'thermal'"),),
            image=channel("thermal"), eight_bit=thermal_eight_bit, sample=thermal_channel(0), thermal=True,
            order={"views": 1, "yolo": 0, "field": 2},
        ),
        SourceRow(
            "rgb", lambda plan: plan.use_rgb,
            renders=(RenderedOutput("rgb", np.float16, channels=3, missing=" (trained without RGB frames)"),),
            image=colour_image, one_sided=True, eight_bit=rgb_eight_bit, sample=sample_rgb, channels=3,
            voxel_value=colour_voxels,
            order={"views": 2, "yolo": 1, "field": 3}, lead="lit",
            lead_why="the run's RGB frames are lit: fruit colour counted best in light (results/count-seeds)",
            fallback_why="the run has no thermal output (trained without thermal frames): fruit colour in RGB",
        ),
    )
}  # fmt: skip
"""Every counting source but ``auto``, in the order :meth:`RunOutputs.available` lists them (fruit, temperature,
thermal_camera, thermal, rgb, then any added)."""


def add_source(row: SourceRow) -> None:
    """Add a counting source (its name new; an output it renders new, or one another source renders alike)."""
    if row.name in SOURCE_TABLE or row.name == "auto":
        raise ValueError(f"counting source {row.name!r} exists")
    SOURCE_TABLE[row.name] = row


def source_row(name: str) -> SourceRow:
    """The row of source ``name``; ValueError listing the sources for an unknown one."""
    if name not in SOURCE_TABLE:
        raise ValueError(f"unknown counting source {name!r} ({', '.join(SOURCE_TABLE)})")
    return SOURCE_TABLE[name]


def rendered_outputs() -> Dict[str, RenderedOutput]:
    """Every output the sources' views keep, by name (the first row naming one defines it)."""
    outputs: Dict[str, RenderedOutput] = {}
    for row in SOURCE_TABLE.values():
        for output in row.renders:
            outputs.setdefault(output.name, output)
    return outputs


def auto_order(order: Order) -> Tuple[str, ...]:
    """The sources of an ``auto`` order, first first."""
    ranked = [
        (row.order[order], index, row.name) for index, row in enumerate(SOURCE_TABLE.values()) if order in row.order
    ]
    return tuple(name for _, _, name in sorted(ranked))
