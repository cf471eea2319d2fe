"""Null calibration of the diagnosis' tests where the data are coarse or dirty (issue 16), on small
numpy-made data (not imurig's simulator):

- the Monte Carlo test's critical value (:func:`imurig.diagnose.engine.mc_threshold`) has level
  k / (n + 1) <= alpha, where an interpolated quantile of 300 simulations gave 0.013 at alpha 0.01;
- the converter's noise before rounding (:func:`imurig.diagnose.position_noise.dither_sd`) from the
  codes of a few dozen positions at a few levels (the moment estimate is off by up to 25 % there);
- the flat-top test does not name a clip where codes repeat because the noise is 0.3 of a step,
  and still names a real flat top;
- the set-point delay test's despiking removes a cable fault's spikes and nothing on clean data.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from imurig.diagnose.engine import mc_threshold
from imurig.diagnose.position_noise import dither_sd
from imurig.diagnose.samples import despike
from imurig.sensors.effects import RawChannelView
from imurig.sensors.effects.saturation import Saturation

Q12 = 20.0 / 2**12


def test_monte_carlo_threshold_has_its_level():
    """Observed and simulated statistics exchangeable: the rejection rate is k / (n + 1), k =
    floor(alpha (n + 1)), within 4 binomial standard errors; the old interpolated quantile's
    rate (4 / 301) lies outside that band."""
    rng = np.random.default_rng(7)
    n, reps, alpha = 300, 20000, 0.01
    draws = rng.standard_normal((reps, n + 1))
    thr = np.array([mc_threshold(row[1:], alpha) for row in draws])
    rate = float(np.mean(draws[:, 0] > thr))
    level = 3 / 301
    se = np.sqrt(level * (1 - level) / reps)
    assert abs(rate - level) < 4 * se, rate
    assert abs(4 / 301 - level) > 4 * se
    assert mc_threshold(np.arange(50.0), 0.01) == float("inf")       # n too small: nothing rejected


def _positions(rng, sigma_q, levels, per_level=6, n=800):
    """Codes (V) of positions at a few true levels (V), noise sigma_q steps before the rounding."""
    x, sl, start = [], [], 0
    for v in levels:
        for _ in range(per_level):
            x.append(np.rint((v + sigma_q * Q12 * rng.standard_normal(n)) / Q12) * Q12)
            sl.append(slice(start, start + n))
            start += n
    return np.concatenate(x), sl


@pytest.mark.parametrize("sigma_q", [0.25, 0.6])
def test_dither_sd_by_maximum_likelihood(sigma_q):
    """Seven levels (a 12-bit axis of a tilt table), three positions each: the pooled maximum
    likelihood is within 4 standard errors of the truth, the SE from the spread of 8 replicas."""
    rng = np.random.default_rng(int(sigma_q * 100))
    est = []
    for _ in range(8):
        levels = rng.uniform(-1.0, 1.0, 7)
        x, sl = _positions(rng, sigma_q, levels, per_level=3, n=600)
        est.append(dither_sd(x, sl, Q12) / Q12)
    est = np.array(est)
    se = est.std(ddof=1) / np.sqrt(est.size)
    assert abs(est.mean() - sigma_q) < 4 * se + 1e-3, (est.mean(), se)
    assert est.std(ddof=1) < 0.05 * sigma_q              # a few per cent per record, not 25 %


@pytest.mark.parametrize("sigma_q", [0.3, 0.6, 1.0])
def test_no_flat_top_where_codes_repeat(sigma_q):
    """Stationary positions at the codes' centres (the longest runs): with noise 0.3 q a code
    repeats with probability 0.9, so runs of tens of equal samples are ordinary (the old rule
    named clips at 22); none is named at any noise. Where the noise resolves the step (1 q), a
    real flat top (the top position held at one code for 400 samples) still is."""
    rng = np.random.default_rng(int(10 * sigma_q))
    levels = np.round(np.linspace(-1.0, 1.0, 7) / Q12) * Q12
    x, _ = _positions(rng, sigma_q, levels, per_level=6)
    t = np.arange(x.size) / 100.0
    out = Saturation().test(RawChannelView(channel="acc_x", samples=x, time_s=t, quantum_V=Q12, alpha=0.01))
    assert "finding" not in out, out
    if sigma_q >= 1.0:
        y = x.copy()
        y[-400:] = y.max()
        out = Saturation().test(RawChannelView(channel="acc_x", samples=y, time_s=t, quantum_V=Q12, alpha=0.01))
        assert "finding" in out and out["finding"]["samples"] >= 400


def test_despike_removes_cable_spikes_only():
    """A slow signal with ramps (boxes of a delay residual) plus white noise: clean, nothing is
    touched; with 1-3 sample spikes of 2000 sigma, exactly the spiked samples are replaced."""
    rng = np.random.default_rng(11)
    n = 20000
    t = np.arange(n) / 50.0
    box = 0.05 * ((t % 40) > 25)                               # a delay's residual through the moves
    r = np.column_stack([box + 1e-4 * rng.standard_normal(n) for _ in range(3)])
    f = 9.8 + r
    q = np.full(3, 1e-6)
    g, counts = despike(f, r, q)
    assert counts == [0, 0, 0] and np.array_equal(g, f)
    spiked = np.zeros(n, bool)
    for i in rng.choice(np.arange(10, n - 10, 10), 40, replace=False):
        w = int(rng.integers(1, 4))
        r[i:i + w, 1] += 0.2 * rng.choice([-1, 1])
        spiked[i:i + w] = True
    f = 9.8 + r
    g, counts = despike(f, r, q)
    assert counts[1] == spiked.sum() and counts[0] == counts[2] == 0
    err = np.abs(g[:, 1] - 9.8 - box)
    # the spikes gone: within the noise (8 sigma) away from the box's edges, where a replaced sample
    # takes its window's median, which may be the level on the edge's other side
    edge = np.convolve(np.abs(np.diff(box, prepend=box[0])) > 0, np.ones(7), mode="same") > 0
    assert np.max(err[~edge]) < 8e-4 and np.max(err) < 0.05 + 8e-4
    assert stats.kurtosis(g[~edge, 1] - 9.8 - box[~edge]) < 0.5
