"""Runs written before the model's terms became parts (tests/data/old-runs, commit d1c9fcd) load with today's code:
their config.yml in `ns-eval` and `agrinerf-count`, their checkpoints' learnt event thresholds and response under
the new names, and the event loss's old switches read as today's one switch, `event_supervision`."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest
import torch
import yaml

from agrinerf_ns.model.model_config import AgriNeRFSettings

pytestmark = pytest.mark.slow

OLD = Path(__file__).resolve().parent / "data" / "old-runs"
OLD_ROOT = "\n- tmp\n- oldrun"
"""Where the old runs' config.yml put the dataset and the outputs (/tmp/oldrun/orchard, /tmp/oldrun/outputs)."""


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The capture the old runs trained on, made again (the synthesis is seeded)."""
    from agrinerf_ns.process import ProcessConfig, process_capture
    from agrinerf_ns.synth import SynthConfig, generate_capture

    root = tmp_path_factory.mktemp("old-runs")
    raw = generate_capture(SynthConfig.tiny(seed=2, lighting="dusk"), root / "raw")
    return process_capture(raw, root / "orchard", ProcessConfig(poses="given", show_progress=False))


def _moved_run(method: str, data: Path, root: Path, edit: tuple = ()) -> Path:
    """The old run copied under `root` as its config.yml names it, the dataset and output paths in the file's text
    rewritten (what a user who moved the folders does); `edit`: further (old, new) text replacements."""
    run = root / "outputs" / "old" / method / "run"
    shutil.copytree(OLD / method, run)
    text = (run / "config.yml").read_text()
    for old, new in ((f"{OLD_ROOT}\n- orchard\n", data), (f"{OLD_ROOT}\n- outputs\n", root / "outputs")):
        assert text.count(old) == 1, old
        text = text.replace(old, "".join(f"\n- {part}" for part in new.parts[1:]) + "\n")
    for old, new in edit:
        assert old in text, old
        text = text.replace(old, new)
    (run / "config.yml").write_text(text)
    return run / "config.yml"


def _load(config_yml: Path):
    return yaml.load(config_yml.read_text(), Loader=yaml.Loader)


@pytest.mark.parametrize("method", ["agrinerf-lite", "evdeblurnerf-lite"])
def test_an_old_run_loads_with_its_learnt_event_state_under_the_new_names(
    method: str, dataset: Path, tmp_path: Path
) -> None:
    from nerfstudio.utils.eval_utils import eval_setup

    config_yml = _moved_run(method, dataset, tmp_path)
    model_config = _load(config_yml).pipeline.model
    assert isinstance(model_config, AgriNeRFSettings)
    assert model_config.event_supervision == {"agrinerf-lite": "stream", "evdeblurnerf-lite": "pairs"}[method]
    _, pipeline, checkpoint_path, _ = eval_setup(config_yml, test_mode="test")
    old = torch.load(checkpoint_path, map_location="cpu", weights_only=False)["pipeline"]
    events = pipeline.model.events
    assert events is not None and events.log_threshold is not None
    assert torch.equal(events.log_threshold.detach().cpu(), old["_model.log_event_threshold"])
    if method == "evdeblurnerf-lite":
        assert events.crf is not None and pipeline.model.blur_kernel is not None
        for name, value in events.crf.state_dict().items():
            assert torch.equal(value.cpu(), old[f"_model.event_crf.{name}"]), name
        assert torch.isnan(events.loss_means).all()  # not saved by the old code: the running means start afresh


def test_the_old_event_switches_read_as_event_supervision(dataset: Path, tmp_path: Path) -> None:
    """0 event rays (the old default, every preset without events) and a zero event weight both meant "off"."""
    rays = _moved_run(
        "agrinerf-lite", dataset, tmp_path / "rays", (("event_rays_per_batch: 32", "event_rays_per_batch: 0"),)
    )
    assert _load(rays).pipeline.model.event_supervision == "off"
    weight = _moved_run(
        "agrinerf-lite", dataset, tmp_path / "weight", (("    event_loss: 0.1\n", "    event_loss: 0.0\n"),)
    )
    assert _load(weight).pipeline.model.event_supervision == "off"


def _refuse(constant: str) -> None:
    raise ValueError(f"not strict JSON: {constant}")


def test_ns_eval_and_agrinerf_count_run_on_an_old_run(dataset: Path, tmp_path: Path) -> None:
    config_yml = _moved_run("agrinerf-lite", dataset, tmp_path)
    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    out_json = tmp_path / "eval.json"
    subprocess.run(["ns-eval", "--load-config", str(config_yml), "--output-path", str(out_json)],
                   check=True, env=env, timeout=600)  # fmt: skip
    results = json.loads(out_json.read_text(), parse_constant=_refuse)["results"]  # strict JSON: no NaN
    # the stored step-2 checkpoint evaluated on its one held-out view: PSNR 15.93 dB, thermal-camera PSNR 12.80 dB
    # (2026-12-07, AMD EPYC 2 cores, OMP_NUM_THREADS=1); a checkpoint loaded wrongly renders other pixels
    assert abs(results["psnr"] - 15.93) < 1.0 and abs(results["thermal_camera_psnr"] - 12.80) < 1.0, results
    count = tmp_path / "count"
    subprocess.run(["agrinerf-count", "--config", str(config_yml), "--out", str(count)],
                   check=True, env=env, timeout=600)  # fmt: skip
    assert (count / "count.json").exists() and (count / "fruits.csv").exists()


def test_a_runs_dataset_is_read_from_its_config_alone(dataset: Path, tmp_path: Path) -> None:
    """`agrinerf-count --path bodies --config RUN` finds the run's dataset from config.yml without loading the run;
    it is the folder the loaded run names."""
    from agrinerf_ns.run_loading import load_run, run_dataset

    config_yml = _moved_run("agrinerf-lite", dataset, tmp_path)
    assert run_dataset(config_yml) == dataset == load_run(config_yml).dataset_dir
