"""``agrinerf-bench --profile count`` end to end at the tiny scale: a capture synthesised at the profile's fields of
view, processed with the product's own fruit masks, trained through Nerfstudio's Trainer, counted from its fruit
channel on the whole capture and on the row, beside the truth-mask oracle, and the seeds-by-lightings table written
from those counts: every figure in it read back against the runs' own count.json."""

from __future__ import annotations

import csv
import json
import math
from dataclasses import replace
from pathlib import Path

import pytest

from agrinerf_ns.lab.cli import BenchConfig, main
from agrinerf_ns.lab.count_row_tables import SEED_COLUMNS
from agrinerf_ns.lab.profiles import PROFILES

ORACLE = "oracle (truth masks, true depth)"


def _measure(report: dict, measure: str) -> float:
    """A table measure as the run's count.json gives it (``f1_countable@0.1``: its tiers at 0.1 m)."""
    name, _, distance = measure.partition("@")
    if not distance:
        return float(report["score"][name])
    tier = name.removeprefix("f1").removeprefix("_") or "visible"
    return float(report["tiers"][tier][distance]["f1"])


def _cell(value: float, measure: str) -> str:
    if not math.isfinite(value):
        return "-"
    return f"{100 * value:+.0f}%" if measure.startswith("count_error") else f"{value:.2f}"


@pytest.mark.slow
def test_the_count_profile_writes_its_table_from_the_runs_count_json(tmp_path: Path, monkeypatch) -> None:
    count = PROFILES["count"]
    small = replace(count, views=10, width=64, height=48, steps={**count.steps, "agrinerf-lite": 40}, eval_views=1,
                    rays_per_batch=256)  # fmt: skip
    monkeypatch.setitem(PROFILES, "count", small)  # the profile's own fields of view, masks, counting and ranges
    out = tmp_path / "bench"
    main(BenchConfig(out=out, profile="count", seeds=(100,), scenes=("garden-bright",)))

    seed = out / "seed-100"
    scene = json.loads((seed / "scenes" / "garden-bright" / "raw" / "truth" / "scene.json").read_text())["config"]
    assert (scene["rgb_hfov_deg"], scene["thermal_hfov_deg"], scene["event_substeps"]) == (22.0, 20.0, 1)
    meta = json.loads((seed / "scenes" / "garden-bright" / "data" / "transforms.json").read_text())
    assert meta["agrinerf"]["fruit_masks"]["source"] == "maker:auto"  # the masks the product made itself

    rows = list(csv.DictReader((out / "counts.csv").open()))
    assert sorted((r["label"], r["scene"], r["lighting"], r["seed"], r["role"]) for r in rows) == [
        ("agrinerf-lite", "garden", "bright", "100", "reporting"), (ORACLE, "garden", "bright", "100", "reporting")
    ]  # fmt: skip
    reports = {r["label"]: json.loads((out / r["folder"] / "count.json").read_text()) for r in rows}
    for report in reports.values():
        assert report["max_range"] == small.row_range["garden"] == 2.4 and report["source"] != ""
        assert report["detector"]["source"] == "fruit"
    run = seed / "count-row" / "garden-bright" / "agrinerf-lite"
    whole = json.loads((run / "capture" / "count.json").read_text())
    assert whole["max_range"] is None and (run / "capture" / "renders").is_dir()
    assert reports["agrinerf-lite"]["score"]["visible"] <= whole["score"]["visible"]  # the row holds fewer fruit
    assert not (seed / "count-row" / "garden-bright" / "oracle" / "renders").exists()  # made again when needed

    text = (out / "counts.md").read_text()
    header = next(line for line in text.splitlines() if line.startswith("| scene | lighting | seeds |"))
    assert header.split(" | ")[5:8] == ["countable F1 0.05", "0.10", "0.15"]  # the countable tier first
    assert "Reporting seeds (100 and up, never tuned on): 100." in text and "Tuning seeds" in text
    assert "FruitNeRF++" in text and "0.15 of Nerfstudio's normalised units" in text  # the anchors and their rules
    for label, report in reports.items():
        line = next(
            line for line in text.splitlines() if line.startswith(f"| garden | bright | reporting 100 | {label} |")
        )
        cells = [c.strip() for c in line.strip("|").split("|")][5:]
        expected = [_cell(_measure(report, measure), measure) for _, measure in SEED_COLUMNS]
        assert cells == expected, (label, cells, expected)  # one seed: the mean is the run's own, no spread
    oracle = reports[ORACLE]["score"]
    assert oracle["precision"] == 1.0 or oracle["counted"] == 0  # true fruit pixels count nothing but fruit

    summary = {r["label"]: r for r in csv.DictReader((out / "summary.csv").open())}
    assert float(summary["agrinerf-lite"]["f1_countable"]) == pytest.approx(
        reports["agrinerf-lite"]["score"]["f1_countable"], abs=5e-4
    )
    assert summary["agrinerf-lite"]["f1_countable_sd"] == "nan" and summary["agrinerf-lite"]["runs"] == "1"
