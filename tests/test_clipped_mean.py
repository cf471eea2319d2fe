"""The clipped mean (per-position statistic of a tilt record on an ADC's grid): robust to spikes
like the median, but not held to the grid. Truth: a known input on a known grid."""
from __future__ import annotations

import math

import numpy as np

from imurig.calibration.preprocess import clipped_mean


def test_clipped_mean_recovers_an_off_grid_level_and_ignores_spikes():
    rng = np.random.default_rng(3)
    q, sigma, n = 1.0, 0.4, 4000                      # step, Gaussian input noise (0.4 q: the median is on the grid)
    mu = rng.uniform(0.1, 0.4, 3)                     # true levels, off the grid
    x = q * np.rint((mu + sigma * rng.standard_normal((n, 3))) / q)
    x[rng.integers(0, n, 8), 1] += 500 * q            # cable spikes on one channel
    est = clipped_mean(x)
    # bound: 4 standard errors of the mean of the codes, plus the rounding's bias for this dither
    # (first harmonic of the dithered quantiser's mean error: q / pi * exp(-2 pi^2 sigma^2 / q^2))
    se = math.sqrt(sigma**2 + q**2 / 12) / math.sqrt(n)
    bias = q / math.pi * math.exp(-2 * math.pi**2 * sigma**2 / q**2)
    assert np.all(np.abs(est - mu) < 4 * se + bias)
    med = np.median(x, axis=0)
    assert np.all(np.abs(med - mu) > 4 * se + bias)   # the median stays on the grid: the test can fail


def test_clipped_mean_of_unquantised_noise_is_its_mean():
    # 500 Gaussian samples lie within ~3.5 sigma, far inside the 6-robust-sigma window: nothing is clipped
    x = np.random.default_rng(4).standard_normal((500, 2))
    assert np.all(np.abs(x - np.median(x, axis=0)) < 5.0)
    np.testing.assert_allclose(clipped_mean(x), x.mean(axis=0), rtol=0, atol=1e-12)
