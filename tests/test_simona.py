"""SIMONA gyro table (seed section 4.4.2, appendix B): import, linear calibration, Fig. 4.19."""
from __future__ import annotations

import math

import numpy as np
import pytest

from imurig.calibration.simona import GYROS, SimonaCalibration, measured_rate, read_simona
from imurig.calibration.simona_report import plot_fig_4_19, simona_markdown
from imurig.kernel.errors import RecordingError
from imurig.kernel.recording import Recording
from imurig.kernel.units import DEG


@pytest.fixture(scope="module")
def real():
    return read_simona()


def _synthetic(beta0_dps, beta1_dps_per_V, V, noise_dps=None):
    """Row recording whose stopwatch rounds follow rate = beta0 + beta1*V (+ noise) exactly."""
    n = V.size
    rate_dps = {g: beta0_dps[g] + beta1_dps_per_V[g] * V for g in GYROS}
    # one reference rate per row (the same table rate for all three gyros): invert the p model
    # and derive q, r voltages from the same rate
    ref_dps = rate_dps["p"] if noise_dps is None else rate_dps["p"] + noise_dps
    volts = {g: (rate_dps["p"] - beta0_dps[g]) / beta1_dps_per_V[g] for g in GYROS}
    T = 360.0 / ref_dps
    t = np.arange(n, dtype=float)
    ch = {"rate_dial": ref_dps * DEG, "rate_nominal": ref_dps * DEG, "expected_round": T, "measured_round": T,
          "round_measured": np.ones(n)} | {f"gyro_{g}": volts[g] for g in GYROS}
    units = {"rate_dial": "rad/s", "rate_nominal": "rad/s", "expected_round": "s", "measured_round": "s",
             "round_measured": "1"} | {f"gyro_{g}": "V" for g in GYROS}
    return Recording(time_s=t, channels=ch, units=units,
                     segments={"start_s": t, "stop_s": t + 1, "rate_dial": ch["rate_dial"], "row": np.arange(n)},
                     meta={"row_recording": True}).validate()


def test_import_rows_units_segments(real):
    assert real.n == 25 and real.n_segments == 25
    assert real.units["rate_dial"] == "rad/s" and real.units["gyro_p"] == "V" and real.units["measured_round"] == "s"
    last = real.channels["rate_dial"][-1]
    assert abs(last - 100 * math.pi / 180) <= 1e-15 * last
    assert real.segments["rate_dial"][-1] == last
    assert [s.stop - s.start for s in real.segment_slices()] == [1] * 25
    np.testing.assert_array_equal(real.time_s, np.arange(25.0))
    # first row at rest, round not timed; all others timed
    assert real.channels["round_measured"][0] == 0 and real.channels["round_measured"][1:].all()
    w = measured_rate(real)
    assert w[0] == 0.0
    assert w[-1] == pytest.approx(2 * math.pi / 4.37, rel=1e-15)
    assert real.meta["gyro_nominal_sensitivity_V_per_rad_s"]["q"] == pytest.approx(0.006 / DEG, rel=1e-15)
    assert real.meta["direction"] == "clockwise" and real.meta["notes"]


def test_own_fit_matches_closed_form_and_beats_manufacturer(real):
    fit = SimonaCalibration().fit(real).summary_
    ref_dps = np.where(real.channels["measured_round"] > 0, 360.0 / np.where(real.channels["measured_round"] > 0,
                                                                              real.channels["measured_round"], 1), 0)
    for g in GYROS:
        V = real.channels[f"gyro_{g}"]
        slope, icpt = np.polyfit(V, ref_dps, 1)
        f = fit[g]
        assert f["beta1_dps_per_V"] == pytest.approx(slope, rel=1e-10)
        assert f["beta0_dps"] == pytest.approx(icpt, rel=1e-10, abs=1e-10)
        assert f["scale_mV_per_dps"] == pytest.approx(1000 / slope, rel=1e-10)
        np.testing.assert_allclose(f["residuals_dps"], ref_dps - (icpt + slope * V), atol=1e-10)
        np.testing.assert_allclose(f["manufacturer_residuals_dps"], ref_dps - V / 0.006, atol=1e-10)
        # seed: "Even this rough calibration is way more accurate than ... the manufacturer"
        assert f["manufacturer_max_abs_dps"] >= 10 * f["max_abs_residual_dps"]
    md = simona_markdown(fit)
    assert [ln.split(" | ")[0] for ln in md.splitlines() if ln.startswith("| ")] == ["| gyro", "| P", "| Q", "| R"]
    assert "agrees with" in md


def test_fit_before_range_change(real):
    before = SimonaCalibration(rows=slice(0, -9)).fit(real).summary_
    after = SimonaCalibration(rows=slice(-9, None)).fit(real).summary_
    assert before["p"]["rows"].tolist() == list(range(16))
    assert after["p"]["result"].n == 9
    V = real.channels["gyro_p"][:16]
    ref = measured_rate(real)[:16] / DEG
    assert before["p"]["beta1_dps_per_V"] == pytest.approx(np.polyfit(V, ref, 1)[0], rel=1e-10)
    md = simona_markdown(SimonaCalibration().fit(real).summary_, before)
    assert "(virtual)" in md


def test_synthetic_exact_recovery():
    V = np.linspace(0.002, 0.45, 20)
    b0 = {"p": 0.03, "q": -0.02, "r": 0.05}
    b1 = {"p": 183.0, "q": 184.5, "r": 185.2}
    fit = SimonaCalibration().fit(_synthetic(b0, b1, V)).summary_
    for g in GYROS:
        assert fit[g]["beta0_dps"] == pytest.approx(b0[g], abs=1e-12)
        assert fit[g]["beta1_dps_per_V"] == pytest.approx(b1[g], rel=1e-12)
        assert np.max(np.abs(fit[g]["residuals_dps"])) < 1e-11


def test_synthetic_noise_within_four_standard_errors():
    rng = np.random.default_rng(20240611)
    V = np.linspace(0.002, 0.45, 40)
    b0 = {"p": 0.1, "q": 0.1, "r": 0.1}
    b1 = {"p": 180.0, "q": 180.0, "r": 180.0}
    sigma = 0.05
    fit = SimonaCalibration().fit(_synthetic(b0, b1, V, noise_dps=rng.normal(0.0, sigma, V.size))).summary_
    for g in GYROS:
        f = fit[g]
        assert abs(f["beta0_dps"] - b0[g]) < 4 * f["beta0_se_dps"]
        assert abs(f["beta1_dps_per_V"] - b1[g]) < 4 * f["beta1_se_dps_per_V"]
        assert 0.5 * sigma < f["sigma_res_dps"] < 1.5 * sigma


HEADER = "rate_dial_dps,rate_nominal_dps,expected_round_s,measured_round_s,p_V,q_V,r_V"


def test_malformed_csv(tmp_path):
    p = tmp_path / "no_p.csv"
    p.write_text("# comment\nrate_dial_dps,rate_nominal_dps,expected_round_s,measured_round_s,q_V,r_V\n"
                 "0,0,0,0,0,0\n1,0.83,432,453.7,0.0043,0.0044\n")
    with pytest.raises(RecordingError, match="p_V"):
        read_simona(p)
    p = tmp_path / "text.csv"
    p.write_text(f"{HEADER}\n0,0,0,0,0,0,0\n1,0.83,432,453.7,0.0043,abc,0.0044\n")
    with pytest.raises(RecordingError, match=r"'abc'.*q_V"):
        read_simona(p)
    with pytest.raises(RecordingError, match="does not exist"):
        read_simona(tmp_path / "missing.csv")


def test_plot_real_and_virtual(real, tmp_path):
    a = plot_fig_4_19(tmp_path / "fig_4_19.png", real)
    b = plot_fig_4_19(tmp_path / "fig_4_19_twin.png", real, virtual=real, gyro="r")
    for path in (a, b):
        data = path.read_bytes()
        assert len(data) > 10_000 and data[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(x.name for x in tmp_path.iterdir()) == ["fig_4_19.png", "fig_4_19_twin.png"]
