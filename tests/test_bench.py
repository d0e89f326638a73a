"""agrinerf-bench: result bookkeeping, clean-truth metrics, and the machinery end to end on a tiny scene."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch
import yaml

from agrinerf_ns import colour, image_metrics
from agrinerf_ns.lab import margins, results
from agrinerf_ns.lab.cli import BenchConfig, main, step_budgets
from agrinerf_ns.views import CPU_RAYS_PER_CHUNK, evenly_spaced, rays_per_chunk


def test_pareto_front_keeps_only_undominated_points() -> None:
    points = [(10.0, 20.0), (5.0, 18.0), (20.0, 19.0), (30.0, 25.0), (7.0, float("nan"))]
    assert results.pareto_front(points) == [1, 0, 3]


def test_quality_at_time_and_time_to_quality() -> None:
    rows = [
        {"scene": "s", "method": "a", "wall_s": "10", "psnr": "15"},
        {"scene": "s", "method": "a", "wall_s": "20", "psnr": "18"},
        {"scene": "s", "method": "b", "wall_s": "12", "psnr": "17"},
    ]
    assert results.psnr_at_time(rows, "a", "s", 15.0, "psnr") == 15.0
    assert results.psnr_at_time(rows, "a", "s", 25.0, "psnr") == 18.0
    assert math.isnan(results.psnr_at_time(rows, "b", "s", 5.0, "psnr"))
    assert results.time_to_quality(rows, "a", "s", 16.0, "psnr") == 20.0
    assert math.isnan(results.time_to_quality(rows, "b", "s", 30.0, "psnr"))


def _checkpoints(method: str, points: list) -> list:
    return [{"scene": "s", "method": method, "step": str(step), "wall_s": str(wall), "psnr": str(q)}
            for step, wall, q in points]  # fmt: skip


def test_margins_at_equal_time_and_steps_flag_a_flat_baseline(tmp_path: Path) -> None:
    rows = (_checkpoints("agrinerf", [(130, 40, 16.0), (260, 80, 18.0), (390, 120, 19.0)])
            + _checkpoints("nerfacto", [(13, 40, 7.75), (26, 80, 7.75), (40, 120, 7.76)])
            + _checkpoints("tensorf", [(130, 30, 12.0), (260, 60, 14.0), (390, 90, 15.0)]))  # fmt: skip
    table = {(r["baseline"], r["basis"]): r for r in margins.margins(rows, "psnr")}
    assert set(table) == {(b, basis) for b in ("nerfacto", "tensorf") for basis in ("wall_s", "steps")}
    # equal wall time: both at the shorter run's end (tensorf 90 s: agrinerf's best by then is 18.0 at 80 s)
    assert table["tensorf", "wall_s"]["at"] == 90 and table["tensorf", "wall_s"]["difference"] == 18.0 - 15.0
    # equal steps: both at 390 steps
    assert table["tensorf", "steps"]["at"] == 390 and table["tensorf", "steps"]["difference"] == 19.0 - 15.0
    # nerfacto ran 40 steps: at equal steps agrinerf has no checkpoint by step 40
    assert math.isnan(table["nerfacto", "steps"]["difference"])
    assert table["nerfacto", "wall_s"]["baseline_flat"] and not table["tensorf", "wall_s"]["baseline_flat"]
    text = "\n".join(margins.summary_lines(list(table.values())))
    assert "did not learn" in text and "no checkpoint of both" in text
    written = results.read_rows(margins.write_margins(list(table.values()), tmp_path / "margins.csv"))
    assert len(written) == 4 and {r["baseline_flat"] for r in written} == {"True", "False"}


def test_step_budgets_override_the_profile_and_refuse_a_bad_pair() -> None:
    assert step_budgets(("nerfacto=390", "tensorf=390")) == {"nerfacto": 390, "tensorf": 390}
    for bad in ("nerfacto", "nerfacto=0", "nerfacto=ten", "nerfactoo=40"):
        with pytest.raises(ValueError, match="expected METHOD=N"):
            step_budgets((bad,))


def test_csv_append_survives_and_resumes(tmp_path: Path) -> None:
    path = tmp_path / "r.csv"
    results.append_rows(path, [{"scene": "s", "method": "a", "step": 1, "psnr": 1.5, "lpips": float("nan")}])
    results.append_rows(path, [{"scene": "s", "method": "b", "step": 2, "psnr": 2.5}])
    rows = results.read_rows(path)
    assert [r["method"] for r in rows] == ["a", "b"] and rows[0]["lpips"] == "nan"
    assert results.done_runs(rows) == {("s", "a"), ("s", "b")}


def test_exposure_alignment_scores_structure_not_exposure() -> None:
    torch.manual_seed(0)
    truth = torch.rand(24, 32, 3) * 0.8 + 0.1
    dark = colour.linear_to_srgb(colour.srgb_to_linear(truth) * 0.05)
    assert image_metrics.psnr(dark, truth) < 15
    assert image_metrics.psnr(image_metrics.exposure_align(dark, truth), truth) > 40
    noisy = (dark + 0.02 * torch.randn_like(dark)).clamp(0, 1)
    assert image_metrics.psnr(image_metrics.exposure_align(noisy, truth), truth) < 30, "noise is still penalised"


def test_evenly_spaced_views_span_the_capture() -> None:
    assert evenly_spaced(8, 3) == [0, 4, 7]  # 3.5 rounds to even
    assert evenly_spaced(60, 3) == [0, 30, 59]  # 29.5 rounds to even
    assert evenly_spaced(5, None) == [0, 1, 2, 3, 4]
    assert evenly_spaced(5, 99) == [0, 1, 2, 3, 4]
    assert evenly_spaced(5, 0) == [0], "at least one view"
    assert evenly_spaced(0, 3) == []


def test_render_chunk_is_small_on_a_cpu_and_the_configs_on_a_gpu(monkeypatch) -> None:
    assert rays_per_chunk(123) == 123
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert rays_per_chunk() == CPU_RAYS_PER_CHUNK == 1024
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    assert rays_per_chunk() is None and rays_per_chunk(8192) == 8192


@pytest.mark.slow
def test_bench_end_to_end_tiny(tmp_path: Path) -> None:
    config = BenchConfig(out=tmp_path / "bench", profile="tiny", methods=("agrinerf-lite", "nerfacto-thermal"))
    rows = main(config)
    methods = {r["method"] for r in rows}
    assert methods == {"agrinerf-lite", "nerfacto-thermal"}
    assert len(rows) == 2 * 2, "two evaluated checkpoints per run"
    for row in rows:
        for key in ("wall_s", "s_per_step", "peak_rss_mb", "thermal_psnr", "thermal_ssim"):
            assert math.isfinite(results.as_float(row, key)), (row["method"], key)
        assert row["eval_views"] == "1", "the tiny profile evaluates all of its one held-out view"
        if row["method"] == "agrinerf-lite":
            for key in ("psnr", "ssim", "psnr_clean", "ssim_clean"):
                assert math.isfinite(results.as_float(row, key)), key
    table = (tmp_path / "bench" / "results.md").read_text()
    assert "AgriNeRF-lite" in table and "Nerfacto (Thermal)" in table and "Command:" in table
    assert (tmp_path / "bench" / "tradeoff.png").stat().st_size > 5000
    assert results.read_rows(tmp_path / "bench" / "margins.csv") == [], "no RGB baseline ran: no margin"
    # resumable: a second call trains nothing new and appends nothing
    again = main(config)
    assert len(again) == len(rows)
    assert len(results.read_rows(tmp_path / "bench" / "results.csv")) == len(rows)


@pytest.mark.slow
def test_bench_trains_a_table_iv_ablation(tmp_path: Path) -> None:
    """A Table IV row without an RGB head: trained with its modalities, scored on thermal only."""
    rows = main(BenchConfig(out=tmp_path / "bench", profile="tiny", methods=("lite-ablation-thermal",)))
    assert [r["label"] for r in rows] == ["AgriNeRF-lite (Thermal)"] * 2
    for row in rows:
        assert math.isfinite(results.as_float(row, "thermal_psnr"))
        assert math.isnan(results.as_float(row, "psnr")) and math.isnan(results.as_float(row, "psnr_clean"))
    (config,) = (tmp_path / "bench" / "runs").glob("*/lite-ablation-thermal/agrinerf-lite/run/config.yml")
    loaded = yaml.load(config.read_text(), Loader=yaml.Loader)
    assert tuple(loaded.pipeline.model.modalities) == ("thermal",)


def test_a_sample_budget_row_trains_the_papers_samples_for_the_presets_wall_time(tmp_path: Path) -> None:
    """`agrinerf-paper-samples`: the preset with the paper's 64 + 64 samples and 1024 event pixels, for fewer steps."""
    from agrinerf_ns.lab.methods import SAMPLE_BUDGETS
    from agrinerf_ns.lab.profiles import PROFILES
    from agrinerf_ns.method_configs.agrinerf_methods import agrinerf

    preset = agrinerf.config.pipeline.model
    assert (preset.num_coarse_samples, preset.num_fine_samples, preset.event_rays_per_batch) == (64, 32, 512)
    main(BenchConfig(out=tmp_path / "bench", profile="tiny", methods=("agrinerf-paper-samples",)))
    (config,) = (tmp_path / "bench" / "runs").glob("*/agrinerf-paper-samples/agrinerf/run/config.yml")
    loaded = yaml.load(config.read_text(), Loader=yaml.Loader)
    model = loaded.pipeline.model
    assert (model.num_coarse_samples, model.num_fine_samples, model.event_rays_per_batch) == (64, 64, 1024)
    budget = SAMPLE_BUDGETS["agrinerf-paper-samples"]
    assert loaded.max_num_iterations == round(PROFILES["tiny"].steps["agrinerf"] * budget.step_scale)
    assert budget.step_scale < 1, "the paper's samples make a slower step: fewer steps for the same wall time"
