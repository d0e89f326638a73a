"""The count profile's counting of one trained run (`agrinerf_ns.lab.count_bench.count_run_rows`): a synthetic capture
processed by `agrinerf-process`, trained through Nerfstudio's Trainer, counted by the field path on each source it has
and by the view path, its fruit placed by depth and by rays, every row scored against the capture's truth."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from helpers.model_scene import tiny_trainer_config
from helpers.tiny_run import train_saved_run

from agrinerf_ns.count.field_count import FieldCountConfig
from agrinerf_ns.count.volume import VolumeConfig
from agrinerf_ns.lab.cli import BenchConfig, main
from agrinerf_ns.lab.count_bench import ORACLE_METHOD, VIEW_PLACEMENTS, count_run_rows
from agrinerf_ns.lab.count_tables import read_rows
from agrinerf_ns.process import ProcessConfig, process_capture
from agrinerf_ns.synth import SynthConfig, generate_capture


def test_a_run_is_counted_by_every_path_and_placement_and_scored(tmp_path: Path) -> None:
    raw = generate_capture(SynthConfig.tiny(lighting="bright", scene="garden"), tmp_path / "raw")
    data = process_capture(raw, tmp_path / "dataset", ProcessConfig(poses="given", show_progress=False))
    run = train_saved_run(tiny_trainer_config(data, tmp_path / "outputs", max_num_iterations=30, rays=512), seed=0)

    small = FieldCountConfig(volume=VolumeConfig(max_voxels=100_000, max_views=3))
    rows = count_run_rows("garden-bright", "agrinerf-lite", 0, run, raw, tmp_path / "count", small)
    paths = {(r["path"], r["source"]) for r in rows}
    assert {("field", "temperature"), ("views", "rgb")} <= paths
    for source in ("temperature", "thermal", "rgb"):  # the view path's sources this run renders, both placements
        assert {(path, source) for path in VIEW_PLACEMENTS} <= paths
    visible = {r["visible"] for r in rows}
    assert len(visible) == 1 and visible.pop() > 0  # every row scored against the same visible truth
    for row in rows:
        assert row["lighting"] == "bright" and row["seed"] == 0 and row["step"] == 29
        assert 0.0 <= row["f1"] <= 1.0 and np.isfinite(row["count_error"]) and row["seconds"] > 0
        report = json.loads((tmp_path / "count" / "garden-bright" / "agrinerf-lite" /
                             f"{row['path']}-{row['source']}" / "count.json").read_text())  # fmt: skip
        assert report["score"]["f1"] == row["f1"]
        if row["path"].startswith("views"):
            assert report["cluster"]["triangulate"] == (row["path"] == "views-rays")


@pytest.mark.slow
def test_the_count_profile_counts_stock_runs_by_their_views_and_skips_thermal_camera_runs(tmp_path: Path) -> None:
    """Nerfacto has no AgriNeRF heads for the field path: its RGB views are counted; Nerfacto (Thermal) renders the
    thermal camera's views, which the count does not read: it is left out, not scored against the RGB truth. The
    Table IV ablation trained on thermal frames alone sees through the RGB camera without an RGB head: it is counted
    from its thermal outputs, by both paths, and from no RGB."""
    out = tmp_path / "bench"
    methods = {"nerfacto": "nerfacto", "nerfacto-thermal": "nerfacto", "lite-ablation-thermal": "agrinerf-lite"}
    main(BenchConfig(out=out, profile="tiny", methods=tuple(methods), count=True))  # the tiny profile counts nothing
    assert "agrinerf-bench" in (out / "count.md").read_text()  # the command that counted, from main
    rows = read_rows(out / "count.csv")
    counted = {(r["method"], r["path"]) for r in rows}
    assert {("nerfacto", path) for path in VIEW_PLACEMENTS} <= counted
    assert {m for m, p in counted if p == "field" and m != ORACLE_METHOD} == {"lite-ablation-thermal"}
    assert "nerfacto-thermal" not in {m for m, _ in counted}
    assert {r["source"] for r in rows if r["method"] == "nerfacto"} == {"rgb"}
    thermal_only = {(r["path"], r["source"]) for r in rows if r["method"] == "lite-ablation-thermal"}
    assert {("field", "thermal"), ("views", "thermal"), ("views-rays", "thermal")} <= thermal_only
    assert "rgb" not in {source for _, source in thermal_only}
    assert "nerfacto" in (out / "count.md").read_text()
