"""Count's sources are resolved in one place (agrinerf_ns.count.sources): ``--path views`` and ``--path auto`` count a
lit run from the same output, and a render folder keeps the light its run was rendered in."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from helpers.small_model import SMALL_MODEL
from nerfstudio.data.scene_box import SceneBox

from agrinerf_ns.count.auto_path import choose_plan
from agrinerf_ns.count.cli import CountArgs, main
from agrinerf_ns.count.errors import CountInputError
from agrinerf_ns.count.render import RenderedView, RenderSet, WorldFrame, load_renders, save_renders
from agrinerf_ns.count.sources import RunOutputs, field_outputs, resolve_source, rgb_frames_dark
from agrinerf_ns.model.model import AgriNeRFModelConfig


def _view() -> RenderedView:
    """A view of a tri-modal run: RGB, the cross-spectral channel and the temperature."""
    h, w = 4, 5
    return RenderedView(name="000000", split="train", file_path="images/000000.png", rgb=np.zeros((h, w, 3), np.float32),
                        depth=np.ones((h, w), np.float32), accumulation=np.ones((h, w), np.float32),
                        origins=np.zeros((h, w, 3), np.float32), directions=np.ones((h, w, 3), np.float32),
                        focal=10.0, thermal=np.zeros((h, w), np.float32), temperature=np.zeros((h, w), np.float32))  # fmt: skip


@pytest.mark.parametrize("rgb_level, source", [(0.4, "rgb"), (0.039, "temperature")])
def test_views_and_auto_resolve_the_same_source_for_a_run(rgb_level: float, source: str) -> None:
    """A tri-modal model lit (RGB frames at 40%) or dark (below its low_light_level 0.04), rendering RGB, thermal and
    temperature: the view path's ``auto`` and the plan agree (lit: the RGB views; dark: the plan leaves the views)."""
    box = SceneBox(aabb=torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]))
    metadata = {"modalities": ("rgb", "thermal", "events"), "rgb_level": rgb_level}
    model = AgriNeRFModelConfig(**SMALL_MODEL).setup(scene_box=box, num_train_data=4, metadata=metadata)
    renders = RenderSet([_view()], WorldFrame(np.eye(4)[:3], 1.0), None, None, "agrinerf-lite", rgb_frames_dark(model))
    views = resolve_source("auto", "views", renders.outputs())[0]  # --path views: what run_count detects on
    assert views == source
    plan = choose_plan(model)  # --path auto
    if source == "rgb":
        assert plan.path == "views"  # and run_count then resolves the same renders: the same source
    else:
        assert plan.path == "field" and resolve_source("auto", "field", field_outputs(model))[0] == "thermal_camera"


def test_the_orders_and_asking_by_name() -> None:
    thermal_only = RunOutputs(thermal=True, thermal_camera=True)
    assert resolve_source("auto", "field", thermal_only)[0] == "thermal_camera"
    unknown = RunOutputs(rgb=True, thermal=True, dark=None)  # a render folder that does not say its run's light
    assert resolve_source("auto", "views", unknown)[0] == "thermal"
    assert resolve_source("auto", "views", RunOutputs(rgb=True, thermal=True, dark=False))[0] == "rgb"
    assert resolve_source("auto", "views", RunOutputs(rgb=True, temperature=True), "yolo")[0] == "rgb"
    assert resolve_source("auto", "field", RunOutputs(rgb=True, dark=False))[1].startswith("the run has no thermal")
    assert resolve_source("fruit", "field", RunOutputs(fruit=True)) == ("fruit", "asked for")
    # a fruit head: its rendered regions on the view path, lit or dark; the field path takes it only by name
    for dark in (False, True):
        assert (
            resolve_source("auto", "views", RunOutputs(fruit=True, rgb=True, temperature=True, dark=dark))[0] == "fruit"
        )
    assert resolve_source("auto", "field", RunOutputs(fruit=True, temperature=True))[0] == "temperature"
    with pytest.raises(CountInputError, match=r"no 'temperature' output .* \(it has: thermal, rgb\)"):
        resolve_source("temperature", "views", RunOutputs(thermal=True, rgb=True))


def test_a_render_folder_keeps_its_runs_light(tmp_path: Path) -> None:
    for dark in (False, True, None):
        save_renders(RenderSet([_view()], WorldFrame(np.eye(4)[:3], 1.0), None, None, "m", dark), tmp_path / str(dark))
        assert load_renders(tmp_path / str(dark)).dark is dark
    meta = json.loads((tmp_path / "False" / "renders.json").read_text())
    del meta["rgb_dark"]  # a folder written before the light was recorded
    (tmp_path / "False" / "renders.json").write_text(json.dumps(meta))
    assert load_renders(tmp_path / "False").dark is None


def test_views_and_auto_count_a_lit_run_from_the_same_output(tiny_run_config: Path, tmp_path: Path) -> None:
    """The tiny tri-modal run (lit): ``--path views`` and ``--path auto`` write the same detection source."""
    sources = {}
    for path in ("views", "auto"):
        main(CountArgs(out=tmp_path / path, config=tiny_run_config, path=path, splits=("eval",), save_renders=False))
        report = json.loads((tmp_path / path / "count.json").read_text())
        assert report["path"] == "views"
        sources[path] = report["detector"]["source"]
    assert sources == {"views": "rgb", "auto": "rgb"}
