"""``agrinerf-bench --profile count`` end to end, shrunk (12 views of 96x72, 300 steps): a capture synthesised at the
profile's fields of view, processed with the product's own fruit masks, trained through Nerfstudio's Trainer, counted
from its fruit channel on the whole capture and on the row, beside the truth-mask oracle, and the seeds-by-lightings
table written from those counts: every figure in it read back against the runs' own count.json."""

from __future__ import annotations

import csv
import json
import math
from dataclasses import replace
from pathlib import Path

import pytest

from agrinerf_ns.lab.cli import BenchConfig, main
from agrinerf_ns.lab.count_row_bench import LABELS
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
    # shrunk to 12 views of 96x72 and 300 steps: the smallest at which the trained run counts fruit of its own
    small = replace(count, views=12, width=96, height=72, steps={**count.steps, "agrinerf-lite": 300}, eval_views=1,
                    rays_per_batch=512)  # fmt: skip
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
        ("agrinerf-lite", "garden", "bright", "100", "reporting"), (LABELS["bodies"], "garden", "bright", "100", "reporting"),
        (ORACLE, "garden", "bright", "100", "reporting")
    ]  # fmt: skip  # the lit masks' fruit bodies are counted beside the run, with no field
    rows = [r for r in rows if r["label"] != LABELS["bodies"]]
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
    assert oracle["precision"] == 1.0 and oracle["f1_countable"] > 0  # true fruit pixels count fruit and nothing else

    summary = {r["label"]: r for r in csv.DictReader((out / "summary.csv").open())}
    assert float(summary["agrinerf-lite"]["f1_countable"]) == pytest.approx(
        reports["agrinerf-lite"]["score"]["f1_countable"], abs=5e-4
    )
    assert summary["agrinerf-lite"]["f1_countable_sd"] == "nan" and summary["agrinerf-lite"]["runs"] == "1"


def _row_count(out: Path, seed: int, key: str, f1: float, count_error: float, scene: str = "garden") -> None:
    """A row count as the bench lays it out: OUT/seed-<S>/count-row/<scene>-bright/<key>/row/count.json beside the
    capture's truth/scene.json."""
    raw = out / f"seed-{seed}" / "scenes" / f"{scene}-bright" / "raw"
    (raw / "truth").mkdir(parents=True, exist_ok=True)
    (raw / "truth" / "scene.json").write_text(json.dumps({"config": {"scene": scene, "lighting": "bright",
                                                                      "seed": seed}}))  # fmt: skip
    folder = out / f"seed-{seed}" / "count-row" / f"{scene}-bright" / key / "row"
    folder.mkdir(parents=True)
    score = {"counted": 10, "visible": 20, "countable": 16, "well_seen": 12, "f1": f1 - 0.1, "precision": 0.9,
             "recall": 0.5, "count_error": -0.5, "f1_countable": f1, "recall_countable": 0.5,
             "count_error_countable": count_error, "f1_well_seen": f1 + 0.1, "recall_well_seen": 0.6,
             "count_error_well_seen": -0.2, "mean_temperature_error": 0.5}  # fmt: skip
    tiers = {
        t: {d: {"f1": f1 + float(d)} for d in ("0.05", "0.1", "0.15")} for t in ("visible", "countable", "well_seen")
    }
    report = {"truth": "/moved/away", "score": score, "tiers": tiers, "max_range": 2.4}
    (folder / "count.json").write_text(json.dumps(report))


def test_the_table_pools_seeds_of_a_role_and_keeps_tuning_seeds_apart(tmp_path: Path) -> None:
    from agrinerf_ns.lab.count_row_bench import write_bench_tables

    out = tmp_path / "bench"
    _row_count(out, 100, "agrinerf-lite", 0.6, -0.2)
    _row_count(out, 101, "agrinerf-lite", 0.8, 0.0)
    _row_count(out, 100, "oracle", 0.9, -0.1)
    _row_count(out, 0, "agrinerf-lite", 0.1, -0.9)
    rows = write_bench_tables(out, "header")
    assert [(r["seed"], r["label"]) for r in rows] == [(0, "agrinerf-lite"), (100, "agrinerf-lite"), (100, ORACLE),
                                                        (101, "agrinerf-lite")]  # fmt: skip
    text = (out / "counts.md").read_text()
    # mean and sample standard deviation over the two reporting seeds; the tier at 0.10 and 0.15 m from count.json
    reporting = "| garden | bright | reporting 100 101 | agrinerf-lite | 2 | 0.70 ± 0.14 | 0.80 ± 0.14 | 0.85 ± 0.14 "
    assert reporting + "| -10% ± 14 | 0.60 ± 0.14 |" in text
    assert "| garden | bright | tuning 0 | agrinerf-lite | 1 | 0.10 | 0.20 | 0.25 | -90% | 0.00 |" in text
    assert text.index("| reporting 100 | " + ORACLE) < text.index("| tuning 0 |")  # the oracle beside its seeds
    assert "Tuning seeds (below 100; the project chooses its settings on 0-2): 0." in text
    assert "garden 2.4 m" in text and "Per lighting, the scenes pooled" not in text  # one scene: nothing to pool
    _row_count(out, 100, "agrinerf-lite", 0.4, -0.4, scene="orchard")
    write_bench_tables(out, "header")
    text = (out / "counts.md").read_text()
    pooled = "| all | bright | reporting 100 101 | agrinerf-lite | 3 | 0.60 ± 0.20 |"  # garden 100, 101 and orchard 100
    assert pooled in text.split("Per lighting, the scenes pooled")[1]
    summary = {(r["scene"], r["role"], r["label"]) for r in csv.DictReader((out / "summary.csv").open())}
    assert ("all", "reporting", "agrinerf-lite") in summary and ("orchard", "reporting", "agrinerf-lite") in summary
    with pytest.raises(FileNotFoundError, match="no row counts"):
        write_bench_tables(tmp_path / "empty", "header")


def test_a_cached_dataset_without_the_profiles_fruit_masks_is_processed_again(tmp_path: Path) -> None:
    from agrinerf_ns.lab.scenes import prepare_scene

    tiny = replace(PROFILES["tiny"], views=6)
    raw, data = prepare_scene("garden-bright", tiny, 0, tmp_path)
    transforms = data / "transforms.json"
    assert "fruit_masks" not in json.loads(transforms.read_text())["agrinerf"]
    stamp = (raw / "calib.yaml").stat().st_mtime_ns
    prepare_scene("garden-bright", replace(tiny, process={"fruit_mask_maker": "auto"}), 0, tmp_path)
    meta = json.loads(transforms.read_text())
    assert meta["agrinerf"]["fruit_masks"]["source"] == "maker:auto"  # the same capture, processed with masks
    assert (
        all("fruit_mask_file_path" in frame for frame in meta["frames"])
        and (raw / "calib.yaml").stat().st_mtime_ns == stamp
    )


def test_a_scene_without_a_row_range_is_refused_before_anything_is_trained(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setitem(PROFILES, "count", replace(PROFILES["count"], row_range={"garden": 2.4}))
    with pytest.raises(ValueError, match="no row range for 'orchard' scenes"):
        main(BenchConfig(out=tmp_path / "bench", profile="count", scenes=("orchard-bright",)))
    assert not (tmp_path / "bench").exists()


def test_a_dark_capture_gets_its_thermal_bodies_row_beside_the_runs(tmp_path: Path) -> None:
    """Where the dataset holds thermal bodies (dark frames, the product's own masks), the bench counts them on the
    row with no run, and the table gives that count as it is in its count.json."""
    from agrinerf_ns.dataset_format import FRUIT_BODIES
    from agrinerf_ns.lab.count_row_bench import LABELS, count_row_bench, write_bench_tables
    from agrinerf_ns.lab.layout import BenchLayout
    from agrinerf_ns.lab.scenes import prepare_scene

    profile = replace(PROFILES["count"], views=8, width=96, height=72)
    layout = BenchLayout(tmp_path / "bench")
    raw, data = prepare_scene("garden-dark", profile, 100, layout.scenes)
    assert (data / FRUIT_BODIES).is_file()  # the dark frames' masks came from the thermal bodies
    count_row_bench(layout, ["garden-dark"], {}, profile)  # no run: the oracle and the bodies only
    report = json.loads((layout.out / "count-row" / "garden-dark" / "bodies" / "row" / "count.json").read_text())
    assert report["path"] == "bodies" and report["max_range"] == 2.4 and report["truth"] == str(raw.resolve())
    rows = {r["label"]: r for r in write_bench_tables(layout.out, "header")}
    assert set(rows) == {LABELS["bodies"], LABELS["oracle"]}
    assert rows[LABELS["bodies"]]["f1_countable"] == pytest.approx(report["score"]["f1_countable"], nan_ok=True)
