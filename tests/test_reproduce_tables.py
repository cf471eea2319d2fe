"""``imurig reproduce`` items of the seed's final accelerometer calibration: Tabs. 4.4-4.6, Figs. 4.10, 4.13, 4.14."""
from __future__ import annotations

import math

import numpy as np
import pytest

from imurig.calibration.accelerometer import INPUTS, MODELS
from imurig.reports import reproduce as R
from imurig.reports import reproduce_tables as T

KEYS = ("tab_4_4", "tab_4_5", "tab_4_6", "fig_4_10", "fig_4_13", "fig_4_14")


def _tilt_positions(rng):
    """u (240, 3) on the seed's 10 x 12 x 2 positions (unit-gravity directions x 9.81, both mountings)."""
    th, ph = np.meshgrid(np.radians(np.arange(0, 91, 10)), np.radians(np.arange(0, 360, 30)), indexing="ij")
    th, ph = th.ravel(), ph.ravel()
    f = 9.81 * np.column_stack([-np.cos(ph) * np.sin(th), np.sin(ph) * np.sin(th), np.cos(th)])
    return np.vstack([f * [1, -1, -1], f]) + rng.normal(0, 1e-3, (240, 3))


def test_seed_fit_closed_form_sigma_m_res_and_r():
    rng = np.random.default_rng(1)
    u = _tilt_positions(rng)
    inputs = {n: u[:, j] for j, n in enumerate(INPUTS)}
    X = MODELS["linear"]("x").design(inputs)
    # a residual orthogonal to the model's columns: the fit returns exactly it
    r = rng.normal(0, 0.005, 240)
    r -= X @ np.linalg.lstsq(X, r, rcond=None)[0]
    ref = 1.01 * u + r[:, None]
    fit = T.seed_fit(u, ref, "linear")
    assert fit["sigma_res"][0] == pytest.approx(np.std(r, ddof=1), rel=1e-9)
    np.testing.assert_allclose(fit["residuals"][0], -r, atol=1e-12)
    # the seed's M_res and R compare the reading with the calibrated value 1.01 u (listing C.1.1)
    ss = np.sum((0.01 * u[:, 0]) ** 2)
    assert fit["m_res"][0] == pytest.approx(ss / (240 - 4), rel=1e-6)
    assert fit["R"][0] == pytest.approx(math.sqrt(1 - ss / np.sum((u[:, 0] - u[:, 0].mean()) ** 2)), rel=1e-9)
    # no error at all: the seed's M_res is 0 and R is 1
    exact = T.seed_fit(u, u, "linear")
    assert max(exact["m_res"]) < 1e-20 and min(exact["R"]) == pytest.approx(1.0)


def test_sigma_se_and_the_reduction_se_against_a_monte_carlo():
    assert T.sigma_rel_se(240, 4) == pytest.approx(1 / math.sqrt(472))
    rng = np.random.default_rng(7)
    u = _tilt_positions(rng)
    inputs = {n: u[:, j] for j, n in enumerate(INPUTS)}
    X4, X7 = MODELS["linear"]("x").design(inputs), MODELS["cross"]("x").design(inputs)
    signal = 1.3e-4 * X7[:, 6]               # a real product term in the truth (the seed's size)
    d, s4, s7 = [], [], []
    for _ in range(400):
        y = X4 @ [0.01, 1.0, 0.005, 0.0] + signal + rng.normal(0, 0.005, 240)
        r4 = y - X4 @ np.linalg.lstsq(X4, y, rcond=None)[0]
        r7 = y - X7 @ np.linalg.lstsq(X7, y, rcond=None)[0]
        s4.append(np.std(r4, ddof=1))
        s7.append(np.std(r7, ddof=1))
        d.append(1 - s7[-1] / s4[-1])
    se = T.reduction_se(float(np.mean(s4)), float(np.mean(s7)), 240, 7, 3)
    sd = float(np.std(d, ddof=1))
    # the delta method's SE matches the scatter of 400 repeats: their sd has a relative SE of 1/sqrt(2 x 399)
    # = 3.5 %, the band is 4.3 of those
    assert 0.85 * sd < se < 1.15 * sd
    # pure noise: a small reduction with a small SE
    assert T.reduction_se(1.0, math.sqrt(1 - 3 / 236), 240, 7, 3) < 0.01


def test_phi_harmonics_closed_form():
    phi = np.radians(np.arange(0, 360, 30))
    v = np.column_stack([0.1 - 0.64 * np.cos(phi), 0.64 * np.sin(phi), np.full(12, -0.76)])
    level, amp = T.phi_harmonics(phi, v)
    np.testing.assert_allclose(level, [0.1, 0.0, -0.76], atol=1e-12)
    np.testing.assert_allclose(amp, [0.64, 0.64, 0.0], atol=1e-12)


def test_the_items_are_registered_with_their_explanations():
    for k in KEYS:
        it = R.ITEMS[k]
        assert it.describes and it.if_outside and it.seed_ref
        assert (it.figure is not None) == k.startswith("fig")
    assert not any(k in key for key in R.PENDING for k in KEYS)


@pytest.mark.slow
def test_the_items_run_and_their_rows_are_well_formed(tmp_path):
    from imurig.kernel.outputs import OutputFolder

    rows = {k: R.ITEMS[k].run() for k in KEYS}
    for k, rs in rows.items():
        assert rs and all(r["item"] == k and r["tolerance"] > 0 for r in rs)
        for r in rs:
            assert r["verdict"] == ("within" if abs(r["imurig"] - r["seed"]) <= r["tolerance"] else "outside")
    assert len(rows["tab_4_4"]) == 3 and len(rows["tab_4_5"]) == 8 and len(rows["tab_4_6"]) == 6
    # fit targets say so in their notes, predictions too: x and y of Tabs. 4.4-4.5 and the kept products
    for k in ("tab_4_4", "tab_4_5", "tab_4_6", "fig_4_14"):
        for r in rows[k]:
            target = k in ("tab_4_4", "tab_4_5") and (" A_x" in r["quantity"] or " A_y" in r["quantity"])
            assert ("FIT TARGET" in r["note"]) == target and ("PREDICTION" in r["note"]) != target
    # the fitted sizes carry over from the fit's design labs to the reproduce labs (other seeds): the targets
    # come out within the seed's scatter, and the products now remove a share of x and y like the seed's
    assert all(r["verdict"] == "within" for r in rows["tab_4_5"] if "FIT TARGET" in r["note"])
    s = {k: np.array([r["imurig"] for r in rows[k][:3]]) for k in ("tab_4_4", "tab_4_5", "tab_4_6")}
    assert np.all(s["tab_4_5"][:2] < 0.92 * s["tab_4_4"][:2])
    # z: a phi error leaves it alone, so its products fit only noise (reduction below 3 %)
    assert s["tab_4_5"][2] > 0.97 * s["tab_4_4"][2]
    # Fig. 4.10's ratios follow eqs. 4.36-4.38 to the virtual IMU's scale errors (within 3 % each)
    assert all(abs(r["imurig"] / r["seed"] - 1) < 0.03 for r in rows["fig_4_10"])
    out = OutputFolder(tmp_path / "r")
    with out:
        summary = R.reproduce("fig_4_14", out, log=lambda *_: None)
    md = (tmp_path / "r" / "reproduce.md").read_text()
    assert "fig_4_14_residuals.png" in md and (tmp_path / "r" / "fig_4_14_residuals.png").stat().st_size > 1000
    assert summary["quantities"] == 3
