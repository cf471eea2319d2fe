"""The Delft 2005 preset on the turn table: its fit to Figs. 4.20-4.21, its effects, and the items on it."""
from __future__ import annotations

import math

import numpy as np
import pytest

from imurig.campaigns.delft_2005_turn import Delft2005Turn, fitted_turn_sizes
from imurig.montecarlo import delft_fit_turn as F
from imurig.sensors.chain import ImuLab
from imurig.sensors.effects import GyroScaleInstability


def test_fit_recovers_known_sizes_within_their_standard_errors():
    """Envelopes of the model at known sizes, each perturbed by its own standard error (fixed draws), are
    fitted back: every fitted size lies within 3 SE of the known one (on the squared sizes, where the fit is)."""
    st = F.structure()
    known = np.array([1.0e-4, 1.5e-4, F.FIXED["slip_density_V_rtHz"]])
    model, scatter = F.envelopes(known, st, n_draws=200)
    _, reading = F.seed_values()
    se = np.sqrt(reading**2 + scatter**2)
    target = model + se * np.random.default_rng(7).standard_normal(model.size)
    rec = F.fit(target, reading, st, n_draws=200)
    for k, name in enumerate(F.FREE):
        s = rec["sizes"][name]
        assert abs(s["square"] - known[k] ** 2) <= 3 * s["square_se"], (name, s, known[k])
    # the figures' envelopes grow with each size: the fit can tell a larger scale-factor wander
    bigger = F.envelopes(known * [2, 1, 1], st, n_draws=200)[0]
    assert np.all(bigger[[0, 1, 2]] > model[[0, 1, 2]])


def test_window_variance_of_the_scale_factor_wander_matches_its_simulation():
    """var(mean s over T) of the Gauss-Markov wander: closed form against 400 simulated windows (its SE
    from the chi^2 of 399 degrees of freedom)."""
    eff = GyroScaleInstability(enabled=True, sigma=2e-4, tau_s=10.0)
    fs, T, n = 50.0, 7.0, 400
    rng = np.random.default_rng(3)
    means = np.array([eff.wander(int(T * fs), fs, rng).mean() for _ in range(n)])
    want = float(eff.window_variance(T))
    assert abs(means.var(ddof=1) - want) <= 3 * want * math.sqrt(2 / (n - 1))
    v = np.ones(10)
    assert np.array_equal(GyroScaleInstability(enabled=False, sigma=1e-3).inject(v, None, rng), v)


def test_preset_sizes_are_fitted_and_within_their_physical_bounds():
    rec = fitted_turn_sizes()
    for name in F.FREE:
        s, b = rec["sizes"][name], rec["bounds"][name]
        assert s["fitted"] and s["se"] is not None and s["se"] > 0
        assert b["lower"] <= s["value"] <= b["upper"] * (1 + 1e-9), name
    pre = Delft2005Turn.fitted()
    lab = pre.apply(ImuLab(), 1000.0)
    assert {t.name: t.jitter_s for t in lab.timers}["gps_mark"] == pytest.approx(pre.gps_jitter_s)
    (sf,) = [e for e in lab.effects if e.name == GyroScaleInstability.name]
    assert sf.sigma == pytest.approx(pre.sf_sigma) and sf.lines(["gyro_p", "acc_x"]) == ["gyro_p"]
    # the slip rings are a density: the per-sample rms scales with sqrt(f_s)
    assert pre.slip_rings(400.0).rms_V == pytest.approx(pre.slip_rings(100.0).rms_V * 2)
    assert len(pre.describe()) == 7 and all(r["seed_says"] for r in pre.describe())
    # the table's ripple (Table B.1's fit) is the campaign's table physics on the preset, not on the quiet lab
    from imurig.campaigns.turn_table import TurnTableCampaign
    from imurig.rigs.turn_table import TurnTableErrors

    assert TurnTableCampaign(lab="delft-2005").build()[0].errors.ripple == pre.table_ripple != TurnTableErrors.ripple
    assert TurnTableCampaign().build()[0].errors.ripple == TurnTableErrors.ripple


def test_the_step_windows_are_whole_rounds_of_at_least_the_minimum():
    for mount, w, T in F.steps(F.FINAL_PROTOCOL):
        T_round = 360.0 / abs(w)
        n = round(T / T_round)
        assert abs(T - n * T_round) < 1e-9 and (T >= F.FINAL_PROTOCOL.min_window_s or n == 1)
        assert n == 1 or (n - 1) * T_round < F.FINAL_PROTOCOL.min_window_s


def test_turn_table_campaign_refuses_an_unknown_lab():
    from imurig.campaigns.turn_table import TurnTableCampaign
    from imurig.kernel.errors import ConfigError

    with pytest.raises(ConfigError, match="delft-2005"):
        TurnTableCampaign(lab="basement").build()


@pytest.mark.slow
def test_the_model_predicts_the_simulated_timer_study():
    """One preset timer study (the simulator) against the fit's model: each timer's envelope within 3
    scatters of the model's expectation."""
    from imurig.campaigns.turn_table import timer_study

    ts = timer_study(seed=11, lab="delft-2005")["timers"]
    rec = fitted_turn_sizes()
    for k, (_, timer, _, _) in enumerate(F.SEED[:3]):
        assert abs(ts[timer]["envelope_dps"] - rec["model"][k]) <= 3 * rec["scatter"][k], timer


def test_gls_covariance_holds_the_scale_factor_wander():
    """segment_covariance's wander term on one window equals Omega^2 var(mean s over T) (the effect's own
    closed form); across blocks (remounts) the windows are independent."""
    from imurig.calibration.gyro import segment_covariance
    from imurig.kernel.recording import Recording

    t = np.arange(0.0, 100.0, 0.1)
    rec = Recording(time_s=t, channels={"x": np.zeros_like(t)}, units={"x": "V"},
                    segments={"start_s": np.array([5.0, 40.0]), "stop_s": np.array([25.0, 52.0])},
                    segment_units={"start_s": "s", "stop_s": "s"}, meta={}).validate()
    w = np.array([1.0, -2.0])
    eff = GyroScaleInstability(enabled=True, sigma=3e-4, tau_s=10.0)
    cov = segment_covariance(rec, w, {"scale_instability": eff.sigma, "scale_instability_tau_s": eff.tau_s}, 0.0)
    np.testing.assert_allclose(np.diag(cov), w**2 * eff.window_variance(np.array([20.0, 12.0])), rtol=1e-12)
    assert cov[0, 1] < 0                                    # opposite rates, a shared positive wander
    assert np.array_equal(segment_covariance(rec, w, {}, 0.0), np.zeros((2, 2)))
