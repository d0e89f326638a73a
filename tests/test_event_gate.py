"""The event term's data gate (issue 50, item 3): a real model trained on a tiny synthetic dusk capture keeps its
event term where the events agree with the frames, and switches it down where they contradict them (the same
capture with every event's polarity flipped: the events of the path driven backwards). The capture is the tiny
scene in bright light with 24 views: with the tiny 8 views the field's renders between the frames explain even
agreeing events worse than 'no change', and the gate then (rightly) keeps the term off. The gate starts closed: the
agreeing events open it once the frames-shaped field explains them."""

from __future__ import annotations

import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest
import torch
from helpers.small_model import SMALL_MODEL
from PIL import Image

from agrinerf_ns.dataparsers.agrinerf_dataparser import AgriNeRFDataParserConfig
from agrinerf_ns.model import event_gate
from agrinerf_ns.model.model import AgriNeRFModelConfig
from agrinerf_ns.process import ProcessConfig, process_capture
from agrinerf_ns.synth import SynthConfig, generate_capture


@pytest.fixture(scope="module")
def captures(tmp_path_factory: pytest.TempPathFactory):
    root = tmp_path_factory.mktemp("event-gate")
    raw = generate_capture(SynthConfig.tiny(seed=4, lighting="bright", views=24), root / "raw")
    data = process_capture(raw, root / "data", ProcessConfig(poses="given", show_progress=False))
    flipped = root / "flipped"
    shutil.copytree(data, flipped)
    with h5py.File(flipped / "events" / "stream.h5", "r+") as f:
        p = np.asarray(f["events"]["p"])
        f["events"]["p"][...] = (1 - p.astype(np.int64)).astype(p.dtype)
    return data, flipped


FIELD = dict(init_resolution=32, final_resolution=48, num_coarse_samples=32, num_fine_samples=32, density_shift=0.0,
             event_window_min_fraction=1.0)  # fmt: skip
"""A field that reconstructs the 24 views well enough in 300 steps for the frames alone to explain their events
better than 'no change' (on whole frame windows: in short sub-windows the tiny capture's coarse events do not)."""


def _train(data: Path, steps: int = 300, **kw):
    outputs = AgriNeRFDataParserConfig(data=data).setup().get_dataparser_outputs("train")
    torch.manual_seed(0)
    config = AgriNeRFModelConfig(
        **{**SMALL_MODEL, "modalities": ("rgb", "events"), "cross_spectral_output": False,
           "event_supervision": "stream", "event_rays_per_batch": 128, "event_gate": True, "event_gate_every": 25,
           "event_gate_samples": 512, "loss_coefficients": {"rgb_loss": 1.0, "event_loss": 0.1}, **kw},
    )  # fmt: skip
    model = config.setup(scene_box=outputs.scene_box, num_train_data=len(outputs.image_filenames),
                         metadata=outputs.metadata)  # fmt: skip
    model.train()
    images = torch.stack([
        torch.from_numpy(np.asarray(Image.open(p).convert("RGB"), dtype=np.float32) / 255.0)
        for p in outputs.image_filenames
    ])  # fmt: skip
    params = [p for group in model.get_param_groups().values() for p in group]
    optimiser = torch.optim.Adam(params, lr=0.02)
    generator = torch.Generator().manual_seed(1)
    n, h, w = images.shape[:3]
    factors = []
    for step in range(steps):
        model.step = step
        index = torch.randint(0, n, (256,), generator=generator)
        ys, xs = torch.randint(0, h, (256,), generator=generator), torch.randint(0, w, (256,), generator=generator)
        rays = outputs.cameras.generate_rays(camera_indices=index[:, None], coords=torch.stack([ys, xs], -1) + 0.5)
        out = model(rays.flatten() if rays.shape != (256,) else rays)
        batch = {"image": images[index, ys, xs]}
        metrics = model.get_metrics_dict(out, batch)
        loss = sum(model.get_loss_dict(out, batch, metrics).values())
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        factors.append(float(model.events.gate.factor))
    return model, factors


def test_the_gate_rule_halves_to_zero_and_recovers() -> None:
    f = event_gate.next_factor
    assert f(1.0, 0.5, 0.4, 0.4) == 0.5  # not below the reference: halved
    assert f(1.0, 0.3, 0.4, 0.2) == 0.5  # below the reference, but risen past the best so far
    assert f(0.5, 0.3, 0.4, 0.3) == 1.0
    assert f(event_gate.FLOOR, 0.5, 0.4, 0.4) == 0.0  # below the floor: off
    assert f(0.0, 0.3, 0.4, 0.3) == event_gate.RESTART  # and back when the residual falls


def test_held_out_pixels_are_never_drawn_for_training(captures) -> None:
    outputs = AgriNeRFDataParserConfig(data=captures[0]).setup().get_dataparser_outputs("train")
    config = AgriNeRFModelConfig(modalities=("rgb", "events"), cross_spectral_output=False,
                                 event_supervision="stream", event_gate=True, event_gate_samples=64, **SMALL_MODEL)  # fmt: skip
    model = config.setup(scene_box=outputs.scene_box, num_train_data=len(outputs.image_filenames),
                         metadata=outputs.metadata)  # fmt: skip
    gate = model.events.gate
    drawn = set(gate.training_pixels(20000).tolist())
    held = set(range(model.events.stream.width * model.events.stream.height)) - set(gate.train_pixels.tolist())
    assert held and not drawn & held
    assert set(model.state_dict()) >= {"events.gate.factor", "events.gate.reference", "events.gate.residual"}


def test_the_gate_keeps_agreeing_events_and_switches_contradicting_ones_down(captures) -> None:
    data, flipped = captures
    agree, agree_factors = _train(data, **FIELD)
    contradict, contradict_factors = _train(flipped, **FIELD)
    # both start closed while the young field explains nothing (a warm-up the data decides: checks at steps 25 and
    # 50 found the residual above the bar); the agreeing events' residual then falls below 'no change' and the term
    # opens at RESTART, the contradicting one's rises and it stays off. Measured: opened at step 100 at 0.0625, 1.0
    # from step 200 (2026-12-07, AMD EPYC 2 cores, OMP_NUM_THREADS=1)
    opened = next((step for step, factor in enumerate(agree_factors) if factor > 0.0), None)
    assert opened is not None and 50 <= opened <= 200, agree_factors[::25]
    assert agree_factors[opened] == event_gate.RESTART and agree_factors[-1] >= 0.5, agree_factors[::25]
    assert max(contradict_factors) == 0.0, contradict_factors[::25]
    assert float(contradict.events.gate.residual) > float(agree.events.gate.residual)
    metrics = agree.get_metrics_dict(*_one_batch(agree, data))
    assert metrics["event_gate"] == agree_factors[-1]


def _one_batch(model, data: Path):
    outputs = AgriNeRFDataParserConfig(data=data).setup().get_dataparser_outputs("train")
    rays = outputs.cameras.generate_rays(camera_indices=0).flatten()[:64]
    return model(rays), {"image": torch.rand(64, 3)}
