"""The event gate in the model's plan (issue 61, item 2): `resolve_plan` decides the gate with the event supervision,
so a preset that gates its event loss is never trained ungated because of what a dataset lacks. The `agrinerf` preset
on a tiny bright capture with its event stream, the same capture with its event frames only (no events/stream.h5),
and without events, against an explicit table; then a real training start of each, and the held-out pixels left out
of the pairs supervision's draws."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path
from typing import Dict, Tuple

import pytest
import torch
from helpers.small_model import SMALL_MODEL

from agrinerf_ns.dataparsers.agrinerf_dataparser import AgriNeRFDataParserConfig
from agrinerf_ns.model.plan import resolve_plan
from agrinerf_ns.process import ProcessConfig, process_capture
from agrinerf_ns.synth import SynthConfig, generate_capture

EVENTS, EVENTLESS = ("rgb", "thermal", "events"), ("rgb", "thermal")


@pytest.fixture(scope="module")
def datasets(tmp_path_factory: pytest.TempPathFactory) -> Dict[str, Tuple[Path, Tuple[str, ...]]]:
    """name -> (dataset folder, the modalities its dataparser is asked for): the capture with its event stream, a copy
    with its event frames only, and the capture without events."""
    root = tmp_path_factory.mktemp("plan-gate")
    raw = generate_capture(SynthConfig.tiny(seed=2, lighting="bright", views=8), root / "raw")
    stream = process_capture(raw, root / "stream", ProcessConfig(poses="given", show_progress=False))
    frames = root / "frames"
    shutil.copytree(stream, frames)
    transforms = json.loads((frames / "transforms.json").read_text())
    del transforms["agrinerf"]["events"]["stream"]
    (frames / "transforms.json").write_text(json.dumps(transforms))
    (frames / "events" / "stream.h5").unlink()
    return {"stream": (stream, EVENTS), "frames": (frames, EVENTS), "none": (stream, EVENTLESS)}


def _outputs(datasets, name: str):
    data, modalities = datasets[name]
    return AgriNeRFDataParserConfig(data=data, modalities=modalities).setup().get_dataparser_outputs("train")  # type: ignore[arg-type]


def _preset(name: str = "agrinerf", **fields):
    from agrinerf_ns.method_configs import agrinerf_methods

    config = getattr(agrinerf_methods, name.replace("-", "_")).config.pipeline.model
    return dataclasses.replace(config, **fields)


GATE_NOTE = ("event_gate", "--pipeline.model.event-gate False")
# (dataset, preset, config fields) -> (event supervision, gate, event loss trained, words every note about it has)
EXPECTED = {
    ("stream", "agrinerf", ()): ("stream", True, True, ()),
    ("frames", "agrinerf", ()): ("off", False, False, GATE_NOTE + ("events/stream.h5",)),
    ("none", "agrinerf", ()): ("off", False, False, ("so it is off",)),
    # the gate switched off by the user: the frames supervise the event loss, ungated as asked
    ("frames", "agrinerf", (("event_gate", False),)): ("frames", False, True, ("'stream' needs",)),
    # every supervision the gate supports gates it; the frames' windows cannot hold its pixels out: off, said
    ("stream", "agrinerf", (("event_supervision", "pairs"),)): ("pairs", True, True, ()),
    ("stream", "evdeblurnerf-lite", (("event_gate", True),)): ("pairs", True, True, ()),
    ("stream", "agrinerf", (("event_supervision", "frames"),)): ("off", False, False, GATE_NOTE + ("'frames'",)),
}


@pytest.mark.parametrize("case", list(EXPECTED), ids=lambda c: f"{c[0]}-{c[1]}-{'-'.join(k for k, _ in c[2])}")
def test_the_plan_decides_the_gate_with_the_supervision(datasets, case) -> None:
    name, preset, fields = case
    supervision, gate, trained, words = EXPECTED[case]
    plan = resolve_plan(_preset(preset, **dict(fields)), _outputs(datasets, name).metadata)
    assert (plan.event_supervision, plan.event_gate, "event_loss" in plan.terms) == (supervision, gate, trained)
    event_notes = [note for note in plan.notes if note.startswith("Events")]
    assert bool(event_notes) == bool(words), event_notes
    for word in words:
        assert any(word in note for note in event_notes), (word, event_notes)
    if plan.use_event_loss and not plan.event_gate:  # ungated only where the config says so
        assert not _preset(preset, **dict(fields)).event_gate


@pytest.mark.parametrize("name", ["stream", "frames", "none"])
def test_a_training_start_builds_the_planned_gate_and_trains_the_planned_terms(datasets, name: str) -> None:
    """The `agrinerf` preset's model (grids and samples shrunk) built from the dataparser's outputs: its gate is the
    plan's, the stream's draws leave the held-out pixels out, and one training step computes the planned terms."""
    outputs = _outputs(datasets, name)
    config = _preset(**SMALL_MODEL, event_rays_per_batch=64, event_gate_samples=64, blur_start_step=0)
    torch.manual_seed(0)
    model = config.setup(scene_box=outputs.scene_box, num_train_data=len(outputs.image_filenames),
                         metadata=outputs.metadata)  # fmt: skip
    model.train()
    gate = None if model.events is None else model.events.gate
    assert (gate is not None) == model.plan.event_gate == (name == "stream")
    index = torch.arange(32) % len(outputs.image_filenames)
    rays = outputs.cameras.generate_rays(camera_indices=index[:, None], coords=torch.full((32, 2), 20.5)).flatten()
    out = model(rays)
    batch = {"image": torch.rand(32, 3), "thermal": torch.rand(32, 1), "thermal_mask": torch.ones(32, 1)}
    losses = model.get_loss_dict(out, batch, model.get_metrics_dict(out, batch))
    assert ("event_loss" in losses) == ("event_loss" in model.plan.terms) == (name == "stream")
    if gate is not None:
        held = ~gate.train_mask
        assert held.any() and not held[gate.training_pixels(4096)].any()


def test_the_pairs_supervision_never_draws_the_held_out_pixels(datasets) -> None:
    outputs = _outputs(datasets, "stream")
    config = _preset(**SMALL_MODEL, event_supervision="pairs", event_gate_samples=64)
    model = config.setup(scene_box=outputs.scene_box, num_train_data=len(outputs.image_filenames),
                         metadata=outputs.metadata)  # fmt: skip
    events = model.events
    assert events is not None and events.gate is not None and events.pairs is not None
    from agrinerf_ns.model.event_pairs import EventPairs

    every = EventPairs.from_h5(events.rig.event_stream.path, events.pairs.width, events.pairs.height)
    held = ~events.gate.train_mask
    assert held[every.pixel].any(), "the capture has pairs at held-out pixels: the test can tell"
    assert not held[events.pairs.pixel].any() and len(events.pairs) == int((~held[every.pixel]).sum())
    pixel, _, _, _ = events.pairs.sample(4096)
    assert not held[pixel].any()
