"""Truth-based tests of the tilt-table campaign: rig physics, sensor chain, calibration."""
from __future__ import annotations

import math
import os

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import small_campaign
from imurig.calibration.preprocess import lowpass_downsample, segment_statistic
from imurig.campaigns.tilt_table import Z_BOUND, calibrate, compare_with_truth
from imurig.kernel.errors import ScheduleError, UnidentifiableTermsError
from imurig.rigs.tilt_table import (TableSurvey, TiltTable, TiltTableErrors, TiltTableProtocol, rotate_to_body,
                                    specific_force_C)
from imurig.kernel.site import EARTH_RATE_RAD_S, Site
from imurig.kernel.units import ARCSEC

G = 9.81242231


# ------------------------------------------------------------------ physics
def test_mujoco_static_truth_matches_closed_form():
    """At rest, MuJoCo's site accelerometer equals seed eq. 4.36-4.38 (with the table errors)
    and the gyro sees exactly the Earth's rate, to near machine precision."""
    proto = TiltTableProtocol(theta_deg=(0, 35, 90), phi_deg=(0, 120, 250), runs=("z_down", "z_up"), dwell_s=0.5,
                              settle_s=2.0, slew_rate_deg_s=30)
    errors = TiltTableErrors(setting_resolution_rad=0.0)
    table = TiltTable(errors=errors, survey=TableSurvey(), site=Site(), dwell_truth="mujoco")
    rec = table.simulate(proto, "2005-06-14T18:00:00+02:00", np.random.default_rng(0))
    f = np.stack([rec.truth_signals[f"f_C_{a}"] for a in "xyz"], 1)
    w = np.stack([rec.truth_signals[f"w_C_{a}"] for a in "xyz"], 1)
    seg = rec.segments
    for i, s in enumerate(rec.segment_slices()):
        m = str(seg["mount"][i])
        expect = specific_force_C(seg["theta"][i:i + 1], seg["phi"][i:i + 1], m, G, errors.theta_zero_rad,
                                  errors.phi_zero_rad[m], errors.level_x_rad)[0]
        np.testing.assert_allclose(f[s], np.broadcast_to(expect, f[s].shape), rtol=0, atol=1e-11 * G)
        # residual servo motion after settling is below 1e-12 rad/s (Earth rate is 7.3e-5 rad/s)
        np.testing.assert_allclose(np.linalg.norm(w[s], axis=1), EARTH_RATE_RAD_S, rtol=0, atol=1e-12)


def test_stitched_truth_equals_full_mujoco_run():
    """MuJoCo for the moves and the closed form at rest (the default) give the truth of a MuJoCo run
    that steps every sample: specific force to 1e-11 g, rates to 1e-12 rad/s, field to 1e-11 of
    its size, joint angles to 1e-11 rad; the set-points, segments and times are identical."""
    proto = TiltTableProtocol(theta_deg=(0, 40, 90), phi_deg=(0, 90, 300), dwell_s=0.5, slew_rate_deg_s=30)
    recs = [TiltTable(errors=TiltTableErrors(), site=Site(), dwell_truth=m, move_step_s=None).simulate(
        proto, "2005-06-14T18:00:00+02:00", np.random.default_rng(3)) for m in ("mujoco", "closed_form")]
    full, fast = recs
    np.testing.assert_array_equal(full.time_s, fast.time_s)
    assert list(full.truth_signals) == list(fast.truth_signals)
    B = np.linalg.norm([full.truth_signals[f"B_C_{a}"][0] for a in "xyz"])
    for k, tol in (("f_C", 1e-11 * G), ("w_C", 1e-12), ("B_C", 1e-11 * B), ("theta_true", 1e-11),
                   ("phi_true", 1e-11)):
        for name in [n for n in full.truth_signals if n.startswith(k)]:
            np.testing.assert_allclose(fast.truth_signals[name], full.truth_signals[name], rtol=0, atol=tol,
                                       err_msg=name)
    for name in full.channels:
        np.testing.assert_array_equal(fast.channels[name], full.channels[name])
    assert fast.truth == full.truth


def test_coarse_move_steps_keep_the_windows_and_the_moves_within_half_an_adc_step():
    """MuJoCo at 10 ms in the moves (the default; 1 ms for the servo's transients at each move's start
    and slew's end, linear in between) leaves the windows' truth bit for bit and keeps f_C within half
    the accelerometer channel's ADC step (q / sensitivity = 1.5e-3 m/s^2) and the angles within the
    table survey's 2 arcsec of a run stepped at every sample, with setting errors (the command's steps) on."""
    proto = TiltTableProtocol(theta_deg=(0, 40, 90), phi_deg=(0, 90, 300), dwell_s=0.5)
    recs = [TiltTable(errors=TiltTableErrors.draw(np.random.default_rng(1)), site=Site(), move_step_s=h).simulate(
        proto, "2005-06-14T18:00:00+02:00", np.random.default_rng(3)) for h in (None, 0.01)]
    fine, coarse = recs
    win = np.zeros(fine.n, bool)
    for s in fine.segment_slices():
        win[s] = True
    lsb_m_s2 = 10.0 / 2**16 / (1.33e-3 / 9.80665 * 750.0)
    for name, x in fine.truth_signals.items():
        np.testing.assert_array_equal(coarse.truth_signals[name][win], x[win], err_msg=name)
        # in the moves: f_C within half an ADC step, the angles within 2 arcsec (other signals: windows only)
        tol = lsb_m_s2 / 2 if name.startswith("f_C") else 2 * ARCSEC if name.endswith("_true") else None
        if tol is not None:
            np.testing.assert_allclose(coarse.truth_signals[name], x, rtol=0, atol=tol, err_msg=name)
    assert np.abs(coarse.truth_signals["f_C_x"] - fine.truth_signals["f_C_x"]).max() > 0  # the moves did differ


def test_perfect_table_reproduces_seed_equations():
    """specific_force_C on a perfect table, z_up mount, is g(-cos phi sin theta, sin phi sin theta, cos theta)."""
    th = np.radians([0, 10, 40, 90, 90])
    ph = np.radians([0, 30, 300, 90, 200])
    f = specific_force_C(th, ph, "z_up", G)
    expect = G * np.stack([-np.cos(ph) * np.sin(th), np.sin(ph) * np.sin(th), np.cos(th)], 1)
    np.testing.assert_allclose(f, expect, rtol=0, atol=4 * np.finfo(float).eps * G)
    f_down = specific_force_C(th, ph, "z_down", G)
    np.testing.assert_allclose(f_down, expect * [1, -1, -1], rtol=0, atol=4 * np.finfo(float).eps * G)


@settings(max_examples=50, deadline=None)
@given(st.floats(-1.6, 1.6), st.floats(-7, 7), st.floats(-1e-3, 1e-3), st.floats(-0.05, 0.05),
       st.sampled_from(["z_up", "z_down"]))
def test_specific_force_norm_is_gravity(theta, phi, lev, pz, mount):
    f = specific_force_C(np.array([theta]), np.array([phi]), mount, G, theta_zero=lev, phi_zero=pz, level_x=lev)
    assert abs(np.linalg.norm(f) - G) <= 8 * np.finfo(float).eps * G


def test_rotate_to_body_matches_mujoco():
    import mujoco

    rng = np.random.default_rng(3)
    q = rng.normal(size=(20, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    v = rng.normal(size=3)
    got = rotate_to_body(q, v)
    for k in range(20):
        R = np.zeros(9)
        mujoco.mju_quat2Mat(R, q[k])
        np.testing.assert_allclose(got[k], R.reshape(3, 3).T @ v, rtol=0, atol=1e-15)


# --------------------------------------------------------------- determinism
def test_same_seed_same_data_bit_for_bit():
    a = small_campaign(seed=5, protocol=TiltTableProtocol(theta_deg=(0, 90), phi_deg=(0, 180), dwell_s=1)).simulate()
    b = small_campaign(seed=5, protocol=TiltTableProtocol(theta_deg=(0, 90), phi_deg=(0, 180), dwell_s=1)).simulate()
    c = small_campaign(seed=6, protocol=TiltTableProtocol(theta_deg=(0, 90), phi_deg=(0, 180), dwell_s=1)).simulate()
    for k in a.channels:
        assert np.array_equal(a.channels[k], b.channels[k]), k
    assert not np.array_equal(a.channels["acc_x"], c.channels["acc_x"])


def test_switching_one_effect_leaves_other_stages_unchanged():
    """Stages draw from generators keyed by name: a loose cable on acc_y does not change acc_x."""
    p = TiltTableProtocol(theta_deg=(0, 90), phi_deg=(0, 180), dwell_s=1)
    a = small_campaign(seed=5, protocol=p).simulate()
    b = small_campaign(seed=5, protocol=p, loose_cable=True).simulate()
    assert np.array_equal(a.channels["acc_z"], b.channels["acc_z"])
    assert not np.array_equal(a.channels["acc_y"], b.channels["acc_y"])


# ----------------------------------------------------------- truth recovery
@pytest.fixture(scope="module")
def truth_runs(small_records):
    out = []
    for seed in (1, 2, 3, 4, 5):
        rec = small_records.get(seed)
        out.append(compare_with_truth(calibrate(rec), rec.truth))
    return out


def test_every_injected_error_recovered_within_bound(truth_runs):
    for params in truth_runs:
        assert len(params) == 15
        for p in params:
            assert p["injected"] is not None
            assert abs(p["z"]) <= Z_BOUND, p


def test_standard_errors_are_honest_not_inflated(truth_runs):
    """The z-scores over 5 seeds x 15 parameters must look standard normal: an inflated
    standard error (which would make the bound above trivial) drives their RMS towards 0.
    75 values: the RMS of N(0,1) lies in [0.75, 1.25] with probability > 0.99."""
    z = np.array([p["z"] for params in truth_runs for p in params])
    rms = math.sqrt(np.mean(z**2))
    assert 0.75 <= rms <= 1.25, rms


def test_standard_errors_resolve_datasheet_sized_errors(truth_runs):
    """The estimator must resolve errors far below the datasheet limits (2 mrad, 8 mg)."""
    for params in truth_runs:
        se = {p["name"]: p["std_error"] for p in params}
        assert max(v for k, v in se.items() if k.startswith("misalignment")) < 2e-3 / 50
        assert max(v for k, v in se.items() if k.startswith("bias")) < 8e-3 * 9.81 / 100


def test_apply_calibration_to_recording(small_recording):
    """Calibrated per-position medians equal the reference to within the fit's residual sigma."""
    from imurig.campaigns.tilt_table import tilt_table_reference

    rec100 = lowpass_downsample(small_recording)
    cal = calibrate(small_recording, processed=rec100)
    out = cal.apply(rec100)
    med = segment_statistic(out, ["acc_cal_x", "acc_cal_y", "acc_cal_z"])
    ref, _, _ = tilt_table_reference(rec100)
    for j, a in enumerate("xyz"):
        err = med[:, j] - ref[:, j]
        assert np.sqrt(np.mean(err**2)) < 1.5 * cal.results_[a].sigma_res
    # and the linear part actually corrects: uncalibrated volts/nominal differ by ~1e-2 m/s^2 or more
    s = np.asarray(small_recording.meta["acc_nominal_sensitivity_V_per_m_s2"])
    raw = segment_statistic(rec100, ["acc_x", "acc_y", "acc_z"]) / s
    assert np.sqrt(np.mean((raw - ref) ** 2)) > 50 * max(cal.results_[a].sigma_res for a in "xyz")


# ---------------------------------------------------------- seed experiments
def test_pump_vibration_medians_cut_residual_several_fold():
    """Seed Table 4.2: with the basement pump running (working hours), calibrating on
    per-position medians instead of the raw 100 Hz samples cuts sigma_res several-fold."""
    rec = small_campaign(seed=7, start_time="2005-06-14T10:00:00+02:00").simulate()
    assert np.any(rec.truth_signals.get("f_dist_C_x", np.zeros(1)))
    rec100 = lowpass_downsample(rec)
    raw = calibrate(rec, model="linear", statistic="raw", processed=rec100)
    med = calibrate(rec, model="linear", statistic="median", processed=rec100)
    for a in "xyz":
        assert raw.results_[a].sigma_res > 5 * med.results_[a].sigma_res, a


def test_crosstalk_grows_with_multiplexing_frequency():
    """Seed Table 4.3: acc_y is scanned right after mag_x; at 200 kHz the multiplexer has
    not settled and the neighbour's (unmodelled) signal leaks in, so sigma_y at 200 kHz is
    clearly above sigma_y at 50 kHz, while acc_x (after a constant channel) is unchanged."""
    proto = TiltTableProtocol(theta_deg=(10, 50, 90), phi_deg=tuple(range(0, 360, 30)), runs=("z_up", "z_down"),
                              dwell_s=3.0, settle_s=1.0, slew_rate_deg_s=30)
    sig = {}
    for f in (200e3, 50e3):
        rec = small_campaign(seed=3, protocol=proto, mux_frequency_hz=f).simulate()
        cal = calibrate(rec, model="linear")
        sig[f] = {a: cal.results_[a].sigma_res for a in "xyz"}
    assert sig[200e3]["y"] > 3 * sig[50e3]["y"], sig
    assert sig[200e3]["x"] < 1.3 * sig[50e3]["x"], sig


def test_single_tilt_angle_is_refused_naming_terms():
    camp = small_campaign(protocol=TiltTableProtocol(theta_deg=(40,), phi_deg=tuple(range(0, 360, 30))))
    with pytest.raises(UnidentifiableTermsError) as e:
        camp.simulate()
    assert set(e.value.terms) == {"1", "az^2"}
    assert "az^2" in str(e.value) and "A_z" in str(e.value)


def test_single_run_single_angle_names_bias_and_z_term():
    camp = small_campaign(model="linear", protocol=TiltTableProtocol(theta_deg=(40,), runs=("z_up",)))
    with pytest.raises(UnidentifiableTermsError) as e:
        camp.check_identifiable()
    assert set(e.value.terms) == {"1", "az"}


@pytest.mark.parametrize("kw, msg", [
    (dict(theta_deg=()), "at least one theta"),
    (dict(dwell_s=-1), "dwell_s must be positive"),
    (dict(theta_deg=(0, 120)), r"within \+-95"),
    (dict(runs=("sideways",)), "unknown mounting"),
    (dict(dwell_s=0.005), "fewer than 10 samples"),
])
def test_impossible_schedules_are_refused(kw, msg):
    with pytest.raises(ScheduleError, match=msg):
        TiltTableProtocol(**kw).validate()


def test_multiplexer_too_slow_for_sample_rate_is_refused():
    from imurig.kernel.errors import ConfigError

    camp = small_campaign(mux_frequency_hz=5e3)  # 10 channels at 5 kHz take 2 ms > 1 ms
    with pytest.raises(ConfigError, match="longer than one sample period"):
        camp.simulate()


# ------------------------------------------------------------------ reference error model
def test_setting_error_covariance_matches_closed_form():
    """A perfect z_up table: f = g (-cos phi sin theta, sin phi sin theta, cos theta), so
    Sigma_k = res^2/12 (J_theta J_theta' + J_phi J_phi') with the analytic derivatives."""
    from imurig.rigs.tilt_table import setting_error_covariance

    theta, phi = np.meshgrid(np.radians(np.arange(0, 181, 15.0)), np.radians(np.arange(0, 360, 30.0)))
    theta, phi = theta.ravel(), phi.ravel()
    segs = {"theta": theta, "phi": phi, "mount": np.array(["z_up"] * theta.size)}
    res = 0.25 * math.pi / 180 / 60
    S = setting_error_covariance(segs, G, TableSurvey(setting_resolution_rad=res))
    Jt = G * np.stack([-np.cos(phi) * np.cos(theta), np.sin(phi) * np.cos(theta), -np.sin(theta)], axis=1)
    Jp = G * np.stack([np.sin(phi) * np.sin(theta), np.cos(phi) * np.sin(theta), np.zeros_like(theta)], axis=1)
    expected = res**2 / 12 * (Jt[:, :, None] * Jt[:, None, :] + Jp[:, :, None] * Jp[:, None, :])
    np.testing.assert_allclose(S, expected, rtol=0, atol=1e-8 * np.max(expected))
    assert not np.any(setting_error_covariance(segs, G, TableSurvey()))  # no resolution given: no term


def test_noise_free_triad_recovers_forward_parameters():
    """Exact data u = G (q + b + k2 q^2), q = (I + M) f: the physical parameters come back to
    the truncation of the inverse model (second order in k2, k2 M cross terms), far below
    2 k2 b, the scale-factor error of converting the linear coefficient without the bias."""
    from imurig.calibration.accelerometer import AccelerometerCalibration
    from imurig.kernel.recording import Recording

    theta, phi = np.meshgrid(np.radians(np.arange(0, 181, 10.0)), np.radians(np.arange(0, 360, 20.0)))
    f1 = specific_force_C(theta.ravel(), phi.ravel(), "z_up", G)
    f = np.concatenate([f1, f1 * [1, -1, -1]])  # both mountings
    s = np.array([0.1017, 0.0987, 0.1003])      # V/(m/s^2)
    b = np.array([0.06, -0.05, 0.04])           # m/s^2
    k2 = np.array([5e-6, -4e-6, 3e-6])          # 1/(m/s^2)
    M = np.array([[0, 4e-4, -3e-4], [2e-4, 0, 5e-4], [-1e-4, 3e-4, 0]])
    q = f + f @ M.T
    v = s * (q + b + k2 * q**2)
    n = f.shape[0]
    rec = Recording(time_s=np.arange(n, dtype=float), channels={f"acc_{a}": v[:, i] for i, a in enumerate("xyz")},
                    units={f"acc_{a}": "V" for a in "xyz"},
                    segments={"start_s": np.arange(n) - 0.25, "stop_s": np.arange(n) + 0.25},
                    meta={"acc_nominal_sensitivity_V_per_m_s2": [0.1, 0.1, 0.1]})
    cal = AccelerometerCalibration(model="physical").fit(rec, f)
    est = {p["name"]: p["estimate"] for p in cal.physical_parameters()}
    cross = np.max(np.abs(M)) * np.max(np.abs(k2)) * G**2  # the k2_j M_ij u_j^2 terms the model leaves out
    for i, a in enumerate("xyz"):
        assert abs(est[f"sensitivity_{a}"] / s[i] - 1) < 0.02 * abs(2 * k2[i] * b[i]), a
        assert abs(est[f"bias_{a}"] - b[i]) < cross, a
        assert abs(est[f"nonlinearity_{a}"] / k2[i] - 1) < 2e-3, a
    for i, j in [(0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1)]:
        assert abs(est[f"misalignment_{'xyz'[i]}{'xyz'[j]}"] - M[i, j]) < 1e-8


def test_lowpass_in_windows_only_equals_whole_record(small_recording):
    """Filtering only the padded acquisition windows gives the whole-record filter's values there
    (the Butterworth's transient decays by e^-100 over the 1 s pad, far below one ADC step, 1.5e-4 V),
    the same decimated time grid, and the raw samples elsewhere."""
    keep = ("theta", "phi", "acc_x", "acc_z", "temp_box")
    rec = small_recording.replace(channels={k: small_recording.channels[k] for k in keep},
                                  truth_signals={k: small_recording.truth_signals[k] for k in ("f_C_x", "theta_true")})
    full, win = lowpass_downsample(rec), lowpass_downsample(rec, windows_only=True)
    np.testing.assert_array_equal(win.time_s, full.time_s)
    inside = np.zeros(win.n, bool)
    for s in win.segment_slices():
        inside[s] = True
    lsb = rec.meta["adc"]["lsb_V"]
    for name in rec.channels:
        np.testing.assert_allclose(win.channels[name][inside], full.channels[name][inside], rtol=0,
                                   atol=1e-9 * lsb, err_msg=name)
    for name in rec.truth_signals:
        scale = np.max(np.abs(full.truth_signals[name])) or 1.0
        np.testing.assert_allclose(win.truth_signals[name][inside], full.truth_signals[name][inside], rtol=0,
                                   atol=1e-12 * scale, err_msg=name)
    idx = np.searchsorted(rec.time_s, win.time_s[~inside])
    np.testing.assert_array_equal(win.channels["acc_x"][~inside], rec.channels["acc_x"][idx])
    np.testing.assert_allclose(segment_statistic(win, ["acc_x", "acc_z"]), segment_statistic(full, ["acc_x", "acc_z"]),
                               rtol=0, atol=1e-9 * lsb)


def _never(out, rec100, fits, early):
    os._exit(3)   # the work ran: the child would end with code 3


def test_figure_process_ends_without_drawing_when_the_fits_fail():
    """The report's figure and .rrd processes are forked before the fits (they load matplotlib and rerun
    meanwhile); when the fits fail they get no fits (a closed pipe) and end cleanly, doing no work, although
    the second was forked holding a copy of the first one's pipe end."""
    from imurig.reports.beside import Beside

    f = Beside(None, None, lambda out, rec100: None, _never, "drawing the figures")
    r = Beside(None, None, lambda out, rec100: None, _never, "writing campaign.rrd")
    f.cancel()
    r.cancel()
    for b in (f, r):
        assert b.child is None or (not b.child.is_alive() and b.child.exitcode == 0)


def _open_rrd_early(out, rec100):
    from imurig.reports.viz import RrdWriter

    return RrdWriter(out / "campaign.rrd", blueprint=None)


def test_rrd_opened_before_the_fits_leaves_no_file_when_they_fail(tmp_path):
    """The .rrd's process opens its writer and logs the record while the parent fits; cancelled (the fits
    failed), it aborts the writer: neither the .rrd nor its temporary file is left."""
    from imurig.reports.beside import Beside

    r = Beside(tmp_path, None, _open_rrd_early, _never, "writing campaign.rrd")
    child = r.child   # None where fork is missing: nothing is opened before the fits there
    r.cancel()
    assert child is None or (not child.is_alive() and child.exitcode == 0)
    assert list(tmp_path.iterdir()) == []