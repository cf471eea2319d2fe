"""Thermal chamber, temperature effects and the thermal calibration, against truth."""
from __future__ import annotations

import math

import numpy as np
import pytest

from imurig.calibration.thermal import ThermalCalibration
from imurig.campaigns.thermal import Z_BOUND, ThermalCampaign, analyse
from imurig.kernel.errors import RecordingError, ScheduleError
from imurig.rigs.thermal_chamber import ThermalProfile
from imurig.sensors.thermal import first_order_lag, hysteresis_state, play_operator

#: a shorter profile for the tests: -40..40 C in 20 C steps, two cycles, 40 min soak
SHORT = ThermalProfile(low_C=-40, high_C=40, step_C=20, soak_s=2400, attitude_dwell_s=40)


def test_first_order_lag_closed_form():
    t = np.arange(0, 3600, 0.1)
    x = np.where(t >= 100, 10.0, 0.0)
    y = first_order_lag(x, t, 300.0)
    k = t >= 100
    np.testing.assert_allclose(y[k], 10 * (1 - np.exp(-(t[k] - 100 + 0.1) / 300)), rtol=0, atol=2e-3)


def test_play_operator_branches():
    T = np.concatenate([np.linspace(0, 50, 501), np.full(100, 50.0), np.linspace(50, 0, 501), np.full(100, 0.0)])
    h = hysteresis_state(T, 4.0, fs=1.0)
    assert h[550] == pytest.approx(0.5)   # held after heating
    assert h[-1] == pytest.approx(-0.5)   # held after cooling
    assert np.all(np.abs(h) <= 0.5 + 1e-12)
    np.testing.assert_array_equal(play_operator(np.zeros(5), 1.0), np.zeros(5))


@pytest.fixture(scope="module")
def runs():
    out = []
    for seed in (1, 2, 3):
        rec = ThermalCampaign(profile=SHORT, seed=seed).simulate()
        out.append((rec, analyse(rec)))
    return out


def test_thermal_coefficients_within_standard_errors(runs):
    for rec, res in runs:
        for c in res["coefficients"]:
            assert c["injected"] is not None
            assert abs(c["z"]) <= Z_BOUND, c


def test_thermal_standard_errors_honest(runs):
    z = np.array([c["z"] for _, res in runs for c in res["coefficients"]])
    assert 0.6 <= math.sqrt(np.mean(z**2)) <= 1.4, z


def test_hysteresis_gap_equals_injected(runs):
    """The heating and cooling branches lie apart by the injected bias hysteresis.

    The measured gap equals the noise-free twin's gap within 4 standard errors. The twin's gap
    differs from the injected H only by (a) the thermal lag left after the soak, which makes
    the heating branch sit e^(-t/tau) x step colder than the set-point and the cooling branch
    as much warmer: 2 |db/dT|max step e^(-t/tau), and (b) the gain G of the indicated units."""
    from imurig.sensors.chain import ThermalLags

    p = SHORT
    settle = p.soak_s + p.switch_s
    lag = math.exp(-settle / ThermalLags().accelerometers_s)
    for rec, res in runs:
        acc = rec.truth["sensors"]["accelerometers"]
        sens = np.asarray(rec.meta["acc_nominal_sensitivity_V_per_m_s2"])
        G = np.asarray(acc["sensitivity_V_per_m_s2"]) / sens
        dT = np.linspace(p.low_C - 25, p.high_C - 25, 101)
        for j, a in enumerate("xyz"):
            h = res["hysteresis"][f"acc_bias_{a}"]
            fitted = next(c for c in res["coefficients"] if c["name"] == f"acc_bias_{a}:hysteresis")
            assert abs(h["measured_gap_m_s2"] - h["injected_gap_m_s2"]) < 4 * fitted["std_error"] * math.sqrt(2), h
            slope = np.abs(acc["bias_tempco_m_s2_per_K"][j] + 2 * acc["bias_tempco2_m_s2_per_K2"][j] * dT
                           + 3 * acc["bias_tempco3_m_s2_per_K3"][j] * dT**2).max()
            H = acc["bias_hysteresis_m_s2"][j]
            bound = 2 * slope * p.step_C * lag * G[j] + abs(G[j] - 1) * H + 4 * fitted["std_error"]
            assert abs(h["injected_gap_m_s2"] - G[j] * H) <= bound, (h, bound)
            assert H > 10 * fitted["std_error"]  # clearly resolved


def test_correction_removes_temperature_dependence(runs):
    """After the thermal correction the bias spread over the steps drops to the noise: by 3x or
    more wherever the true temperature effect (the twin's spread) stands clear of the noise."""
    for rec, res in runs:
        for k, v in res["spread"].items():
            before, after = list(v.values())
            kind, ax = k.rsplit("_", 1)
            j = ("xyz" if kind == "acc_bias" else "pqr").index(ax)
            true_spread = np.std(res["twin_table"][kind][:, j], ddof=1)
            if true_spread > 5 * after:
                assert after < before / 3, (k, v)
            else:
                assert after <= 1.1 * before, (k, v)


def test_one_temperature_is_refused():
    with pytest.raises(ScheduleError, match="temperature"):
        ThermalProfile(low_C=20, high_C=20, step_C=10).validate()
    with pytest.raises(ScheduleError, match="-70 to \\+150"):
        ThermalProfile(low_C=-100).validate()


def test_fit_refuses_single_temperature(runs):
    rec, res = runs[0]
    tab = dict(res["table"])
    keep = np.isclose(tab["T_set"], tab["T_set"][0])
    tab = {k: (v[keep] if isinstance(v, np.ndarray) and v.shape[:1] == keep.shape else v) for k, v in tab.items()}
    with pytest.raises(RecordingError, match="one temperature"):
        ThermalCalibration().fit(tab)
