"""The effect library: every effect keeps the contract, and each one's physics holds in closed form."""
from __future__ import annotations

import json
import math
from dataclasses import fields, is_dataclass, replace

import numpy as np
import pytest

from imurig.sensors.adc import DAQ6036E
from imurig.sensors.effects import LIBRARY, STAGES, AdcCrosstalk, Candidate, PositionView, ScanSlot, by_name
from imurig.sensors.effects.adc_quantisation import floor_V, variance_V2


@pytest.mark.parametrize("cls", LIBRARY, ids=lambda c: c.name)
def test_effect_contract(cls):
    """Names are unique and say where they act; the words and the seed's support are there; the
    parameters carry units; settings and description are plain JSON."""
    assert [c.name for c in LIBRARY].count(cls.name) == 1 and by_name(cls.name) is cls
    assert cls.stage in STAGES
    assert cls.physics and cls.seed_section and cls.seed_says
    assert all(p.unit for p in cls.params)
    eff = cls()
    assert is_dataclass(eff)
    json.dumps(eff.settings())
    json.dumps(cls.describe())
    if "enabled" in {f.name for f in fields(eff)}:  # switched off, the chain sees nothing of it
        x = np.linspace(-1.0, 1.0, 50)
        off = replace(eff, enabled=False)
        slot = ScanSlot(1, 20e3, previous_V=np.full(50, 3.0))
        assert np.array_equal(off.inject(x, slot, np.random.default_rng(0)), x)


def _view(m=12, scan=("acc_x", "mag_x", "acc_y")):
    rng = np.random.default_rng(1)
    med = {c: rng.normal(size=m) for c in scan}
    return PositionView(channel="acc_y", axis="y", readings={n: rng.normal(size=m) for n in ("ax", "ay", "az")},
                        channel_median=med.get, scan_list=scan), med


@pytest.mark.parametrize("cls", [c for c in LIBRARY if c.views], ids=lambda c: c.name)
def test_candidates_have_one_row_per_observation(cls):
    view, _ = _view()
    for cand in cls().candidates(view):
        assert isinstance(cand, Candidate) and cand.name == cls.name
        for th in cand.scan:
            assert cand.design(th).shape == (12, len(cand.param_names))


def test_crosstalk_injection_closed_form():
    """u_j + c (u_{j-1} - u_j) with c = exp(-1 / (f_mux tau)), to machine precision."""
    eff = AdcCrosstalk(settling_tau_s=0.59e-6)
    c = math.exp(-1.0 / (200e3 * 0.59e-6))
    assert eff.coefficient(200e3) == pytest.approx(c, rel=1e-15)
    u, prev = np.array([0.1, -2.0, 4.0]), np.array([1.0, 1.0, -3.0])
    np.testing.assert_allclose(eff.inject(u, ScanSlot(2, 200e3, prev)), u + c * (prev - u), rtol=0, atol=1e-15)
    assert AdcCrosstalk(enabled=False).coefficient(200e3) == 0.0


def test_crosstalk_truth_map_is_the_inverse_models_coefficient():
    """Regressing the true specific force on (measured volts, previous channel's volts) gives the
    coefficient the effect's ``fitted`` states, -c / (s (1 - c)), to machine precision."""
    rng = np.random.default_rng(2)
    s, f_mux = 1.33e-3 / 9.80665 * 750.0, 150e3
    eff = AdcCrosstalk(settling_tau_s=1e-6)
    c = eff.coefficient(f_mux)
    f = rng.normal(0, 9.8, 40)
    v_prev = rng.normal(0, 2.0, 40)
    v_meas = eff.inject(s * f, ScanSlot(2, f_mux, v_prev))
    coef, *_ = np.linalg.lstsq(np.column_stack([v_meas, v_prev]), f, rcond=None)
    truth = {"chain": {"adc": {"crosstalk_coefficient": c}},
             "sensors": {"accelerometers": {"sensitivity_V_per_m_s2": [0.0, s, 0.0]}}}
    assert coef[1] == pytest.approx(eff.fitted(truth, "acc_y")["c"], rel=1e-9)


def test_crosstalk_candidate_is_the_previous_channels_median():
    view, med = _view()
    (cand,) = AdcCrosstalk().candidates(view)
    np.testing.assert_array_equal(cand.design(None)[:, 0], med["mag_x"])
    first = replace(view, channel="acc_x")  # the scan wraps round: acc_x follows acc_y
    np.testing.assert_array_equal(AdcCrosstalk().candidates(first)[0].design(None)[:, 0], med["acc_y"])
    assert AdcCrosstalk().candidates(replace(view, scan_list=())) == []


@pytest.mark.parametrize("averaging", [1, 10])
def test_quantisation_variance_matches_the_converter(averaging):
    """The converter's error on a constant input has the variance (q^2/12 + (k_e q)^2) / n_avg,
    within 4.5 standard errors of the sample variance (SE from the sample's own fourth moment)."""
    adc = DAQ6036E(scan_list=("a",), range_V=0.05, input_noise_lsb_rms=0.6, common_mode_noise_V_rms=0.0,
                   skew_enabled=False, crosstalk_enabled=False, averaging=averaging)
    n = 200_000
    x = np.random.default_rng(3).uniform(-0.01, 0.01, n)  # spread over many codes: the rounding error is uniform
    out, _ = adc.convert({"a": x}, np.arange(n) / 1e3, np.random.default_rng(4))
    e = out["a"] - x
    var, m4 = np.var(e), np.mean((e - e.mean()) ** 4)
    se = math.sqrt((m4 - var**2) / n)
    assert abs(var - variance_V2(adc.lsb_V, 0.6, averaging)) < 4.5 * se
    assert adc.sample_variance_V2() == variance_V2(adc.lsb_V, 0.6, averaging)
    assert floor_V(adc.lsb_V) == pytest.approx(adc.lsb_V / math.sqrt(12), rel=1e-15)
