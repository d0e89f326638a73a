"""The robust spread: a normal sample's sigma, unmoved by a minority of outliers."""

import numpy as np
import pytest

from agrinerf_ns.robust import robust_spread


def test_the_spread_of_a_normal_sample_is_its_sigma_and_outliers_do_not_inflate_it() -> None:
    values = np.random.default_rng(0).normal(5.0, 2.0, 20000)
    assert robust_spread(values) == pytest.approx(2.0, rel=0.03)
    spiked = values.copy()
    spiked[:2000] = 1e6  # a tenth of the values far away (fruit among leaves)
    assert robust_spread(spiked) == pytest.approx(2.0, rel=0.2)
    assert np.std(spiked) > 1e4


def test_the_spread_about_a_given_centre() -> None:
    values = np.array([1.0, 2.0, 3.0])
    assert robust_spread(values, 0.0) == pytest.approx(1.4826 * 2.0)
    assert robust_spread(np.full(5, 3.0)) == 0.0
