"""The benchmark's run layout: what agrinerf-bench writes through it, agrinerf-detect finds through it."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import pytest

from agrinerf_ns import ns_commands
from agrinerf_ns.lab.layout import BenchLayout, run_config, split_scene
from agrinerf_ns.lab.methods import METHODS
from agrinerf_ns.lab.paper_plan import plan_from_bench
from agrinerf_ns.lab.profiles import PROFILES
from agrinerf_ns.lab.runs import run_method
from agrinerf_ns.machine import machine_note
from agrinerf_ns.ns_commands import checkpoints


def _fake_ns_train(name: str, args: Sequence[str], log_path=None, timeout=None) -> ns_commands.CommandResult:
    """Writes what ``ns-train`` writes where its options say: the run's config.yml and two checkpoints."""
    option = dict(zip(args[1::2], args[2::2], strict=False))  # args[0] is the method
    run = Path(option["--output-dir"]) / option["--experiment-name"] / args[0] / option["--timestamp"]
    (run / "nerfstudio_models").mkdir(parents=True)
    (run / "config.yml").write_text("")
    for step in (1, 3):
        (run / "nerfstudio_models" / f"step-{step:09d}.ckpt").write_bytes(b"")
    return ns_commands.CommandResult("", 1.0, 1.0)


def test_a_run_folder_the_bench_writes_is_found_by_detect(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr(ns_commands, "run_ns", _fake_ns_train)
    monkeypatch.setattr("agrinerf_ns.checkpoint_eval.evaluate_checkpoint", lambda *args, **kwargs: {})
    layout = BenchLayout(tmp_path / "bench")
    raw, data = layout.scene("garden-dark")
    data.mkdir(parents=True)
    for key in ("nerfacto", "agrinerf-lite"):
        rows = run_method("garden-dark", key, METHODS[key], raw, data, PROFILES["tiny"], layout.runs, "cpu")
        assert [r["step"] for r in rows] == [2, 4]
        config = run_config(layout.runs, "garden-dark", key, METHODS[key].ns_method)
        assert [step for step, _ in checkpoints(config)] == [1, 3]
    (scene,) = plan_from_bench(layout.out)
    assert (scene.name, scene.lighting, scene.raw, scene.dataset) == ("garden", "dark", raw, data)
    assert [(m.label, m.config) for m in scene.methods] == [
        ("Nerfacto (RGB)", run_config(layout.runs, "garden-dark", "nerfacto", "nerfacto")),
        ("Ours-lite (RGB)", run_config(layout.runs, "garden-dark", "agrinerf-lite", "agrinerf-lite")),
        ("Ours-lite (Cross-Spectral)", run_config(layout.runs, "garden-dark", "agrinerf-lite", "agrinerf-lite")),
    ]
    assert layout.finished_runs("garden-dark", {"tensorf": "tensorf"}) == {}


def test_layout_names() -> None:
    assert split_scene("orchard-dark") == ("orchard", "dark") and split_scene("orchard") == ("orchard", "-")
    assert machine_note(["GPU X"]).startswith("Machine: ") and "GPU X; Python" in machine_note(["GPU X"])
    with pytest.raises(FileNotFoundError, match="not an agrinerf-bench output folder"):
        BenchLayout(Path("/nonexistent")).run_scenes()
