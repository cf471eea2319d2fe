"""The 'realistic size' criterion of the independent-lab benchmark: a mean-level effect's expected
non-centrality from the lab's manifest (benchmarks/independent_detectability.py)."""
from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
from scipy import stats

from independent_lab import recording, tilt

MOD = Path(__file__).resolve().parents[1] / "benchmarks" / "independent_detectability.py"


def _mod():
    spec = importlib.util.spec_from_file_location("independent_detectability", MOD)
    m = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(m)
    return m


def test_lambda_needed_is_the_90_percent_power_point():
    """For one degree of freedom the power point is (z_crit + z_0.9)^2 to within the far tail's
    contribution; a larger non-centrality gives more power."""
    m = _mod()
    lam = m.lambda_needed(1, alpha=0.01, m=20, power=0.9)
    z = stats.norm.isf(0.01 / 20 / 2)
    assert abs(math.sqrt(lam) - (z + stats.norm.isf(0.1))) < 1e-3
    assert m.lambda_needed(2) > lam


def test_nonlinearity_is_undetectable_on_the_12_bit_converter_and_plain_on_the_24_bit_one(tmp_path):
    """The lab's 48 ug/g^2 nonlinearity (k2 f^2 <= 0.5 mm/s^2) under a 4.9 mV step (about 48 mm/s^2,
    rounding shared by a level's positions) is far below the test's power point; with a 24-bit
    converter the per-position noise is the sensors' own and it is far above."""
    m = _mod()
    out = {}
    for conv in ("12bit_10V", "24bit_10V"):
        _, _, truth = recording("tilt_table", "scale_nonlinearity", 6, 100.0, conv)
        out[conv] = m.detectability(truth, tmp_path / "unused.csv", tilt)
    lo, hi = out["12bit_10V"], out["24bit_10V"]
    assert not lo["detectable"] and max(lo["lambda"].values()) < 1.0
    assert hi["detectable"] and min(hi["lambda"].values()) > 10 * hi["lambda_90"]
    # the position noise: coarse converter ~ its shared rounding error, fine one ~ white noise / sqrt(N)
    # 12 bit: the dither (0.3 q) leaves exp(-4 pi^2 0.09) of the first harmonic's q^2 / (2 pi^2),
    # about (0.04 q)^2 shared, beside (0.015 q)^2 averaged over 800 samples
    q = 2 * 10.0 / 2 ** 12
    _, _, truth = recording("tilt_table", "scale_nonlinearity", 6, 100.0, "12bit_10V")
    K = np.asarray(truth["triad"]["K_V_per_m_s2"])
    sig_q = np.asarray(lo["sigma_position_m_s2"]) * K / q
    assert np.all((sig_q > 0.03) & (sig_q < 0.06)), sig_q
    white = 5e-6 * math.sqrt(50.0) / math.sqrt(8.0 * 100.0) * 9.80665
    assert np.allclose(hi["sigma_position_m_s2"], white, rtol=0.02)


def _turn_truth(effect, fs, conv):
    from independent_lab import turn
    _, _, truth = recording("turn_table", effect, 3, fs, conv)
    return truth, turn


def test_slip_ring_ripple_undetectable_under_a_12_bit_step_plain_under_a_16_bit_one():
    """The lab's 40-80 uV ripple against the 12-bit converter's 4.9 mV step (q/sqrt(12) and 0.3 LSB of
    input noise: about 2 mV per sample) stays below the test's power point; with the 16-bit one
    (about 0.1 mV per sample) it is far above. lambda = N A^2 / 2 / sigma^2 per gyro, so the gyros'
    ratios are their amplitudes' squared."""
    m = _mod()
    lo, turn = _turn_truth("slip_ring_noise", 100.0, "12bit_10V")
    hi, _ = _turn_truth("slip_ring_noise", 100.0, "16bit_5V")
    d_lo, d_hi = m.detectability(lo, Path("unused.csv"), tilt), m.detectability(hi, Path("unused.csv"), tilt)
    assert not d_lo["detectable"] and max(d_lo["lambda"].values()) < d_lo["lambda_90"]
    assert d_hi["detectable"] and min(d_hi["lambda"].values()) > 10 * d_hi["lambda_90"]
    amp = hi["effects"][0]["parameters"]["ripple_amplitude_V"]
    assert math.isclose(d_hi["lambda"]["gyro_x"] / d_hi["lambda"]["gyro_z"], (amp[0] / amp[2]) ** 2, rel_tol=1e-9)
    # N: the whole rounds of the plateaus, a little less than the record's turning time
    assert 0.5 * 250 * 100 < d_hi["samples"] < 300 * 100


def test_timer_jitter_plain_at_1_khz_marginal_at_100_hz_plain_at_50_hz():
    """A 4 ms jitter against the sample grid's dt / sqrt(12): 0.29 ms at 1 kHz (power 1), 2.9 ms at
    100 Hz (about 40 residuals against the gyro's angle: power near, not far above, 90 %). At 50 Hz
    the lab's pulse is 1.5 samples wide and shows one or two high samples: the test times each pulse
    at its middle, whose bracket is half a sample (dt / sqrt(48) = 2.9 ms), with the width's fraction
    of a sample unknown; the lab's exact rates lock the pulses near the middle of their interval, but
    the falling edge then sits near a sample and the jitter flips its count: power near 1."""
    m = _mod()
    fast, _ = _turn_truth("timer_quantisation", 1000.0, "24bit_10V")
    slow, _ = _turn_truth("timer_quantisation", 100.0, "24bit_10V")
    d_fast, d_slow = m.detectability(fast, Path("unused.csv"), tilt), m.detectability(slow, Path("unused.csv"), tilt)
    assert d_fast["detectable"] and d_fast["power"] > 0.999
    assert 0.7 < d_slow["power"] < 0.99 and d_slow["dof"] > 30
    d_50 = m.detectability(_turn_truth("timer_quantisation", 50.0, "24bit_10V")[0], Path("unused.csv"), tilt)
    assert d_50["detectable"] and d_50["power"] > 0.95
