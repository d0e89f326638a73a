"""Paired per-view differences of two benchmark runs and their interval (agrinerf_ns.bench.results)."""

import math

import pytest

from agrinerf_ns.bench import results


def test_paired_difference_matches_the_student_t_interval_by_hand() -> None:
    mean, half = results.paired_difference([11.0, 12.0, 13.0], [10.0, 10.0, 10.0])
    assert mean == pytest.approx(2.0)
    assert half == pytest.approx(4.302653 * 1.0 / math.sqrt(3), rel=1e-5)  # t(0.975, 2 dof) * sd / sqrt(n)


def test_paired_difference_with_one_view_has_no_interval_and_unequal_views_are_refused() -> None:
    mean, half = results.paired_difference([3.0], [1.0])
    assert mean == 2.0 and math.isnan(half)
    with pytest.raises(ValueError, match="differ in number"):
        results.paired_difference([1.0, 2.0], [1.0])
