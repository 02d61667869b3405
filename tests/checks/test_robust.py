"""checks.robust: σ from the median absolute deviation."""

import numpy as np
import pytest

from checks.robust import MAD_TO_SIGMA, mad_sigma


def test_mad_sigma_of_a_small_sample_with_an_outlier():
    # median 3, absolute deviations 2 1 0 1 97, their median 1: the outlier does not move it
    assert mad_sigma([1.0, 2.0, 3.0, 4.0, 100.0]) == pytest.approx(MAD_TO_SIGMA, rel=1e-15)


def test_mad_sigma_estimates_the_sigma_of_gaussian_values():
    rng = np.random.default_rng(7)
    values = rng.normal(5.0, 0.3, 200_000)
    # the MAD estimator's relative standard error is ~1.17/sqrt(n) ~ 0.0026 here; 4 of them
    assert mad_sigma(values) == pytest.approx(0.3, rel=0.011)


def test_mad_sigma_along_an_axis_matches_each_column():
    rng = np.random.default_rng(3)
    values = rng.normal(size=(101, 3)) * [1.0, 2.0, 0.5]
    columns = [mad_sigma(values[:, k]) for k in range(3)]
    assert np.array_equal(mad_sigma(values, axis=0), columns)
