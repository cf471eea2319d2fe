"""Mains factor and table slip from a turn-table time series' windows (pulses or integrated rate),
numpy-made: dial rates, a 60 Hz motor on the recording's mains, slip s1 r^-alpha, timer noise."""
from __future__ import annotations

import numpy as np
import pytest

from imurig.diagnose.table_rate import diagnose_table_rate


def _windows(seed, mains_hz, s1=0.0, alpha=0.7, sigma=2e-4, m=24):
    rng = np.random.default_rng(seed)
    dial_dps = np.tile([5.0, 10.0, 20.0, 50.0, 100.0, 200.0], m // 6) * rng.choice([-1, 1], m)
    eff = np.abs(dial_dps) * mains_hz / 60.0
    meas = eff * (1 - s1 * eff ** (-alpha)) * (1 + sigma * rng.standard_normal(m))
    return np.radians(dial_dps), np.radians(meas) * np.sign(dial_dps)


@pytest.mark.parametrize("mains_hz", [50.0, 60.0])
def test_mains_factor_read_from_the_recording(mains_hz):
    dial, meas = _windows(1, mains_hz)
    out = diagnose_table_rate(dial, meas, np.random.default_rng(1), mains_hz=mains_hz, n_sim=200)
    if mains_hz == 50.0:
        f = out["finding_mains"]
        assert f["matched_factor"] == pytest.approx(5 / 6)
        est, se = f["parameters"][0]["estimate"], f["parameters"][0]["std_error"]
        assert abs(est - 5 / 6) < 4 * se
    else:                                      # a 60 Hz motor on 60 Hz mains: nothing to name
        assert "finding_mains" not in out and out["shortfall"]["findings"] == []


def test_slip_found_on_the_windows():
    """Slip s1 = 0.03 at alpha = 0.7: named, s1 within 4 SE of the truth (-s1, first order)."""
    dial, meas = _windows(2, 50.0, s1=0.03)
    out = diagnose_table_rate(dial, meas, np.random.default_rng(2), mains_hz=50.0, n_sim=200)
    (f,) = out["shortfall"]["findings"]
    p = f["parameters"][0]
    assert f["effect"] == "table_slip" and abs(p["estimate"] - (-0.03)) < 4 * p["std_error"]


def test_too_few_windows_is_said():
    out = diagnose_table_rate(np.radians([10.0, 20.0]), np.radians([8.3, 16.6]), np.random.default_rng(0))
    assert out["tested"] is False and "at least" in out["why"]
