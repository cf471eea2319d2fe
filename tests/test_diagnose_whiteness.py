"""imurig.diagnose.whiteness.residual_whiteness: is what a diagnosis leaves white, and at the edges (no spread
left, too few values) a defined answer without a numpy warning."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from imurig.diagnose.whiteness import residual_whiteness


def _quiet(r):
    with warnings.catch_warnings():
        warnings.simplefilter("error")   # a RuntimeWarning (0/0 in a correlation) fails the test
        return residual_whiteness(r)


def test_white_noise_is_white_and_an_ar1_is_not():
    rng = np.random.default_rng(7)
    e = rng.normal(size=400)
    lag1, white = _quiet(e)
    a, b = e[:-1] - e[:-1].mean(), e[1:] - e[1:].mean()
    assert lag1 == pytest.approx(float(a @ b / np.sqrt((a @ a) * (b @ b))), rel=1e-12)   # Pearson's r
    assert white and abs(lag1) < 2.5 / np.sqrt(e.size)
    x = np.zeros(400)
    for i in range(1, x.size):   # AR(1), rho = 0.8: far outside the white band
        x[i] = 0.8 * x[i - 1] + e[i]
    lag1, white = _quiet(x)
    assert not white and lag1 > 0.6


@pytest.mark.parametrize("r", [np.zeros(12), np.r_[np.zeros(11), 1e-9], np.r_[3.0, np.zeros(11)]])
def test_no_spread_left_is_white_and_undefined(r):
    """A perfect fit (or a residual that varies only at one end): nothing unexplained; rho undefined."""
    lag1, white = _quiet(r)
    assert np.isnan(lag1) and white is True


def test_too_few_values_are_not_called_white():
    lag1, white = _quiet(np.array([0.1, -0.2, 0.3]))
    assert np.isnan(lag1) and white is False
