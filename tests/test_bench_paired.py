"""Paired per-view differences of two benchmark runs and their interval (agrinerf_ns.lab.results)."""

import math

import pytest

from agrinerf_ns.lab import results


def test_paired_difference_matches_the_student_t_interval_by_hand() -> None:
    mean, half = results.paired_difference([11.0, 12.0, 13.0], [10.0, 10.0, 10.0])
    assert mean == pytest.approx(2.0)
    assert half == pytest.approx(4.302653 * 1.0 / math.sqrt(3), rel=1e-5)  # t(0.975, 2 dof) * sd / sqrt(n)


def test_paired_difference_with_one_view_has_no_interval_and_unequal_views_are_refused() -> None:
    mean, half = results.paired_difference([3.0], [1.0])
    assert mean == 2.0 and math.isnan(half)
    with pytest.raises(ValueError, match="differ in number"):
        results.paired_difference([1.0, 2.0], [1.0])


def _row(scene: str, method: str, psnr: float, views: str = "") -> results.Row:
    return {"scene": scene, "method": method, "step": "500", "psnr_clean": str(psnr), "psnr_clean_per_view": views}


def test_run_spread_pools_replicates_by_hand_and_ignores_other_methods() -> None:
    rows = [
        _row("a", "rgb", 20.0), _row("a", "rep", 21.0), _row("a", "other", 5.0),
        _row("b", "rgb", 18.0), _row("b", "rep", 18.0), _row("b", "rep2", 18.6),
        _row("c", "rgb", 30.0),  # a group of one adds nothing
    ]  # fmt: skip
    sd, dof = results.run_spread(rows, ["rgb", "rep", "rep2"])
    # scene a: squares 0.25 + 0.25, 1 dof; scene b: mean 18.2, squares 0.04 + 0.04 + 0.16, 2 dof
    assert dof == 3
    assert sd == pytest.approx(math.sqrt((0.5 + 0.24) / 3))
    assert math.isnan(results.run_spread([_row("a", "rgb", 20.0)], ["rgb", "rep"])[0])
    # a run with the very same per-view results drew the same random stream: it counts once
    same = [_row("a", "rgb", 20.0, "19.0;21.0"), _row("a", "rep", 20.0, "19.0;21.0"), _row("a", "rep2", 21.0, "20;22")]
    assert results.run_spread(same, ["rgb", "rep", "rep2"]) == (pytest.approx(math.sqrt(0.5)), 1)


def test_interval_with_run_spread_is_wider_and_can_unmark_a_difference() -> None:
    views_base, views_mine = "20.0;20.1;19.9;20.0", "20.3;20.4;20.2;20.3"  # +0.3, tight across views
    rows = [_row("a", "rgb", 20.0, views_base), _row("a", "new", 20.3, views_mine)]
    tight = results.ablation_table(rows, ["rgb", "new"], "rgb", {})
    assert "*" in tight
    wide = results.ablation_table(rows, ["rgb", "new"], "rgb", {}, run_sd=(0.3, 20))
    assert "*" not in wide
    half = results.difference_interval(0.0, 0.3, 20)
    assert half == pytest.approx(2.085963 * math.sqrt(2) * 0.3, rel=1e-5)  # t(0.975, 20 dof)


def test_difference_spread_pools_per_stream_differences_and_leaves_identical_runs_out() -> None:
    same = "19.0;21.0"
    rows = [
        _row("a", "rgb", 20.0, "19;21"), _row("a", "rgb@s1", 21.0, "20;22"), _row("a", "rgb@s2", 19.0, "18;20"),
        _row("a", "cam", 20.5, "20;21"), _row("a", "cam@s1", 21.1, "21;21.2"), _row("a", "cam@s2", 19.6, "19;20.2"),
        # the same model as the baseline in every stream: its difference is exactly 0 and says nothing of the spread
        _row("a", "geo", 20.0, "19;21"), _row("a", "geo@s1", 21.0, "20;22"), _row("a", "geo@s2", 19.0, "18;20"),
        _row("b", "rgb", 18.0, same), _row("b", "cam", 18.4, "18.1;18.7"),  # one stream: no spread
    ]  # fmt: skip
    sd, dof = results.difference_spread(rows, ["cam", "geo"], "rgb", (0, 1, 2))
    # scene a, cam: differences 0.5, 0.1, 0.6 (mean 0.4; squares 0.01 + 0.09 + 0.04), 2 dof
    assert dof == 2
    assert sd == pytest.approx(math.sqrt(0.14 / 2))
    assert math.isnan(results.difference_spread(rows, ["geo"], "rgb", (0, 1, 2))[0])
    assert results.seed_key("cam", 0) == "cam" and results.seed_key("cam", 2) == "cam@s2"


def test_a_run_identical_to_its_baseline_is_marked_so_without_an_interval() -> None:
    rows = [_row("a", "rgb", 20.0, "19.5;20.5"), _row("a", "geo", 20.0, "19.5;20.5"), _row("a", "cam", 20.4, "20;20.8")]
    table = results.ablation_table(rows, ["rgb", "geo", "cam"], "rgb", {}, run_sd=(0.2, 4), runs_factor=1.0)
    geo, cam = table.splitlines()[2].split(" | ")[2:4]
    assert geo == "20.00 (identical)"
    assert cam.startswith("20.40 (+0.40 ± ")
    assert results.difference_interval(0.0, 0.2, 4, runs_factor=1.0) == pytest.approx(2.776445 * 0.2, rel=1e-5)
