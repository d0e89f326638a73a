"""``agrinerf-count --path auto``: the path that counted best on runs of a kind (results/count-seeds) is chosen from
the run's own model: RGB views placed by rays where its RGB frames are lit, the field's thermal outputs where they are
dark (the model's low-light rule) or absent."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Sequence

import pytest
import torch
from helpers.small_model import SMALL_MODEL
from nerfstudio.data.scene_box import SceneBox

from agrinerf_ns.count.auto_path import choose_plan
from agrinerf_ns.count.sources import field_outputs, resolve_source
from agrinerf_ns.dataset_format import FRUIT_BODIES
from agrinerf_ns.model.model import AgriNeRFModelConfig


def _model(modalities: Sequence[str], rgb_level: float):
    """A small AgriNeRF model set up as a dataset of ``modalities`` whose RGB frames average ``rgb_level``."""
    box = SceneBox(aabb=torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]))
    metadata = {"modalities": tuple(modalities), "rgb_level": rgb_level}
    return AgriNeRFModelConfig(**SMALL_MODEL).setup(scene_box=box, num_train_data=4, metadata=metadata)


@pytest.mark.parametrize(
    "modalities, rgb_level, path",
    [
        (("rgb", "thermal", "events"), 0.4, "views"),  # lit: the RGB views, placed by rays
        (("rgb", "thermal", "events"), 0.039, "field"),  # below low_light_level 0.04: the field's temperature
        (("rgb", "thermal", "events"), 0.041, "views"),
        (("thermal",), float("nan"), "field"),  # no RGB head: the only outputs it has are thermal
        (("rgb",), 0.01, "views"),  # dark, but no thermal frames: nothing better than its RGB
    ],
)
def test_the_plan_follows_the_light_and_the_heads_of_the_run(modalities, rgb_level: float, path: str) -> None:
    model = _model(modalities, rgb_level)
    plan = choose_plan(model)
    assert plan.path == path
    if path == "views":  # the view path's own resolver then detects on the RGB views
        assert plan.triangulate and "rays" in plan.why
        assert resolve_source("auto", "views", field_outputs(model))[0] == "rgb"
    else:
        assert "field" in plan.why


@pytest.mark.parametrize("rgb_level", [0.4, 0.01], ids=["lit", "dark"])
def test_a_run_with_a_fruit_head_is_counted_on_its_fruit_channel(rgb_level: float) -> None:
    """Lit or dark, a run trained with fruit masks is counted by the view path on its rendered fruit regions."""
    box = SceneBox(aabb=torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]))
    metadata = {"modalities": ("rgb", "thermal"), "rgb_level": rgb_level, "fruit_mask_filenames": ["m.png"] * 4}
    model = AgriNeRFModelConfig(**SMALL_MODEL).setup(scene_box=box, num_train_data=4, metadata=metadata)
    plan = choose_plan(model)
    assert plan.path == "views" and not plan.triangulate and "fruit head" in plan.why
    assert resolve_source("auto", "views", field_outputs(model))[0] == "fruit"


@pytest.mark.parametrize(
    ("rgb_level", "bodies", "path"), [(0.01, True, "bodies"), (0.4, True, "bodies"), (0.01, False, "views")]
)
def test_a_run_whose_dataset_holds_fruit_bodies_is_counted_from_them(
    tmp_path: Path, rgb_level: float, bodies: bool, path: str
) -> None:
    """The bodies path wherever the data stage placed fruit bodies (thermal ones in the dark, the masks' in light); a
    run whose dataset has none keeps its fruit channel."""
    box = SceneBox(aabb=torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]))
    metadata = {"modalities": ("rgb", "thermal"), "rgb_level": rgb_level, "fruit_mask_filenames": ["m.png"] * 4}
    model = AgriNeRFModelConfig(**SMALL_MODEL).setup(scene_box=box, num_train_data=4, metadata=metadata)
    if bodies:  # the masks' fruit in light, the thermal bodies in the dark
        row = {"frame": "images/000000.png", "camera": "rgb" if rgb_level > 0.1 else "thermal", "centre": [0, 0, 1],
               "diameter": 0.07}  # fmt: skip
        (tmp_path / FRUIT_BODIES).write_text(json.dumps({"sightings": [row]}))
    plan = choose_plan(model, tmp_path)
    assert plan.path == path, plan
    if bodies and rgb_level > 0.1:  # a dusk run whose bodies are all thermal keeps its fruit head
        row["camera"] = "thermal"
        (tmp_path / FRUIT_BODIES).write_text(json.dumps({"sightings": [row]}))
        assert choose_plan(model, tmp_path).path == "views"
