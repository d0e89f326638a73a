"""benchmarks/count_fruit_table.py: count folders pooled per lighting and label, tuning seeds kept apart."""

import csv
import json
from pathlib import Path

import pytest
from helpers.bench_script import load_bench_script


def _count(root: Path, name: str, scene: str, seed: int, f1: float, truth_relative: bool = False) -> Path:
    raw = root / f"raw-{name}"
    (raw / "truth").mkdir(parents=True)
    (raw / "truth" / "scene.json").write_text(
        json.dumps({"config": {"scene": scene, "lighting": "bright", "seed": seed}})
    )
    folder = root / name
    folder.mkdir()
    score = {"counted": 10, "visible": 20, "well_seen": 12, "f1": f1, "precision": 0.5, "recall": 0.5,
             "count_error": -0.5, "f1_well_seen": f1 + 0.1, "recall_well_seen": 0.6, "count_error_well_seen": -0.2,
             "mean_temperature_error": 0.5, "countable": 16, "f1_countable": f1 + 0.05, "recall_countable": 0.55,
             "count_error_countable": -0.3}  # fmt: skip
    tiers = {"countable": {"0.1": {"f1": f1 + 0.2}, "0.15": {"f1": f1 + 0.3}}}
    truth = f"raw-{name}" if truth_relative else str(raw)
    (folder / "count.json").write_text(json.dumps({"truth": truth, "score": score, "method": "m", "tiers": tiers}))
    return folder


def test_reporting_runs_are_pooled_and_tuning_runs_kept_apart(tmp_path: Path) -> None:
    table = load_bench_script("count_fruit_table")
    folders = [
        _count(tmp_path, "a", "garden", 100, 0.2),
        _count(tmp_path, "b", "orchard", 101, 0.4, truth_relative=True),
        _count(tmp_path, "c", "orchard", 0, 0.9),
    ]
    out = tmp_path / "out"
    table.main(table.TableArgs([f"run={f}" for f in folders], out))
    pooled = {(r["role"], r["label"]): r for r in csv.DictReader((out / "summary.csv").open())}
    assert set(pooled) == {("reporting", "run"), ("tuning", "run")}
    reporting = pooled[("reporting", "run")]
    assert int(reporting["runs"]) == 2 and float(reporting["f1"]) == pytest.approx(0.3)
    assert 0.2 <= float(reporting["f1_low"]) <= 0.3 <= float(reporting["f1_high"]) <= 0.4
    assert float(pooled[("tuning", "run")]["f1"]) == pytest.approx(0.9)  # never pooled with the reporting seeds
    rows = list(csv.DictReader((out / "counts.csv").open()))
    assert [(r["scene"], r["seed"], r["role"]) for r in rows] == [
        ("garden", "100", "reporting"), ("orchard", "101", "reporting"), ("orchard", "0", "tuning")
    ]  # fmt: skip
    # the countable tier first, at 0.05, 0.10 and 0.15 m (from count.json's tiers), then the count error
    assert "| bright | reporting | run | garden:100, orchard:101 | 0.35 [" in (out / "counts.md").read_text()
    assert float(reporting["f1_countable@0.1"]) == pytest.approx(0.5)
    assert float(reporting["f1_countable@0.15"]) == pytest.approx(0.6)
    assert float(reporting["count_error_countable"]) == pytest.approx(-0.3)
    assert reporting["f1@0.1"] == "nan"  # a tier the count did not write stays unknown, never zero
    assert "FruitNeRF" in (out / "counts.md").read_text()  # the anchors stand beside every table
    with pytest.raises(SystemExit, match="LABEL=FOLDER"):
        table.main(table.TableArgs([str(folders[0])], out))
