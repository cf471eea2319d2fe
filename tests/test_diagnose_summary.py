"""The rig-free summary of a diagnosis (diagnosis.json's findings, unexplained, verdict), on
hand-made diagnosis entries with numpy residuals of known structure."""
from __future__ import annotations

import json

import numpy as np
import pytest

from imurig.diagnose.summary import check_schema, summarise


def _tilt(residual, reading, white=None, findings=()):
    e = {"findings": list(findings), "scatter": {},
         "residuals": {"unit": "m/s^2", "after": residual.tolist(), "reading_m_s2": reading.tolist(),
                       "elapsed_h": (np.arange(residual.size) / 60.0).tolist()}}
    if white is not None:
        e["unexplained"] = {"white": white}
    return {"kind": "tilt_table", "axes": {"x": e}}


def test_white_residual_leaves_nothing_unexplained():
    rng = np.random.default_rng(2)
    m = 400
    s = summarise(_tilt(1e-3 * rng.standard_normal(m), rng.uniform(-9.8, 9.8, m)))
    assert s["findings"] == [] and s["unexplained"] == []
    assert s["verdict"] == "no effect found: the recording agrees with its twin; nothing left unexplained"
    assert check_schema(json.loads(json.dumps(s))) == []


def test_periodic_residual_is_reported_where_and_how_large():
    """A ripple of amplitude A at 0.05 cycles per row on white noise sigma: reported unexplained,
    its size the residual RMS sqrt(A^2 / 2 + sigma^2) (to a few standard errors of an RMS),
    its signature the ripple's frequency (to one periodogram bin)."""
    rng = np.random.default_rng(3)
    m, A, sig = 400, 5e-3, 1e-3
    r = A * np.sin(2 * np.pi * 0.05 * np.arange(m)) + sig * rng.standard_normal(m)
    s = summarise(_tilt(r, rng.uniform(-9.8, 9.8, m)))
    (u,) = s["unexplained"]
    assert u["channel"] == "acc_x" and u["unit"] == "m/s^2"
    rms = np.sqrt(A**2 / 2 + sig**2)
    assert abs(u["size"] - rms) < 4 * rms / np.sqrt(2 * m)
    assert abs(u["signature"]["peak_cycles_per_row"] - 0.05) <= 1.0 / m
    assert abs(u["where"]["residual"]) == pytest.approx(np.max(np.abs(r)))
    assert "unexplained residual on acc_x" in s["verdict"]
    assert check_schema(json.loads(json.dumps(s))) == []


def test_level_dependent_residual_shows_its_correlation():
    """A residual that grows with the reading (a clipped or nonlinear channel the library lacks):
    the signature's level dependence is far beyond its null spread 1/sqrt(m)."""
    rng = np.random.default_rng(4)
    m = 300
    reading = rng.uniform(-9.8, 9.8, m)
    r = 1e-4 * np.abs(reading) ** 3 / 100 * rng.standard_normal(m) + 2e-4 * np.sign(reading) * reading**2 / 100
    s = summarise(_tilt(r, reading, white=False))
    sig = s["unexplained"][0]["signature"]
    assert sig["level_dependence"] > 5 / np.sqrt(m) and abs(sig["correlation_with_setpoint"]) > 5 / np.sqrt(m)


def test_engine_finding_carries_units_and_fit():
    f = {"effect": "adc_crosstalk", "parameters": [{"name": "adc_crosstalk:c", "estimate": 2e-4, "std_error": 1e-5}]}
    d = _tilt(np.zeros(10), np.zeros(10), white=True, findings=[f])
    d["axes"]["x"]["fit_steps"] = [{"after_effect": None, "residual_rms": 3e-3},
                                   {"after_effect": "adc_crosstalk", "residual_rms": 1e-3}]
    s = summarise(d)
    (g,) = s["findings"]
    assert g["parameters"] == [{"name": "c", "estimate": 2e-4, "se": 1e-5, "unit": "m/s^2/V"}]  # the library's unit
    assert g["fit"] == {"before_rms": 3e-3, "after_rms": 1e-3, "unit": "m/s^2"}
    assert check_schema(s) == []
    assert check_schema({"findings": [{"effect": "x"}], "unexplained": [], "verdict": "a"}) != []


def test_residuals_without_spread_are_not_unexplained():
    """A fit as large as its data leaves residuals of zero: no lag-1 correlation exists, and the
    channel must not be reported as unexplained (it was, through a NaN correlation)."""
    from imurig.diagnose.summary import unexplained
    flat = {"findings": [], "residuals": {"after": [0.0] * 7, "unit": "rad/s"}}
    ripple = {"findings": [], "residuals": {"after": np.sin(np.arange(20) * 2 * np.pi / 20).tolist(),
                                            "unit": "rad/s"}}
    assert unexplained({"kind": "turn_table", "gyros": {"p": flat}}) == []
    assert [u["channel"] for u in unexplained({"kind": "turn_table", "gyros": {"q": ripple}})] == ["gyro_q"]
