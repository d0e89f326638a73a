"""Display outputs: `rgb_display` at the training frames' exposure or a chosen one, first for a dark capture, absent
from training (the loss and its gradients are those of a model without it); `ns-render --display-ev` taken off the
command line; the temperature legend."""

from __future__ import annotations

import math
import os

import pytest
import torch
from helpers.small_model import SMALL_MODEL
from nerfstudio.cameras.cameras import Cameras
from nerfstudio.data.scene_box import SceneBox

from agrinerf_ns import compat
from agrinerf_ns.colour import srgb_to_linear
from agrinerf_ns.model.display import DISPLAY_LEVEL, DisplayOutputs, expose, frames_ev, legend_markdown
from agrinerf_ns.model.model import AgriNeRFModelConfig
from agrinerf_ns.render_option import EV_ENV, take_render_option

compat.activate()


def test_frames_ev_brings_dark_frames_to_a_lit_level_and_leaves_lit_ones() -> None:
    assert frames_ev(0.5) == 0.0 and frames_ev(float("nan")) == 0.0
    dark = 3 / 255
    ev = frames_ev(dark)
    assert 5 < ev < 9
    shown = expose(torch.full((1, 3), dark), ev)
    assert shown.mean().item() == pytest.approx(DISPLAY_LEVEL, abs=0.02)
    assert frames_ev(dark, rgb_gain=4.0) == pytest.approx(ev - 2.0, abs=0.35), "the dataset's own gain counts"
    rgb = torch.rand(8, 3) * 0.1
    assert torch.allclose(srgb_to_linear(expose(rgb, 2.0)), (srgb_to_linear(rgb) * 4).clamp(max=1), atol=1e-5)


def test_dark_frames_put_rgb_display_first(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(EV_ENV, raising=False)
    outputs = {
        "rgb": torch.full((2, 2, 3), 0.02),
        "depth": torch.ones(2, 2, 1),
        "temperature": torch.full((2, 2, 1), 20.0),
    }

    dark = DisplayOutputs({"rgb_level": 0.02, "rgb_gain": 1.0}, (10.0, 30.0), lambda c: ((c - 10) / 20).clamp(0, 1))
    shown = dark.add(outputs)
    assert list(shown)[:2] == ["rgb_display", "rgb"] and shown["rgb"] is outputs["rgb"]
    assert shown["rgb_display"].mean() > 5 * outputs["rgb"].mean()
    assert torch.allclose(shown["temperature_display"], torch.full((2, 2, 1), 0.5))
    lit = DisplayOutputs({"rgb_level": 0.4}).add(outputs)
    assert list(lit)[0] == "rgb" and torch.equal(lit["rgb_display"], expose(outputs["rgb"], 0.0))
    assert "temperature_display" not in lit, "no range: no temperature head"

    monkeypatch.setenv(EV_ENV, "3")
    assert torch.allclose(dark.add(outputs)["rgb_display"], expose(outputs["rgb"], 3.0))
    dark.slider.value = 1.5  # the viewer's control, where no exposure is set in the environment
    monkeypatch.delenv(EV_ENV)
    assert torch.allclose(dark.add(outputs)["rgb_display"], expose(outputs["rgb"], 1.5))
    assert "10.0 °C" in legend_markdown(10.0, 30.0) and "data:image/png;base64," in legend_markdown(10.0, 30.0)


def test_render_option_is_taken_off_ns_render_only(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(EV_ENV, raising=False)
    argv = ["/venv/bin/ns-render", "dataset", "--display-ev", "2.5", "--load-config", "c.yml"]
    assert take_render_option(argv) == 2.5 and argv == ["/venv/bin/ns-render", "dataset", "--load-config", "c.yml"]
    assert os.environ[EV_ENV] == "2.5"
    argv = ["ns-render", "--display-ev=-1"]
    assert take_render_option(argv) == -1.0 and argv == ["ns-render"]
    other = ["ns-train", "--display-ev", "2"]
    assert take_render_option(other) is None and len(other) == 3
    with pytest.raises(SystemExit) as exit_info:
        take_render_option(["ns-render", "--display-ev", "bright"])
    assert exit_info.value.code == 2


def test_display_outputs_leave_training_alone() -> None:
    """A whole-camera render carries `rgb_display` (first for a dark capture); a training step renders, loses and
    steps exactly as before: the display output has no parameters and no loss reads it."""

    def model(metadata):
        torch.manual_seed(0)
        cfg = AgriNeRFModelConfig(modalities=("rgb",), **SMALL_MODEL)
        box = SceneBox(aabb=torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]))
        return cfg.setup(scene_box=box, num_train_data=4, metadata={"modalities": ("rgb",), **metadata})

    dark, lit = model({"rgb_level": 0.01}), model({})
    assert dict(dark.named_parameters()).keys() == dict(lit.named_parameters()).keys()
    assert all(torch.equal(a, b) for a, b in zip(dark.state_dict().values(), lit.state_dict().values(), strict=True))
    camera = Cameras(camera_to_worlds=torch.tensor([[[1.0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 3]]]), fx=8.0, fy=8.0,
                     cx=4.0, cy=3.0, width=8, height=6)  # fmt: skip
    dark.eval()
    with torch.no_grad():
        outputs = dark.get_outputs_for_camera(camera)
    assert list(outputs)[0] == "rgb_display" and outputs["rgb_display"].shape == outputs["rgb"].shape
    assert math.isclose(float(dark.display.slider.value), round(frames_ev(0.01) * 4) / 4)

    dark.train()
    bundle = camera.generate_rays(camera_indices=0).flatten()
    batch = {"image": torch.full((bundle.shape[0], 3), 0.01)}
    for one in (dark, lit):
        one.train()
    torch.manual_seed(1)
    out_dark = dark(bundle)
    torch.manual_seed(1)
    out_lit = lit(bundle)
    assert "rgb_display" not in out_dark and out_dark.keys() == out_lit.keys()
    loss_dark = sum(dark.get_loss_dict(out_dark, batch).values())
    loss_lit = sum(lit.get_loss_dict(out_lit, batch).values())
    assert torch.equal(loss_dark, loss_lit)
