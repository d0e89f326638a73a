"""`ns-train evdeblurnerf-lite` (the paper's EvDeblurNeRF baseline as published: event-to-event loss, learnt event
response, learnt rigid blur kernel, EDI prior, no thermal head) on a processed synthetic capture through the real CLI,
then `ns-eval` and `ns-render` on the run."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import pytest
import torch
import yaml

from agrinerf_ns.ns_commands import headless_train_args
from agrinerf_ns.process import ProcessConfig, process_capture
from agrinerf_ns.synth import SynthConfig, generate_capture

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def dusk_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("evdeblurnerf")
    config = SynthConfig.tiny(seed=2, lighting="dusk")  # dim light: a long exposure, recorded blur intervals
    raw = generate_capture(config, root / "raw")
    return process_capture(raw, root / "orchard", ProcessConfig(poses="given", show_progress=False))


def test_evdeblurnerf_trains_with_the_event_loss_and_blur_model_and_ns_eval_render_work(
    dusk_dataset: Path, tmp_path: Path
) -> None:
    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    args = ["ns-train", "evdeblurnerf-lite", "--data", str(dusk_dataset)]
    args += headless_train_args(12, 256, tmp_path / "outputs", "evdeblurnerf")
    args += ["--pipeline.model.blur-start-step", "0", "--pipeline.model.event-crf-start-step", "0",
             "--pipeline.model.event-rays-per-batch", "64"]  # fmt: skip
    subprocess.run(args, check=True, env=env, timeout=900)
    run = tmp_path / "outputs" / "evdeblurnerf" / "evdeblurnerf-lite" / "run"
    config = yaml.load((run / "config.yml").read_text(), Loader=yaml.Loader)
    model = config.pipeline.model
    assert model.modalities == ("rgb", "events") and (model.blur_kernel, model.blur_samples) == ("learnt", 10)

    checkpoint = torch.load(sorted((run / "nerfstudio_models").glob("*.ckpt"))[-1], weights_only=False)
    names = list(checkpoint["pipeline"])
    assert not any("thermal" in n for n in names)  # no thermal head: the scene's thermal frames are not modelled
    assert any(n.startswith("_model.blur_kernel.") for n in names) and any(
        n.startswith("_model.events.crf.") for n in names
    )

    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events = EventAccumulator(str(run))
    events.Reload()
    logged = set(events.Tags()["scalars"])
    assert {"Train Loss Dict/event_loss", "Train Loss Dict/rgb_loss", "Train Loss Dict/edi_prior_loss"} <= logged

    out_json = tmp_path / "eval.json"
    subprocess.run(["ns-eval", "--load-config", str(run / "config.yml"), "--output-path", str(out_json)],
                   check=True, env=env, timeout=600)  # fmt: skip
    results = json.loads(out_json.read_text())["results"]
    assert results["psnr"] > 0 and "thermal_psnr" not in results
    renders = tmp_path / "renders"
    subprocess.run(["ns-render", "dataset", "--load-config", str(run / "config.yml"), "--output-path", str(renders),
                    "--split", "test", "--rendered-output-names", "rgb"], check=True, env=env, timeout=600)  # fmt: skip
    assert any(p.suffix in (".png", ".jpg") for p in renders.rglob("*"))
