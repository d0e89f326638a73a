"""benchmarks/before_after.py: the equal-wall-time reading of two quality-against-time curves."""

from __future__ import annotations

import math

import pytest
from helpers.bench_script import load_bench_script

before_after = load_bench_script("before_after")


def _rows(points, key="psnr_clean"):
    return [{"wall_s": str(t), key: str(v)} for t, v in points]


def test_time_to_reach_interpolates_between_checkpoints() -> None:
    curve = [(10.0, 18.0), (20.0, 20.0), (30.0, 21.0)]
    assert before_after.time_to_reach(curve, 19.0) == pytest.approx(15.0)
    assert before_after.time_to_reach(curve, 17.0) == 10.0  # already there at the first checkpoint
    assert math.isnan(before_after.time_to_reach(curve, 22.0))


def test_value_at_is_linear_inside_the_span_and_nan_outside() -> None:
    curve = [(10.0, 18.0), (20.0, 20.0)]
    assert before_after.value_at(curve, 15.0) == pytest.approx(19.0)
    assert math.isnan(before_after.value_at(curve, 25.0)) and math.isnan(before_after.value_at(curve, 5.0))


def test_comparison_reads_the_share_of_before_time_and_the_differences() -> None:
    before = _rows([(20.0, 18.0), (60.0, 20.0)])
    after = _rows([(10.0, 19.0), (20.0, 21.0), (90.0, 22.0)])  # reaches 20 dB at 15 s: a quarter of 60 s
    cells = [c.strip() for c in before_after.comparison(before, after, "psnr_clean").split("|")]
    assert cells[0] == "20.00 at 60 s" and cells[1] == "15 s (0.25x)"
    # after's checkpoints inside before's span: only 20 s, where before is at 18 dB
    assert cells[2] == "+3.00 / +3.00" and cells[3] == "1"
    slower = _rows([(30.0, 17.0), (90.0, 19.5)])
    assert before_after.comparison(before, slower, "psnr_clean").split("|")[1].strip() == "not reached"
