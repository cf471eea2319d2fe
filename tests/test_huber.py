"""The Huber M-estimate of location (the tilt calibration's per-position statistic) against closed
forms: its Gaussian efficiency, its bias under a fraction of cable spikes, and a level off an
ADC's grid. Truth: known inputs; bounds from the estimates' standard errors."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import integrate, optimize
from scipy import stats as sst

from imurig.calibration.preprocess import (
    HUBER_K,
    MAD_SIGMA,
    huber_efficiency,
    huber_location,
    segment_statistic,
    segment_statistic_covariance,
    segment_statistic_variance,
    statistic_efficiency,
)
from imurig.kernel.recording import Recording


def test_huber_efficiency_closed_form():
    """eff(k) = (2 Phi(k) - 1)^2 / E[psi_k^2]: 0.95 at Huber's k = 1.345, -> 1 as k -> inf (the mean),
    -> 2/pi as k -> 0 (the median)."""
    assert huber_efficiency(HUBER_K) == pytest.approx(0.950, abs=5e-4)
    assert huber_efficiency(8.0) == pytest.approx(1.0, abs=1e-12)
    assert huber_efficiency(1e-4) == pytest.approx(2 / math.pi, rel=1e-3)
    assert statistic_efficiency("median") == 2 / math.pi and statistic_efficiency("mean") == 1.0


@pytest.mark.parametrize("statistic", ["huber", "median"])
def test_variance_on_gaussian_windows_is_the_efficiency_closed_form(statistic):
    """R windows of N Gaussian samples: R var(estimate) N eff / sigma^2 ~ chi2(R) (mean known 0), so
    the efficiency is the closed form within the chi2 band at 1e-3 (relative +-3.3 % at R = 20000:
    it separates Huber's 0.950 from the mean's 1 and the median's 0.637)."""
    rng = np.random.default_rng(11)
    R, N, sigma = 20000, 101, 2.0
    x = 5.0 + sigma * rng.standard_normal((R, N))
    est = huber_location(x, axis=1) if statistic == "huber" else np.median(x, axis=1)
    v = np.sum((est - 5.0) ** 2) * N * statistic_efficiency(statistic) / sigma**2
    # the median's variance at finite odd N: pi sigma^2 / (2 (N + 2)) to O(1/N^2) (order statistics)
    v *= (N + 2) / N if statistic == "median" else 1.0
    assert sst.chi2.ppf(5e-4, R) <= v <= sst.chi2.isf(5e-4, R), v / R


def _contaminated_bias(eps: float, k: float = HUBER_K) -> float:
    """The asymptotic Huber estimate (MAD scale) of (1 - eps) N(0, 1) + eps (point mass far to the right)."""
    m0 = sst.norm.ppf(0.5 / (1 - eps))                                     # the mixture's median
    d = optimize.brentq(lambda d: (1 - eps) * (sst.norm.cdf(m0 + d) - sst.norm.cdf(m0 - d)) - 0.5, 1e-6, 10)
    s = MAD_SIGMA * d

    def score(b):
        psi = integrate.quad(lambda z: np.clip((z - b) / s, -k, k) * sst.norm.pdf(z), -12, 12, points=[b])[0]
        return (1 - eps) * psi + eps * k
    return optimize.brentq(score, -1, 2)


def test_spikes_move_the_estimate_by_the_closed_form_bias_only():
    """5 % of each window replaced by cable spikes of 10^3 sigma: the Huber estimates' mean equals the
    asymptotic contaminated-model bias (closed form above, ~0.09 sigma) within 4 standard errors plus
    O(1/N); the mean moves by 50 sigma, the median by its own bias Phi^-1(0.5 / 0.95)."""
    rng = np.random.default_rng(5)
    R, N, eps = 200, 1000, 0.05
    x = rng.standard_normal((R, N))
    x[:, : int(eps * N)] = 1e3
    h = huber_location(x, axis=1)
    b = _contaminated_bias(eps)
    assert 0.05 < b < 0.15
    se = np.std(h, ddof=1) / math.sqrt(R)
    assert abs(np.mean(h) - b) < 4 * se + 2.0 / N, (np.mean(h), b)
    assert np.mean(x, axis=1).min() > 49
    assert abs(np.mean(np.median(x, axis=1)) - sst.norm.ppf(0.5 / (1 - eps))) < 4 * se + 2.0 / N


def test_level_off_an_adc_grid_is_resolved():
    """Codes of a level off the grid with 0.4 q noise: the MAD is 0 or one step, so the scale is
    floored at q and the codes within 1.345 q are averaged: error within 4 standard errors of the
    codes' mean plus the dithered quantiser's bias q / pi exp(-2 pi^2 sigma^2 / q^2), plus the
    clipping at 1.345 q: code 2 (P < 0.3 %) by < 0.6 q and code -1 (P < 1.3 %) by < 0.06 q, together
    < 0.0015 q. The median stays on the grid."""
    rng = np.random.default_rng(3)
    q, sigma, n = 1.0, 0.4, 4000
    mu = rng.uniform(0.1, 0.4, 3)
    x = q * np.rint((mu + sigma * rng.standard_normal((n, 3))) / q)
    x[rng.integers(0, n, 8), 1] += 500 * q
    bound = 4 * math.sqrt(sigma**2 + q**2 / 12) / math.sqrt(n) + q / math.pi * math.exp(
        -2 * math.pi**2 * sigma**2 / q**2) + 0.0015 * q
    assert np.all(np.abs(huber_location(x) - mu) < bound)
    assert np.all(np.abs(np.median(x, axis=0) - mu) > bound)


def test_segment_statistic_huber_per_window_and_its_batch_covariance():
    """segment_statistic('huber') equals huber_location window by window (windows of two lengths);
    the batch-means covariance's diagonal equals segment_statistic_variance, and for white noise
    shared by two channels (a common mode) its off-diagonal mean is the shared variance / N within
    its standard error."""
    rng = np.random.default_rng(8)
    n_seg, fs = 60, 100.0
    lens = np.where(np.arange(n_seg) % 2, 400, 500)
    t = np.arange(lens.sum()) / fs
    common = rng.standard_normal(t.size)
    ch = {f"v{i}": 0.3 * i + common + rng.standard_normal(t.size) for i in range(2)}
    edges = np.concatenate([[0], np.cumsum(lens)])
    segs = {"start_s": t[edges[:-1]], "stop_s": t[edges[1:] - 1] + 0.5 / fs}
    rec = Recording(time_s=t, channels=ch, units={k: "V" for k in ch}, segments=segs,
                    segment_units={"start_s": "s", "stop_s": "s"}, meta={"sample_rate_hz": fs})
    got = segment_statistic(rec, ["v0", "v1"], "huber")
    x = np.stack([ch["v0"], ch["v1"]], 1)
    want = np.array([huber_location(x[a:b]) for a, b in zip(edges[:-1], edges[1:])])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    C = segment_statistic_covariance(rec, ["v0", "v1"], "huber")
    np.testing.assert_allclose(np.diagonal(C, axis1=1, axis2=2), segment_statistic_variance(rec, ["v0", "v1"], "huber"),
                               rtol=1e-10)
    # shared variance 1 per sample, a window's Huber ~ mean of the shared part: cov ~ 1 / N
    ratio = C[:, 0, 1] * lens
    assert abs(np.mean(ratio) - 1.0) < 4 * np.std(ratio, ddof=1) / math.sqrt(n_seg)


def test_statistic_setting_selects_the_seed_median_and_refuses_unknown_names():
    """The campaign and the Monte-Carlo default to 'huber'; 'median' (the seed's) is selectable; an
    unknown name is the project's ConfigError, before anything is simulated."""
    from imurig.campaigns.tilt_table import TiltTableCampaign
    from imurig.kernel.errors import ConfigError
    from imurig.montecarlo.tilt import TILT_TABLE

    assert TiltTableCampaign().statistic == "huber" and TILT_TABLE.validate({})["statistic"] == "huber"
    assert TILT_TABLE.validate({"statistic": "median"})["statistic"] == "median"
    with pytest.raises(ConfigError, match="statistic"):
        TiltTableCampaign(statistic="mode").check_identifiable()
    with pytest.raises(ConfigError, match="statistic"):
        TILT_TABLE.validate({"statistic": "mode"})
