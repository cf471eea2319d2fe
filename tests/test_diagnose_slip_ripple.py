"""A deterministic ripple locked to the table angle (slip rings): found on the signal by regression
on the angle's harmonics, where the running mean of the noise-spread test removes it; numpy-made
samples, not imurig's simulator."""
from __future__ import annotations

import numpy as np
import pytest

from imurig.sensors.effects import SlipRingNoise, TurnSampleView
from imurig.sensors.effects.slip_rings import rounding_harmonic_bound_V
from scipy import ndimage

Q16 = 10.0 / 2**16


def _view(A_V, fs, seed, rate_dps=10.0, rounds=3, noise_V=2e-4, q=Q16):
    """`rounds` rounds at `rate_dps`; the gyro line carries A cos(3 theta - 40 deg), a 1/rev signal
    of 2 mV (the Earth's horizontal rate: physics, not the effect) and white noise, rounded to q."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(rounds * 360.0 / rate_dps * fs)) / fs
    th = np.radians(rate_dps * t) % (2 * np.pi)
    x = (A_V * np.cos(3 * th - np.radians(40.0)) + 2e-3 * np.cos(th - 1.0)
         + noise_V * rng.standard_normal(t.size))
    x = np.round(x / q) * q if q else x
    x = x + 0.05 + 1e-4 * t                                  # bias and drift, removed per window
    res = x - ndimage.uniform_filter1d(x, SlipRingNoise.window, mode="nearest")
    win = (t // (360.0 / rate_dps)).astype(int)              # whole rounds
    return TurnSampleView("gyro_r", th, res, alpha=0.01, signal_V=x, quantum_V=q, window=win, time_s=t), th


@pytest.mark.parametrize("fs", [50.0, 100.0, 1000.0])
def test_ripple_found_with_amplitude_and_phase(fs):
    A = 1e-3
    view, _ = _view(A, fs, seed=int(fs))
    res = SlipRingNoise().test(view)
    rp = res["finding"]["ripple"]
    assert rp["harmonic"] == 3 and abs(rp["amplitude_V"] - A) < 4 * rp["amplitude_se_V"]
    assert abs(rp["phase_deg"] - 40.0) < np.degrees(4 * rp["amplitude_se_V"] / A)   # phase of 3 theta
    assert rp["noise_V"] >= Q16 / np.sqrt(12)


def test_ripple_invisible_to_the_spread_test_but_found():
    """At 1 deg/s the 51-sample running mean removes the ripple: the spread test alone misses it."""
    view, _ = _view(1e-3, 100.0, seed=5, rate_dps=1.0, rounds=1)
    res = SlipRingNoise().test(view)
    assert res["p_value"] > 0.01 and res["finding"]["ripple"]["amplitude_V"] > 0


@pytest.mark.parametrize("q", [Q16, 20 * Q16])
def test_no_ripple_no_finding(q):
    """Without ripple (the 1/rev signal only), at an ADC step below and far above the noise: no finding."""
    view, _ = _view(0.0, 200.0, seed=9, q=q)
    assert "finding" not in SlipRingNoise().test(view)


def test_ripple_below_the_step_found_where_the_noise_dithers():
    """A ripple of q / 3 under noise of 0.6 q (dithered): the rounding of the 2 mV 1/rev signal makes
    harmonics far below it (the bound's exp(-2 pi^2 sigma^2 / q^2)), so it is named; the bound
    itself stays above what the rounding makes of a 1/rev signal without noise."""
    q = 20 * Q16
    view, _ = _view(q / 3, 200.0, seed=4, noise_V=0.6 * q, q=q)
    rp = SlipRingNoise().test(view)["finding"]["ripple"]
    assert rp["harmonic"] == 3 and abs(rp["amplitude_V"] - q / 3) < 4 * rp["amplitude_se_V"]
    assert rp["rounding_bound_V"] < 0.01 * q


def test_rounding_bound_holds_without_dither():
    """Without noise, b + a1 cos(theta) rounded to q: every harmonic 2..5 within the bound, any b."""
    th = np.linspace(0, 2 * np.pi, 20000, endpoint=False)
    for a1 in (0.2, 0.8, 3.0):
        for b in (0.0, 0.3, 0.5):
            e = np.round(b + a1 * np.cos(th)) - (b + a1 * np.cos(th))
            for m in (2, 3, 4, 5):
                assert 2 * abs(np.mean(e * np.exp(-1j * m * th))) <= rounding_harmonic_bound_V(1.0, a1, 0.0, m) + 1e-3
