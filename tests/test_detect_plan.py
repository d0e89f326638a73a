"""Plans: the JSON plan file and the plan read from an agrinerf-bench output folder."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from agrinerf_ns.detect.evaluate import load_plan, plan_from_bench


def test_load_plan_resolves_relative_paths_and_reports_missing_keys(tmp_path: Path) -> None:
    plan = tmp_path / "plan.json"
    plan.write_text(
        json.dumps(
            {
                "scenes": [
                    {
                        "name": "garden",
                        "lighting": "dark",
                        "raw": "raw",
                        "dataset": "/abs/data",
                        "methods": [
                            {"label": "Nerfacto (Thermal)", "config": "runs/c.yml", "detector": "thermal"},
                            {"label": "Ours (Cross-Spectral)", "renders": "r", "output": "thermal"},
                        ],
                    }
                ]
            }
        )
    )
    (scene,) = load_plan(plan)
    assert scene.raw == tmp_path / "raw" and scene.dataset == Path("/abs/data")
    nerfacto_thermal, ours = scene.methods
    assert nerfacto_thermal.config == tmp_path / "runs" / "c.yml" and nerfacto_thermal.output == "rgb"
    assert nerfacto_thermal.detector_modality() == "thermal" and ours.detector_modality() == "thermal"
    plan.write_text(json.dumps({"scenes": [{"name": "x", "raw": "raw", "methods": []}]}))
    with pytest.raises(ValueError, match="scene 0 lacks the key 'lighting'"):
        load_plan(plan)
    plan.write_text("{not json")
    with pytest.raises(ValueError, match="cannot read the plan"):
        load_plan(plan)


def test_plan_from_bench_layout(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="not an agrinerf-bench output folder"):
        plan_from_bench(tmp_path)
    for scene in ("garden-dark", "orchard-shadowed"):
        (tmp_path / "scenes" / scene / "raw").mkdir(parents=True)
        (tmp_path / "scenes" / scene / "data").mkdir(parents=True)
        for key, method in (
            ("nerfacto", "nerfacto"),
            ("nerfacto-thermal", "nerfacto"),
            ("agrinerf-lite", "agrinerf-lite"),
        ):
            run = tmp_path / "runs" / scene / key / method / "run"
            run.mkdir(parents=True)
            (run / "config.yml").write_text("")
            (run / "nerfstudio_models").mkdir()
            (run / "nerfstudio_models" / "step-000000009.ckpt").write_bytes(b"")
    # a run still training (no checkpoint yet) is left out
    (
        tmp_path
        / "runs"
        / "orchard-shadowed"
        / "agrinerf-lite"
        / "agrinerf-lite"
        / "run"
        / "nerfstudio_models"
        / "step-000000009.ckpt"
    ).unlink()
    garden, orchard = plan_from_bench(tmp_path)
    assert (garden.name, garden.lighting, garden.raw) == ("garden", "dark", tmp_path / "scenes" / "garden-dark" / "raw")
    assert [(m.label, m.output, m.detector_modality()) for m in garden.methods] == [
        ("Nerfacto (RGB)", "rgb", "rgb"),
        ("Nerfacto (Thermal)", "rgb", "thermal"),
        ("Ours-lite (RGB)", "rgb", "rgb"),
        ("Ours-lite (Cross-Spectral)", "thermal", "thermal"),
    ]
    assert [m.label for m in orchard.methods] == ["Nerfacto (RGB)", "Nerfacto (Thermal)"]
