"""The Delft 2005 lab preset (issue 17): the converter's options, the preset against the quiet lab,
and the Tab. 4.3 fit (truth tests: sizes recovered within their standard errors)."""
import math
from dataclasses import asdict

import numpy as np
import pytest

from imurig.campaigns.delft_2005 import Delft2005, fitted_sizes
from imurig.campaigns.tilt_table import TiltTableCampaign
from imurig.kernel.errors import ConfigError
from imurig.kernel.units import ARCMIN
from imurig.montecarlo import delft_fit, delft_fit_42, delft_fit_44
from imurig.rigs.tilt_table import TiltTableProtocol
from imurig.sensors.adc import DAQ6036E
from imurig.sensors.chain import DEFAULT_SCAN


def test_a_grounded_slot_leaks_zero_volts_as_a_scale_factor_and_a_line_settles_with_its_own_tau():
    """u_j <- u_j + c (u_{j-1} - u_j): after a grounded slot u_{j-1} = 0, so u_j (1 - c); channel y has its tau."""
    n = 4000
    analog = {"a": np.full(n, 1.0), "b": np.full(n, -2.0), "y": np.full(n, 3.0)}
    t = np.arange(n) / 1000.0
    tau, tau_y = 0.8e-6, 1.2e-6
    c, cy = math.exp(-1 / (200e3 * tau)), math.exp(-1 / (200e3 * tau_y))
    kw = dict(mux_frequency_hz=200e3, settling_tau_s=tau, skew_enabled=False, common_mode_noise_V_rms=0.0,
              channel_settling_tau_s={"y": tau_y})
    rng = np.random.default_rng(3)
    g, rep = DAQ6036E(scan_list=("a", "b", "y"), ground_between=True, **kw).convert(analog, t, rng)
    p, _ = DAQ6036E(scan_list=("a", "b", "y"), **kw).convert(analog, t, rng)
    noise_se = DAQ6036E(scan_list=("a",)).lsb_V * 0.8 / math.sqrt(n)   # rounding + input noise per mean
    assert abs(g["b"].mean() - (-2.0) * (1 - c)) < 5 * noise_se
    assert abs(g["y"].mean() - 3.0 * (1 - cy)) < 5 * noise_se
    assert abs(p["y"].mean() - (3.0 + cy * (-2.0 - 3.0))) < 5 * noise_se   # the previous data slot leaks
    assert rep["crosstalk_coefficients"]["y"] == pytest.approx(cy)
    with pytest.raises(ConfigError, match="grounded slot"):
        DAQ6036E(scan_list=DEFAULT_SCAN, ground_between=True).validate()   # 20 slots > 16
    with pytest.raises(ConfigError, match="not in the scan list"):
        DAQ6036E(scan_list=("a",), channel_settling_tau_s={"z": 1e-6}).validate()


def test_the_preset_differs_from_the_quiet_lab_only_by_its_named_imperfections():
    proto = TiltTableProtocol(theta_deg=(0.0, 90.0), phi_deg=(0.0, 90.0, 180.0, 270.0), runs=("z_down",))
    t0, lab0, _ = TiltTableCampaign(protocol=proto).build()
    t1, lab1, _ = TiltTableCampaign(protocol=proto, lab="delft-2005").build()
    pre = Delft2005.fitted()
    e0, e1 = asdict(t0.errors), asdict(t1.errors)
    assert {k for k in e0 if e0[k] != e1[k]} == {"setting_resolution_rad"}
    assert e1["setting_resolution_rad"] == pre.setting_error_rad
    a0, a1 = lab0.adc.settings(), lab1.adc.settings()
    assert {k for k in a0 if a0[k] != a1[k]} <= {"settling_tau_s", "channel_settling_tau_s", "crosstalk_coefficient",
                                                 "crosstalk_coefficients", "channel_slow_settling"}
    assert a1["channel_settling_tau_s"] == {"acc_y": pre.settling_tau_y_s}
    assert a1["channel_slow_settling"] == {"acc_y": (pre.slow_tail_alpha, pre.slow_tail_tau_s)}
    assert [e.name for e in lab0.effects] == []
    assert sorted(e.name for e in lab1.effects) == sorted(e.name for e in pre.effects())
    assert lab1.pump.rms_m_s2 == pre.pump_rms_m_s2 and lab0.pump.rms_m_s2 == type(lab0.pump)().rms_m_s2
    assert all(e.seed_says for e in lab1.effects)
    assert all(r["seed_says"] for r in pre.describe()) and sum(r["fitted"] for r in pre.describe()) == 7
    with pytest.raises(ConfigError, match="unknown lab"):
        TiltTableCampaign(protocol=proto, lab="delft").build()


def test_the_preset_constants_are_the_fit_record():
    rec = fitted_sizes()
    pre = Delft2005.fitted()
    assert pre.setting_error_rad == pytest.approx(rec["sizes"]["setting_error_arcmin"]["value"] * ARCMIN)
    assert pre.settling_tau_y_s == rec["sizes"]["settling_tau_y_s"]["value"]
    assert rec["dof"] == 10 and len(rec["z"]) == 5
    assert pre.channel_slow_settling() == {"acc_y": (rec["sizes"]["slow_tail_alpha"]["value"],
                                                     rec["sizes"]["slow_tail_tau_s"]["value"])}
    s42 = rec["table_4_2"]["sizes"]
    assert (pre.cable_offset_V, pre.pump_rms_m_s2) == (s42["cable_offset_V"]["value"], s42["pump_rms_m_s2"]["value"])
    fin = rec["final_campaign"]["sizes"]
    assert pre.reference_phi_error_rad == pytest.approx(fin["reference_phi_error_arcmin"]["value"] * ARCMIN)
    assert pre.final_setting_error_rad == pytest.approx(fin["setting_error_arcmin"]["value"] * ARCMIN)
    assert pre.reference_phi_error().delta_phi_rad == pre.reference_phi_error_rad
    assert rec["final_campaign"]["dof"] == 4 and rec["final_campaign"]["bounds"]["reference_phi_error_arcmin"]["within"]


def _synthetic_design():
    """F, S, K of the size the simulator gives (assets record), for the estimator's own truth test."""
    d = fitted_sizes()["design"]
    return {k: np.array(d[k]) for k in ("F", "S", "K", "Q")}


def test_the_fit_recovers_known_sizes_from_tables_made_with_them():
    """Tables drawn from the model with the seed's relative scatter 1/8: the WLS estimate lies within
    3 SE of the truth in each of 20 draws for w and the y tail's alpha (c of the card and c_y of the y line
    are at their bound 0 in some)."""
    d = _synthetic_design()
    truth = np.array([2.5, 4e-4, 1e-3, 0.012, 0.40])
    exact = delft_fit.model_sigmas(truth, d)
    res = delft_fit.fit(exact, d)
    assert res["sizes"]["setting_error_arcmin"]["value"] == pytest.approx(2.5, rel=1e-4)
    assert res["sizes"]["slow_tail_alpha"]["value"] == pytest.approx(0.012, rel=1e-3)
    assert res["sizes"]["slow_tail_decay"]["value"] == pytest.approx(0.40, rel=1e-3)
    rng = np.random.default_rng(17)
    misses = 0
    for _ in range(20):
        table = exact * (1 + delft_fit.REL_SE * rng.standard_normal(exact.shape))
        s = delft_fit.fit(table, d)["sizes"]
        for key, k in (("setting_error_arcmin", 0), ("slow_tail_alpha", 3)):
            misses += abs(s[key]["value"] - truth[k]) > 3 * s[key]["se"]
    assert misses <= 1   # 40 comparisons at 3 SE: P(> 1 miss) < 0.01


@pytest.mark.slow
def test_the_fit_recovers_sizes_from_simulator_output():
    """Tab. 4.3 made by the simulator with known sizes (own seeds), fitted with a design on other seeds."""
    w, c, cy, alpha, ys = 2.0, 5e-4, 1e-3, 0.012, 0.40
    tau, tau_y, tail = delft_fit.tau_for(c), delft_fit.tau_for(cy), (alpha, delft_fit.tau_for(ys))
    table = np.array([delft_fit.simulate_sigmas(w, tau, tau_y, f, g, 900 + i, tail)
                      for i, (f, g) in enumerate(delft_fit.SETTINGS)])
    res = delft_fit.fit(table, delft_fit.design(seeds=(11, 12, 13)))
    s = res["sizes"]
    for key, truth in (("setting_error_arcmin", w), ("c200", c), ("slow_tail_alpha", alpha)):
        assert abs(s[key]["value"] - truth) < 3 * s[key]["se"], key


def test_the_tab_4_2_fit_recovers_known_sizes_from_tables_made_with_them():
    """As for Tab. 4.3, with the Tab. 4.2 terms of the record and its relative scatter 1/sqrt(2(240-4))."""
    d = {k: np.array(v) for k, v in fitted_sizes()["table_4_2"]["design"].items()}
    truth = np.array([3.0, 0.025, 0.08])
    exact = delft_fit_42.model_sigmas(truth, d)
    got = delft_fit_42.fit(exact, d)["sizes"]
    assert [got[k]["value"] for k in ("setting_error_arcmin", "pump_rms_m_s2", "cable_offset_V")] == \
        pytest.approx(truth, rel=1e-4)
    rng = np.random.default_rng(5)
    misses = 0
    for _ in range(20):
        s = delft_fit_42.fit(exact * (1 + delft_fit_42.REL_SE * rng.standard_normal(exact.shape)), d)["sizes"]
        misses += sum(abs(s[k]["value"] - t) > 3 * s[k]["se"]
                      for k, t in zip(("setting_error_arcmin", "pump_rms_m_s2", "cable_offset_V"), truth))
    assert misses <= 1   # 60 comparisons at 3 SE: P(> 1 miss) < 0.02


def _final_design():
    return {k: np.array(v) for k, v in fitted_sizes()["final_campaign"]["design"].items()}


def test_the_seeds_covariance_of_nested_sigmas_against_a_monte_carlo():
    """seed_covariance's (sigma_4.4, sigma_4.5) block against 300 nested regressions on 240 rows with a real
    product term: the correlation within 0.1 (the MC correlation's SE is ~0.03 at rho ~ 0.7)."""
    rng = np.random.default_rng(3)
    th, ph = np.meshgrid(np.radians(np.arange(0, 91, 10)), np.radians(np.arange(0, 360, 30)), indexing="ij")
    f = 9.81 * np.column_stack([-np.cos(ph.ravel()) * np.sin(th.ravel()), np.sin(ph.ravel()) * np.sin(th.ravel()),
                                np.cos(th.ravel())])
    u = np.vstack([f * [1, -1, -1], f])
    X4 = np.column_stack([np.ones(240), u])
    X7 = np.column_stack([X4, u[:, 0] * u[:, 1], u[:, 0] * u[:, 2], u[:, 1] * u[:, 2]])
    s = []
    for _ in range(300):
        y = 1.4e-4 * X7[:, 6] + rng.normal(0, 0.005, 240)
        s.append([np.std(y - X @ np.linalg.lstsq(X, y, rcond=None)[0], ddof=1) for X in (X4, X7)])
    s = np.array(s)
    y6 = delft_fit_44.targets(sig44=[s[:, 0].mean()] * 3, sig45=[s[:, 1].mean()] * 3, coef=[0.0, 0.0])
    C = delft_fit_44.seed_covariance(y6, np.ones(2))
    rho = C[0, 1] / math.sqrt(C[0, 0] * C[1, 1])
    assert abs(np.corrcoef(s.T)[0, 1] - rho) < 0.1
    assert math.sqrt(C[1, 1]) == pytest.approx(np.std(s[:, 1], ddof=1), rel=0.15)   # 300 draws: sd's SE 4 %


def test_the_final_campaign_fit_recovers_known_sizes_from_tables_made_with_them():
    """Six numbers drawn from the model at known (delta, w) with the seed's covariance: the GLS estimate
    recovers them exactly without scatter, and lies within 3 SE of the truth in 20 draws (at most 1 miss of 40)."""
    d = _final_design()
    truth = np.array([2.0, 5.0])
    exact = delft_fit_44._vector(delft_fit_44.model_values(truth, d))
    got = delft_fit_44.fit(exact, d)
    assert [got["sizes"][k]["value"] for k in ("reference_phi_error_arcmin", "setting_error_arcmin")] == \
        pytest.approx(truth, rel=1e-5)
    assert got["chi2"] < 1e-8
    C = delft_fit_44.seed_covariance(exact, d["g"])
    rng = np.random.default_rng(44)
    misses = 0
    for _ in range(20):
        s = delft_fit_44.fit(rng.multivariate_normal(exact, C), d)["sizes"]
        misses += sum(abs(s[k]["value"] - t) > 3 * s[k]["se"]
                      for k, t in zip(("reference_phi_error_arcmin", "setting_error_arcmin"), truth))
    assert misses <= 1   # 40 comparisons at 3 SE: P(> 1 miss) < 0.01


@pytest.mark.slow
def test_the_final_campaign_fit_recovers_sizes_from_simulator_output():
    """Tabs. 4.4-4.5 (x, y and the kept products) of one simulated final campaign at known sizes (own seed),
    fitted with the record's design (other seeds): both sizes within 3 SE."""
    delta, w = 2.0, 5.0
    st = delft_fit_44.simulate(4242, w, delta)
    y = delft_fit_44.targets(st["sigma"][0], st["sigma"][1], st["b"])
    s = delft_fit_44.fit(y, _final_design())["sizes"]
    assert abs(s["reference_phi_error_arcmin"]["value"] - delta) < 3 * s["reference_phi_error_arcmin"]["se"]
    assert abs(s["setting_error_arcmin"]["value"] - w) < 3 * s["setting_error_arcmin"]["se"]


def test_no_sum_of_exponentials_leaks_more_through_a_grounded_slot_than_the_50_khz_share_allows():
    """Jensen: per exponential L / U = l(G / U) with l convex, so any mixture has L / U >= l(G / U); one
    exponential is the equality. 200 random mixtures of 1-4 exponentials, none below the bound."""
    rng = np.random.default_rng(11)
    for _ in range(200):
        k = rng.integers(1, 5)
        lk = delft_fit.slot_leaks(rng.exponential(size=k), rng.uniform(0.01, 0.99, size=k))
        assert lk["L"] / lk["U"] >= delft_fit.fifty_khz_share(lk["G"] / lk["U"]) * (1 - 1e-12)
    one = delft_fit.slot_leaks([1.0], [0.3])
    assert one["L"] / one["U"] == pytest.approx(delft_fit.fifty_khz_share(one["G"] / one["U"]), rel=1e-12)


def test_the_seed_s_grounded_y_asks_a_50_khz_leak_the_seed_does_not_show():
    """On the seed's Tab. 4.3: the grounded share r = 0.61 needs sigma_y(50 kHz) >= 0.0035 (seed 0.00176);
    the 50 kHz y at its 2-SE edge caps the grounded y below the seed's value but inside its 2-SE band."""
    rec = fitted_sizes()
    d, w = rec["design"], rec["sizes"]["setting_error_arcmin"]["value"]
    table, floor_y = np.array(rec["seed_table"]), math.sqrt(d["F"][1] + d["S"][1] * w ** 2)
    b = delft_fit.grounded_slot_bound(table, floor_y)
    assert b["ratio_needed"] == pytest.approx(0.609, abs=0.005)
    assert b["sigma_y_50khz_at_least"] > table[1, 1] * (1 + 2 * delft_fit.REL_SE)
    assert table[3, 1] * (1 - 2 * delft_fit.REL_SE) < b["sigma_y_grounded_at_most"] < table[3, 1]


def test_a_slow_settling_tail_remembers_the_slot_before_a_grounded_slot():
    """u_y <- u_y + alpha y (r - u_y), r = (1 - y) sum y^(k-1) u_(j-k) + y^j u_idle (grounded slots 0 V), checked
    on constant lines (a, b, y) = (1, -2, 3) V with y = 1/2 per 200 kHz slot, to the converter's half LSB."""
    n = 200
    analog = {"a": np.full(n, 1.0), "b": np.full(n, -2.0), "y": np.full(n, 3.0)}
    t = np.arange(n) / 1000.0
    alpha, tau_s = 0.05, 5e-6 / math.log(2)
    kw = dict(mux_frequency_hz=200e3, crosstalk_enabled=False, skew_enabled=False, common_mode_noise_V_rms=0.0,
              input_noise_lsb_rms=0.0, channel_slow_settling={"y": (alpha, tau_s)})
    rng = np.random.default_rng(1)
    plain, _ = DAQ6036E(scan_list=("a", "b", "y"), **kw).convert(analog, t, rng)
    grounded, _ = DAQ6036E(scan_list=("a", "b", "y"), ground_between=True, **kw).convert(analog, t, rng)
    r_plain = 0.5 * (-2.0 + 0.5 * 1.0) + 0.25 * 3.0                 # slots b, a, then the idle y
    r_ground = 0.5 * (0.5 * -2.0 + 0.125 * 1.0) + 0.5 ** 5 * 3.0     # G, b, G, a, G, then the idle y
    q = DAQ6036E(scan_list=("a",)).lsb_V
    assert np.abs(plain["y"][1:] - (3.0 + alpha * 0.5 * (r_plain - 3.0))).max() <= q / 2
    assert np.abs(grounded["y"][1:] - (3.0 + alpha * 0.5 * (r_ground - 3.0))).max() <= q / 2
    assert np.abs(plain["a"] - 1.0).max() <= q / 2    # a channel without a tail is untouched
    with pytest.raises(ConfigError, match="channel_slow_settling names"):
        DAQ6036E(scan_list=("a",), channel_slow_settling={"z": (0.01, 1e-6)}).validate()
