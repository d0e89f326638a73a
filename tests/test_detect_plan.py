"""Plans: the JSON plan file and the plan read from an agrinerf-bench output folder."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from agrinerf_ns.detect.training import trained_scene_detectors
from agrinerf_ns.lab.methods import ABLATIONS
from agrinerf_ns.lab.paper_plan import load_plan, plan_from_bench
from agrinerf_ns.lab.paper_tables import TABLE_IV_ORDER


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


def _finished_run(root: Path, scene: str, key: str, method: str) -> None:
    run = root / "runs" / scene / key / method / "run"
    (run / "nerfstudio_models").mkdir(parents=True)
    (run / "config.yml").write_text("")
    (run / "nerfstudio_models" / "step-000000009.ckpt").write_bytes(b"")


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
            _finished_run(tmp_path, scene, key, method)
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


def test_plan_from_bench_table_iv_takes_the_ablations(tmp_path: Path) -> None:
    for scene in ("garden-dusk", "garden-dark"):
        (tmp_path / "scenes" / scene / "raw").mkdir(parents=True)
        _finished_run(tmp_path, scene, "agrinerf-lite", "agrinerf-lite")
        _finished_run(tmp_path, scene, "nerfacto", "nerfacto")
    for key in ABLATIONS:
        _finished_run(tmp_path, "garden-dusk", key, "agrinerf-lite")
    (scene,) = plan_from_bench(tmp_path, "IV")  # the dark garden has no ablation runs
    assert (scene.name, scene.lighting) == ("garden", "dusk")
    rows = {m.label: (m.output, m.detector_modality()) for m in scene.methods}
    assert sorted(rows) == sorted(TABLE_IV_ORDER)
    assert rows["Ours (RGB)"] == rows["Ours (RGB+Events)"] == ("rgb", "rgb")
    for label in ("Ours (RGB+Thermal)", "Ours (Thermal)", "Ours (Thermal+Events)", "Ours (All)"):
        assert rows[label] == ("thermal", "thermal"), label
    all_row = next(m for m in scene.methods if m.label == "Ours (All)")
    assert all_row.config is not None and "/agrinerf-lite/agrinerf-lite/" in str(all_row.config)
    # Table III of the same folder leaves the ablations out
    labels = {m.label for s in plan_from_bench(tmp_path, "III") for m in s.methods}
    assert labels == {"Nerfacto (RGB)", "Ours-lite (RGB)", "Ours-lite (Cross-Spectral)"}


def test_detectors_from_an_earlier_evaluation_are_checked(tmp_path: Path) -> None:
    work = tmp_path / "work" / "garden_dusk"
    with pytest.raises(FileNotFoundError, match="no trained thermal detector"):
        trained_scene_detectors(work, {"thermal"}, ["000004"], 30)
    for modality, images in (("rgb", ["truth/rgb_clean/000001.png"]), ("thermal", ["data/thermal/000002.png"])):
        run = work / f"detector_{modality}"
        (run / "weights").mkdir(parents=True)
        (run / "weights" / "best.pt").write_bytes(b"weights")
        (run / "agrinerf_detect.json").write_text(json.dumps({"images": images, "min_box_pixels": 30}))
    weights = trained_scene_detectors(work, {"rgb", "thermal"}, ["000004"], 30)
    assert weights == {m: work / f"detector_{m}" / "weights" / "best.pt" for m in ("rgb", "thermal")}
    with pytest.raises(ValueError, match=r"trained on held-out views \['000002'\]"):
        trained_scene_detectors(work, {"thermal"}, ["000002", "000004"], 30)
    with pytest.raises(ValueError, match="min_box_pixels 30"):
        trained_scene_detectors(work, {"rgb"}, ["000004"], 0)
