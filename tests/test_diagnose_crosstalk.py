"""Crosstalk without ``adc.scan_list`` in the metadata: the scan order defaults to the file's
channel order (said in the finding); numpy-made position medians, not imurig's simulator."""
from __future__ import annotations

import numpy as np
import pytest

from imurig.diagnose.engine import select_effects
from imurig.diagnose.samples import scan_order
from imurig.kernel.recording import Recording
from imurig.sensors.effects import PositionView, for_view

G = 9.80665


def _positions(c: float, seed: int, m: int = 36, s_V=2.5e-3 * G / G, noise_V=2e-6):
    """Per-position medians of a triad and a magnetometer channel at m random attitudes; acc_y's
    converter slot keeps a fraction c of the previously converted mag_x: V_y' = (1 - c) V_y + c V_m."""
    rng = np.random.default_rng(seed)
    g = rng.normal(size=(m, 3))
    f = G * g / np.linalg.norm(g, axis=1, keepdims=True)                 # specific force at rest (m/s^2)
    V = 0.01 + s_V * f + noise_V * rng.standard_normal((m, 3))          # V
    Vm = rng.uniform(-2.0, 2.0, m)                                       # the field along mag_x (V)
    Vy = (1 - c) * V[:, 1] + c * Vm
    return f, V, Vy, Vm, s_V


def _recording():
    n = 10
    ch = {k: np.zeros(n) for k in ("acc_x", "mag_x", "acc_y", "acc_z")}
    return Recording(np.arange(n) / 100.0, ch, {k: "V" for k in ch}, meta={"rig": "tilt_table"})


def _diagnose(c, seed):
    f, V, Vy, Vm, s = _positions(c, seed)
    rec = _recording()
    scan, source = scan_order(rec)
    assert scan == ["acc_x", "mag_x", "acc_y", "acc_z"] and "channel order of the file" in source
    u = {"ax": (V[:, 0] - 0.01) / s, "ay": (Vy - 0.01) / s, "az": (V[:, 2] - 0.01) / s}
    med = {"acc_x": V[:, 0], "mag_x": Vm, "acc_y": Vy, "acc_z": V[:, 2]}
    view = PositionView("acc_y", "y", u, med.get, scan_list=tuple(scan), model_terms=frozenset({"b", "s_y"}))
    lib = [cand for cls in for_view(PositionView.kind) for cand in cls().candidates(view)
           if cand.name == "adc_crosstalk"]
    X0 = np.column_stack([np.ones(f.shape[0]), u["ay"], u["ax"], u["az"]])
    return select_effects(f[:, 1], X0, ["b", "s", "m_yx", "m_yz"], lib, np.random.default_rng(seed), alpha=0.01,
                          n_sim=200), s


@pytest.mark.parametrize("seed", [1, 2])
def test_crosstalk_found_in_file_order(seed):
    c = 2e-3
    d, s = _diagnose(c, seed)
    (f,) = d.findings
    est, se = f.params["adc_crosstalk:c"]
    assert f.name == "adc_crosstalk" and abs(est - (-c / ((1 - c) * s))) < 4 * se


def test_no_crosstalk_no_finding():
    d, _ = _diagnose(0.0, 3)
    assert d.findings == []
