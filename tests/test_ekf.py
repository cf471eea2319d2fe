"""The loosely coupled EKF against truth: consistency (NEES, NIS) over repeated runs, GPS outage
growth and recovery, bias estimation, refusals. Data are drawn from exactly the filter's error
model (``synthetic.synthetic_sensors``) along closed-form S-turns (``ins.s_turn_truth``)."""
import math

import numpy as np
import pytest
from imurig.flights import earth as E
from imurig.flights import ekf, ins
from imurig.flights.synthetic import synthetic_sensors
from scipy.stats import chi2

from imurig.kernel.errors import ConfigError, RecordingError
from imurig.kernel.navdata import GpsFixes, ImuStream

D = math.pi / 180
RUNS = 8
DUR = 200.0
OUTAGE = (90.0, 130.0)
LEVER = np.array([1.5, 0.0, -2.0])


@pytest.fixture(scope="module")
def truth():
    return ins.s_turn_truth(DUR, 100.0, yaw_amp_rad=60 * D, yaw_period_s=80.0, pitch_amp_rad=3 * D,
                            pitch_period_s=30.0, climb_amp_m_s=3.0)


def _run(truth, seed, noise_filter=None, outages=(OUTAGE,), compiled=True):
    noise = ekf.ImuNoise(vrw=5e-4)
    rng = np.random.default_rng(np.random.SeedSequence([6, seed]))
    imu, gps, tb = synthetic_sensors(truth, noise, rng, lever_gps_B=LEVER, mag_sigma_rad=1 * D,
                                         outages=outages)
    cfg = ekf.FilterConfig(nav_rate_hz=20.0, mag_heading_sigma_rad=1 * D, sigma0_heading_rad=5 * D,
                           sigma0_acc_bias_m_s2=0.05, sigma0_gyro_bias_rad_s=0.003 * D)
    f = ekf.LooseEKF(cfg, noise_filter or noise, lever_gps_B=LEVER, compiled=compiled)
    # initial state drawn from the filter's own prior (what NEES assumes)
    s0 = np.sqrt(np.diag(f.initial_covariance()))
    dx = rng.standard_normal(18) * s0
    x0 = ins.state_at(truth, 0)
    x0.lat_rad, x0.lon_rad, x0.h_m = (float(a) for a in E.geodetic_from_ned(dx[:3], x0.lat_rad, x0.lon_rad, x0.h_m))
    x0.v_N = x0.v_N + dx[3:6]
    x0.q_NB = E.q_mult(E.q_from_rotvec(-dx[6:9]), x0.q_NB)
    res = f.fit(imu, gps, x0).solution_
    idx = np.arange(res.time_s.size) * res.meta["samples_per_step"]
    return res, idx, tb


@pytest.fixture(scope="module")
def runs(truth):
    return [_run(truth, s) for s in range(RUNS)]


def test_nees_and_nis_inside_chi_square_bounds(truth, runs):
    """N·mean NEES ~ χ²(9N) at each epoch; 99 % two-sided bounds; a consistent filter has 1 % of
    epochs outside: we require at most 10 % (epochs 1 s apart are correlated). The NIS of all GPS
    and heading updates of all runs sums to χ²(Σ dof) (innovations of a consistent filter are
    white), checked against its 99.9 % two-sided interval."""
    every = 20
    nees = np.array([ekf.nees_nav(r, truth, idx)[::every] for r, idx, _ in runs])
    lo, hi = chi2.ppf([0.005, 0.995], 9 * RUNS) / RUNS
    m = nees.mean(axis=0)
    inside = np.mean((m >= lo) & (m <= hi))
    assert inside >= 0.9, (inside, m.min(), m.max(), lo, hi)
    for kind in ("gps_pos", "gps_vel", "mag"):
        s = sum(r.updates[kind]["nis"].sum() for r, _, _ in runs)
        dof = sum(r.updates[kind]["dof"].sum() for r, _, _ in runs)
        a, b = chi2.ppf([0.0005, 0.9995], dof)
        assert a < s < b, (kind, s / dof, a / dof, b / dof)


def _assert_same_to_rounding(res_c, res_p):
    """Two runs of the filter on the same data, compiled and plain Python (``LooseEKF(compiled=...)``):
    the same arithmetic, only the n x n products summed in another order, so the two differ by rounding
    (~1e-16 relative per operation, ~1e4 epochs and updates): every navigation error state within
    1e-9 of its own σ, every variance within 1e-9 relative. A wrong entry of F or Φ, a missed epoch of
    the record or a wrong span boundary is orders of magnitude larger."""
    sigma = np.sqrt(res_p.P_diag)
    R_N, R_E = E.radii(res_p.lat_rad)           # the differences in metres (NED), not via ECEF (1e-9 m rounding)
    d_pos = np.stack([(res_c.lat_rad - res_p.lat_rad) * (R_N + res_p.h_m),
                      (res_c.lon_rad - res_p.lon_rad) * (R_E + res_p.h_m) * np.cos(res_p.lat_rad),
                      res_p.h_m - res_c.h_m], axis=1)
    assert np.all(np.abs(d_pos) <= 1e-9 * sigma[:, :3])
    assert np.all(np.abs(res_c.v_N - res_p.v_N) <= 1e-9 * sigma[:, 3:6])
    dq = E.q_mult(res_p.q_NB, E.q_conj(res_c.q_NB))
    assert np.all(np.abs(E.rotvec_from_q(dq)) <= 1e-9 * sigma[:, 6:9])
    assert np.all(np.abs(res_c.acc_bias_m_s2 - res_p.acc_bias_m_s2) <= 1e-9 * sigma[:, 9:12])
    assert np.all(np.abs(res_c.gyro_bias_rad_s - res_p.gyro_bias_rad_s) <= 1e-9 * sigma[:, 12:15])
    assert np.all(np.abs(res_c.P_diag - res_p.P_diag) <= 1e-9 * res_p.P_diag)
    np.testing.assert_array_equal(res_c.time_s, res_p.time_s)
    for kind in res_p.updates:
        np.testing.assert_allclose(res_c.updates[kind]["nis"], res_p.updates[kind]["nis"], rtol=1e-7, atol=1e-12)


def test_compiled_propagation_is_the_python_path(truth, runs):
    """The 18-state filter's compiled span propagation (``ekf_kernel``) against the plain Python path on
    the same data (S-turns, a 40 s GPS outage), to rounding (:func:`_assert_same_to_rounding`)."""
    _assert_same_to_rounding(runs[0][0], _run(truth, 0, compiled=False)[0])


def test_compiled_propagation_with_the_receivers_error_states(truth):
    """The same with the receiver's Gauss-Markov position error as three more states (21): their
    decay between updates, their process noise following the fixes' σ and their reset after the
    outage."""
    noise = ekf.ImuNoise(vrw=5e-4)
    imu, gps, _ = synthetic_sensors(truth, noise, np.random.default_rng(3), lever_gps_B=LEVER, mag_sigma_rad=1 * D,
                                    outages=(OUTAGE,))
    cfg = ekf.FilterConfig(nav_rate_hz=20.0, mag_heading_sigma_rad=1 * D, gps_pos_states=True, gps_pos_tau_s=100.0,
                           gps_pos_sigma_white_N_m=(0.1, 0.1, 0.2))
    assert cfg.n_states == 21
    res = [ekf.LooseEKF(cfg, noise, lever_gps_B=LEVER, compiled=c).fit(imu, gps, ins.state_at(truth, 0)).solution_
           for c in (True, False)]
    _assert_same_to_rounding(*res)
    assert np.all(np.abs(res[0].P_diag[:, 18:] - res[1].P_diag[:, 18:]) <= 1e-9 * res[1].P_diag[:, 18:])


def test_overconfident_filter_fails_the_nees_test(truth):
    """The NEES test can fail: a filter told the gyros are 10x quieter than they are is
    overconfident, and its mean NEES leaves the upper bound."""
    bad = ekf.ImuNoise(vrw=5e-4, arw=0.1 * ekf.ImuNoise().arw, gyro_bias_sigma=0.1 * ekf.ImuNoise().gyro_bias_sigma)
    rs = [_run(truth, 100 + s, noise_filter=bad) for s in range(3)]
    nees = np.array([ekf.nees_nav(r, truth, idx)[::20] for r, idx, _ in rs])
    hi = chi2.ppf(0.995, 9 * 3) / 3
    assert np.mean(nees.mean(axis=0) > hi) > 0.3


def test_gps_outage_degrades_as_predicted_and_recovers(truth, runs):
    r, idx, _ = runs[0]
    t = r.time_s
    sig_pos = np.sqrt(r.P_diag[:, 0:3].sum(axis=1))
    before = sig_pos[np.searchsorted(t, OUTAGE[0] - 1)]
    end = np.searchsorted(t, OUTAGE[1] - 0.01)
    after = sig_pos[np.searchsorted(t, OUTAGE[1] + 20)]
    assert sig_pos[end] > 2.5 * before        # the covariance predicts the drift ...
    assert np.all(np.diff(sig_pos[np.searchsorted(t, OUTAGE[0] + 1):end]) > 0)   # monotone growth
    assert after < 2 * before                  # ... and the filter recovers
    # the actual error at the end of the outage, over all runs, is as predicted:
    # Σ_runs e_endᵀ P⁻¹ e_end ~ χ²(3 RUNS), 99.9 % interval
    s = 0.0
    for r, idx, _ in runs:
        sol = ins.NavSolution(r.time_s, r.lat_rad, r.lon_rad, r.h_m, r.v_N, r.q_NB)
        e = ins.nav_errors(sol, truth, idx)["pos_N_m"][end]
        s += float(e @ np.linalg.solve(r.P_nav[end, :3, :3], e))
    a, b = chi2.ppf([0.0005, 0.9995], 3 * RUNS)
    assert a < s < b


def test_biases_estimated_within_their_standard_errors(runs):
    """Turn-on biases drawn per run; estimates at the end within 4σ of the filter's own σ (the
    gyro's Gauss-Markov part is part of the truth the filter tracks, so only the accelerometer
    turn-on bias is compared directly)."""
    for r, _, tb in runs:
        z = (r.acc_bias_m_s2[-1] - tb["acc_bias_m_s2"]) / np.sqrt(r.P_diag[-1, 9:12])
        assert np.all(np.abs(z) < 4.5), z
        assert np.all(np.sqrt(r.P_diag[-1, 9:12]) < 0.05 / 5)   # observable: σ shrank ≥ 5x


def test_scale_factor_variant_runs_and_estimates(truth):
    noise = ekf.ImuNoise(vrw=5e-4)
    rng = np.random.default_rng(11)
    imu, gps, _ = synthetic_sensors(truth, noise, rng, mag_sigma_rad=1 * D)
    cfg = ekf.FilterConfig(nav_rate_hz=20.0, estimate_scale_factors=True, sigma0_heading_rad=2 * D)
    r = ekf.LooseEKF(cfg, noise).fit(imu, gps, ins.state_at(truth, 0)).solution_
    assert r.P_diag.shape[1] == 24 and len(r.state_names) == 24
    # scale factors are observable with S-turns: the yaw-gyro scale σ shrinks below its prior
    assert math.sqrt(r.P_diag[-1, 23]) < 0.5 * cfg.sigma0_gyro_scale


def test_refuses_bad_inputs(truth):
    noise = ekf.ImuNoise()
    rng = np.random.default_rng(3)
    imu, gps, _ = synthetic_sensors(truth, noise, rng)
    f = ekf.LooseEKF(ekf.FilterConfig(nav_rate_hz=20.0), noise)
    fast = GpsFixes(time_s=np.arange(0, 10, 0.001), lat_rad=np.zeros(10000), lon_rad=np.zeros(10000),
                    h_m=np.zeros(10000), v_N=np.zeros((10000, 3)), sigma_pos_N=np.ones((10000, 3)),
                    sigma_vel_N=np.ones((10000, 3)))
    with pytest.raises(ConfigError, match="above the IMU rate"):
        f.fit(imu, fast, ins.state_at(truth, 0))
    imu.f_B[100, 0] = np.nan
    with pytest.raises(RecordingError, match="NaN"):
        f.fit(imu, gps, ins.state_at(truth, 0))


def test_observability_table_of_the_paper():
    """Paper Table 1 from eq. 4: biases and scale factors observable, misalignments only with
    enough excitation. A straight level leg leaves the misalignments and scale factors at their
    prior (σ ratio > 0.95 / > 0.7) and the horizontal accelerometer biases tied to the tilt;
    S-turns with pitch and climb changes observe biases and scale factors (ratio < 0.15) and
    the misalignments partly (ratio < 0.75)."""
    from imurig.flights import observability as O

    straight = O.gramian(ins.s_turn_truth(240, 20))
    turns = O.gramian(ins.s_turn_truth(240, 20, yaw_amp_rad=60 * D, yaw_period_s=80, pitch_amp_rad=5 * D,
                                       pitch_period_s=30, climb_amp_m_s=5))
    names = straight.state_names
    r0 = dict(zip(names, straight.sigma_ratio))
    r1 = dict(zip(names, turns.sigma_ratio))
    mis = [k for k in names if ".axis_misalignment." in k]
    scale = [k for k in names if ".scale_factor." in k]
    bias = [k for k in names if ".bias." in k]
    assert min(r0[k] for k in mis) > 0.95
    assert max(r1[k] for k in mis) < 0.75
    assert min(r0[k] for k in scale) > 0.7
    assert max(r1[k] for k in scale + bias) < 0.15
    assert r0["acc.bias.b_x"] > 0.5 and r0["acc.bias.b_y"] > 0.5          # bias vs tilt on a straight leg
    assert max(r1[k] for k in ("acc.temperature_sensor.dT_x", "acc.temperature_sensor.dT_y", "acc.temperature_sensor.dT_z")) < 0.1   # temperature channels
    # G is positive definite on the S-turns (all singular values > 0)
    assert turns.singular_values[-1] > 0


# --- the real GPS chain (Euro4 receiver model, IMU-clock tags) on the MuJoCo flight ------------------
REAL_SEEDS = (1, 2, 3, 4)
REAL_DUR = 300.0


@pytest.fixture(scope="module")
def flight_truth():
    """The default flight's first REAL_DUR s. The flight is simulated forward in time, so the plan's
    first five phases (parked, ground circle, take-off, climb, the leg to Delft: 0-453 s) give
    these samples bit for bit; the later phases are not flown (half the simulation's CPU)."""
    from imurig.flights.plan import FlightPlan, default_phases, simulate_flight

    tr = simulate_flight(FlightPlan(phases=default_phases()[:5]), progress_bar=False)
    assert tr.time_s[-1] >= tr.time_s[0] + REAL_DUR
    return tr.slice(tr.time_s[0], tr.time_s[0] + REAL_DUR)


def _perfect_imu_real_gps(tr, seed, acc_bias_prior=1e-3):
    """The filter as ``imurig flight`` sets it up (:func:`imurig.campaigns.flight.run_filter`: GPS Gauss-Markov states,
    time-of-validity error in R, IGRF declination along the route, P0 from the alignment), fed the
    truth's own IMU samples (held over each interval) plus the white noise of the filter's IMU model,
    the magnetometer's true field, and the receiver model's fixes. The accelerometer-bias prior is
    1e-3 m/s² (the true bias is zero)."""
    from imurig.campaigns import flight as R

    class Opt:
        nav_rate_hz, gps_rate_hz, gps_latency_s, gps_time_sigma_s = 25.0, 1.0, 0.0, 0.0

    opt = Opt()
    gps = R.gps_fixes(tr, opt, seed)
    lab = R.flight_lab(seed)
    T = np.full((tr.n, 3), 298.15)
    noise = ekf.ImuNoise.from_sensors(lab.accelerometers, lab.gyros, tr.rate_hz)
    # the IMU's white noise as the filter models it (VRW, ARW at the sample rate): a calibrated IMU
    # without residual systematic errors
    rng = np.random.default_rng(np.random.SeedSequence([66, seed]))
    sq = math.sqrt(tr.rate_hz)
    w = tr.w_IB_B + rng.standard_normal((tr.n, 3)) * noise.arw * sq
    f = tr.f_B + rng.standard_normal((tr.n, 3)) * noise.vrw * sq
    imu = ImuStream(time_s=tr.time_s, f_B=f, w_IB_B=w, B_B=tr.B_B, T_acc_K=T, samples=ins.sample_semantics(tr))
    # the true field: the heading σ is the fluxgate's own noise over the horizontal intensity
    H = float(np.median(np.hypot(tr.B_B[:, 0], tr.B_B[:, 1])))
    cfg = ekf.FilterConfig(nav_rate_hz=25.0, gps_latency_s=opt.gps_latency_s, gps_time_sigma_s=opt.gps_time_sigma_s,
                           mag_heading_sigma_rad=lab.magnetometer.noise_T_rms / H, sigma0_acc_bias_m_s2=acc_bias_prior,
                           gps_pos_states=True, **R.gps_error_model(gps))
    f = ekf.LooseEKF(cfg, noise, lever_gps_B=tr.lever_gps_B, declination=R.declination_model(tr))
    x0 = R.align(tr, imu, gps, R.declination_model(tr))
    f_m, B_m = R.alignment_means(tr, imu)
    P0 = f.alignment_covariance(x0, f_m, B_m, gps, window_s=R.ALIGN_WINDOW_S, sigma_mag_rad=cfg.mag_heading_sigma_rad)
    return f.fit(imu, gps, x0, P0=P0).solution_, gps


@pytest.fixture(scope="module")
def real_gps_runs(flight_truth):
    return [_perfect_imu_real_gps(flight_truth, s) for s in REAL_SEEDS]


def test_consistent_on_the_real_gps_chain(flight_truth, real_gps_runs):
    """IMU with white noise only, the receiver model's fixes (Gauss-Markov RTK error with the ppm baseline term,
    20 ms latency, jitter, tags rounded to the IMU clock): after the 60 s alignment the mean NEES
    over the runs stays inside the 99 % χ²(9N)/N band at ≥ 90 % of the epochs, and the summed NIS
    of the GPS position and velocity updates inside their 99.9 % χ² intervals. Before the GPS error
    states, the held-sample pre-integration and the a·σ_t velocity term this NEES was ~18 and the
    position NIS 0.06/dof (R inflated 11x in σ)."""
    N = len(real_gps_runs)
    nees = []
    for res, _ in real_gps_runs:
        idx = np.arange(res.time_s.size) * res.meta["samples_per_step"]
        m = res.time_s >= res.time_s[0] + 60.0
        nees.append(ekf.nees_nav(res, flight_truth, idx)[m][::25])
    mean = np.mean(nees, axis=0)
    lo, hi = chi2.ppf([0.005, 0.995], 9 * N) / N
    inside = np.mean((mean >= lo) & (mean <= hi))
    assert inside >= 0.9, (inside, mean.mean(), lo, hi)
    for kind in ("gps_pos", "gps_vel"):
        s = sum(r.updates[kind]["nis"].sum() for r, _ in real_gps_runs)
        dof = sum(r.updates[kind]["dof"].sum() for r, _ in real_gps_runs)
        a, b = chi2.ppf([0.0005, 0.9995], dof)
        assert a < s < b, (kind, s / dof, a / dof, b / dof)


def test_position_error_is_the_receivers_own(flight_truth, real_gps_runs):
    """With a perfect IMU the position error is the receiver's own: while parked (first 30 s,
    after 10 s) it is within 3σ of the receiver's Gauss-Markov + white σ (1 cm + 1 ppm of the
    35 km baseline to Delft); on the move the time-tag error adds σ_t |v| per fix (5 ms, 0.6 m at
    120 m/s), and the filter's own σ covers the error (NEES test above)."""
    for res, gps in real_gps_runs:
        K = res.meta["samples_per_step"]
        idx = np.arange(res.time_s.size) * K
        sol = ins.NavSolution(res.time_s, res.lat_rad, res.lon_rad, res.h_m, res.v_N, res.q_NB)
        e = ins.nav_errors(sol, flight_truth, idx)["pos_N_m"]
        m = (res.time_s >= 10.0) & (res.time_s < 30.0)
        sig = np.asarray(gps.sigma_pos_N, float)[np.asarray(gps.valid)][0]
        rms = np.sqrt(np.mean(e[m] ** 2, axis=0))
        assert np.all(rms < 3 * sig), (rms, sig)


def test_held_samples_preintegrated_as_held(flight_truth):
    """The flight truth's IMU samples are held over [t_k, t_k+1) (MuJoCo's step). Pre-integrated as
    held (forward increments, second-order coning/sculling) the free INS keeps the attitude to
    1.4e-6 rad over 300 s (parked, ground circle, take-off, climb: rounding and the 25 Hz
    position scheme); read as instantaneous (trapezoid) it is half a sample ahead, 1.2e-3 rad."""
    tr = flight_truth
    err = {}
    for s in ("held", "instantaneous"):
        inc = ins.preintegrate(tr.time_s, tr.w_IB_B, tr.f_B, 4, samples=s)
        sol = ins.navigate(inc, ins.state_at(tr, 0))
        e = ins.nav_errors(sol, tr, np.arange(sol.time_s.size) * 4)
        err[s] = (np.abs(e["att_N_rad"]).max(), np.abs(e["vel_N_m_s"]).max())
    assert ins.sample_semantics(tr) == "held"
    assert err["held"][0] < 1e-5 and err["held"][0] < 0.01 * err["instantaneous"][0], err
    assert err["held"][1] < err["instantaneous"][1], err
    with pytest.raises(ConfigError, match="samples must be"):
        ins.preintegrate(tr.time_s, tr.w_IB_B, tr.f_B, 4, samples="smooth")


def test_datasheet_bias_prior_while_parked_stays_consistent(flight_truth):
    """With the datasheet's accelerometer-bias prior (0.1 m/s²) and the fluxgate's own heading σ
    (0.015 deg) the filter used to diverge while parked: P0 treated tilt and bias as independent,
    although levelling makes the tilt error −δb_a/g. With P0 from the alignment's error propagation
    the same setting stays consistent: over 2 runs the mean NEES after 60 s is inside the 99 %
    χ²(9N)/N band at ≥ 90 % of the epochs."""
    runs = [_perfect_imu_real_gps(flight_truth, s, acc_bias_prior=0.1)[0] for s in REAL_SEEDS[:2]]
    nees = []
    for res in runs:
        idx = np.arange(res.time_s.size) * res.meta["samples_per_step"]
        m = res.time_s >= res.time_s[0] + 60.0
        nees.append(ekf.nees_nav(res, flight_truth, idx)[m][::25])
    mean = np.mean(nees, axis=0)
    lo, hi = chi2.ppf([0.005, 0.995], 9 * len(runs)) / len(runs)
    assert np.mean((mean >= lo) & (mean <= hi)) >= 0.9, (mean.mean(), lo, hi)


def test_mag_heading_jacobian_matches_finite_differences():
    """z = ŷaw − ψ_m(B_B levelled with the estimated roll, pitch) against ψ by central differences:
    the closed form [tan I cos D, tan I sin D, −1] holds at any attitude (to the O(h²) of the
    differences, 1e-7); the older ∂yaw/∂ψ row (levelling left out) misses tan I = 2.36 on ψ_n."""
    rng = np.random.default_rng(5)
    Dd, I = 0.02, 67 * D
    B_N = np.array([math.cos(Dd), math.sin(Dd), math.tan(I)]) * 19e-6
    for _ in range(5):
        eul = (rng.uniform(-1, 1), rng.uniform(-0.6, 0.6), rng.uniform(-3, 3))
        q = E.q_from_euler(*eul)
        B_B = E.C_from_q(q).T @ B_N

        def z(psi, q=q, B_B=B_B):
            rr, pp, yy = E.euler_from_C(E.C_from_q(E.q_mult(E.q_from_rotvec(-psi), q)))
            return E.wrap_pi(yy - ekf.mag_heading(B_B, rr, pp, Dd))

        h = 1e-6
        J = np.array([(z(h * e) - z(-h * e)) / (2 * h) for e in np.eye(3)])
        Hc = ekf.mag_heading_jacobian(E.C_from_q(q), B_B)
        assert np.allclose(J, Hc, atol=1e-7), (J, Hc)
        assert np.allclose(Hc, [math.tan(I) * math.cos(Dd), math.tan(I) * math.sin(Dd), -1.0], atol=1e-12)


def test_mag_iron_jacobian_matches_finite_differences():
    """z = ŷaw − ψ_m((I + ΔÂ)⁻¹(B_m − b̂)) against the 12 installation-error estimates θ̂ = [b̂, ΔÂ]
    by central differences, at random attitudes and random θ̂ of the datasheet's size (hard iron
    2000 nT, ΔA 5 %): the closed form matches to the O(h²) of the differences; the corrected field
    inverts B_m = (I + ΔA) B_B + b exactly."""
    rng = np.random.default_rng(11)
    Dd, I = 0.02, 67 * D
    B_N = np.array([math.cos(Dd), math.sin(Dd), math.tan(I)]) * 19e-6
    scale = np.r_[np.full(3, 1e-6), np.full(9, 1e-3)]      # difference steps: T, −
    for _ in range(5):
        eul = (rng.uniform(-1, 1), rng.uniform(-0.6, 0.6), rng.uniform(-3, 3))
        q = E.q_from_euler(*eul)
        B_B = E.C_from_q(q).T @ B_N
        theta = np.r_[rng.uniform(-2e-6, 2e-6, 3), rng.uniform(-0.05, 0.05, 9)]
        B_m = (np.eye(3) + theta[3:].reshape(3, 3)) @ B_B + theta[:3]
        assert np.allclose(ekf.mag_corrected_field(B_m, theta), B_B, rtol=0, atol=1e-18)
        th_est = theta + rng.uniform(-1, 1, 12) * scale * 100

        def z(t, B_m=B_m, eul=eul):
            return E.wrap_pi(eul[2] - ekf.mag_heading(ekf.mag_corrected_field(B_m, t), eul[0], eul[1], Dd))

        J = np.array([(z(th_est + s_ * e) - z(th_est - s_ * e)) / (2 * s_) for s_, e in zip(scale * 1e-3, np.eye(12))])
        Hc = ekf.mag_iron_jacobian(B_m, th_est, eul[0], eul[1])
        assert np.allclose(J * scale, Hc * scale, atol=1e-8), (J, Hc)
        # the heading-relevant part of the hard iron is ~1/H per tesla
        assert 0.1 / 19e-6 < np.linalg.norm(Hc[:3]) < 10 / 19e-6


def test_mag_iron_prior_matches_the_datasheet_draws():
    """The prior covariance of [b, ΔA] derived from the fluxgate's datasheet draws agrees with the
    sample covariance of 4000 draws of :meth:`FluxgateTriad.from_datasheet` (read with the nominal
    sensitivity) to within the sampling error (4 SE of a variance: 4 √(2/N) σ² ≈ 9 % for a Gaussian,
    less for the uniform draws) plus the second-order products the derivation leaves out."""
    from imurig.sensors.magnetometer import FluxgateTriad

    rng = np.random.default_rng(3)
    N = 4000
    th = np.empty((N, 12))
    for k in range(N):
        f = FluxgateTriad.from_datasheet(rng)
        Dm = np.diag(f.sensitivity_V_per_T / 4.0e4)
        th[k, :3] = Dm @ f.hard_iron_T
        th[k, 3:] = (Dm @ f.soft_iron @ (np.eye(3) + f.misalignment_rad) - np.eye(3)).ravel()
    P = ekf.mag_iron_prior_cov(2000e-9, 0.05, 5e-3, 0.02)
    Ps = np.cov(th.T)
    sd = np.sqrt(np.diag(P))
    rel = (Ps - P) / np.outer(sd, sd)
    assert np.all(np.abs(rel) < 4 * math.sqrt(2 / N) * 1.2), np.abs(rel).max()


def test_alignment_covariance_is_the_levelling_error_propagation():
    """Levelling a static IMU with an accelerometer bias b and a compass heading error gives
    ψ_n = (C δf)_e/g, ψ_e = −(C δf)_n/g (δf = −δb_a = b) and ψ_d = hᵀψ − e_m: the regression of ψ
    on the sources implied by P0 reproduces the actual alignment error of :func:`imurig.campaigns.flight.align`
    to second order, |Δψ| < 10 (|b|/g)², and P0 is positive semi-definite."""
    from types import SimpleNamespace

    from imurig.campaigns import flight as R

    g = 9.81
    eul = (0.05, -0.03, 1.2)
    q = E.q_from_euler(*eul)
    C = E.C_from_q(q)
    b = np.array([0.02, -0.015, 0.01])
    Dd = 0.01
    B_N = np.array([math.cos(Dd), math.sin(Dd), math.tan(67 * D)]) * 19e-6
    n = 500
    stream = ImuStream(time_s=np.arange(n) * 0.01, w_IB_B=np.zeros((n, 3)), f_B=np.tile(C.T @ [0, 0, -g] + b, (n, 1)),
                       B_B=np.tile(C.T @ B_N, (n, 1)))
    gps = GpsFixes(time_s=np.array([0.0]), lat_rad=np.array([0.9]), lon_rad=np.array([0.08]), h_m=np.array([0.0]),
                   v_N=np.zeros((1, 3)), sigma_pos_N=np.full((1, 3), 0.02), sigma_vel_N=np.full((1, 3), 0.01))
    tr = SimpleNamespace(rate_hz=100.0, lever_gps_B=np.array([1.0, 0.0, -2.0]))
    x0 = R.align(tr, stream, gps, Dd)
    S = np.eye(3) - E.C_from_q(x0.q_NB) @ C.T
    psi = np.array([S[2, 1], S[0, 2], S[1, 0]])
    f = ekf.LooseEKF(ekf.FilterConfig(), lever_gps_B=tr.lever_gps_B)
    f_m, B_m = R.alignment_means(tr, stream)
    P0 = f.alignment_covariance(x0, f_m, B_m, gps, window_s=5.0, sigma_mag_rad=1 * D)
    pred = P0[6:9, 9:12] @ np.linalg.solve(P0[9:12, 9:12], -b)
    assert np.all(np.abs(pred - psi) < 10 * (np.linalg.norm(b) / g) ** 2), (pred, psi)
    assert np.linalg.eigvalsh(P0).min() > -1e-12 * np.abs(P0).max()
    # the tilt is (almost) fully explained by the bias (0.1 m/s² prior against the levelling noise)
    expl = np.diag(P0[6:8, 9:12] @ np.linalg.solve(P0[9:12, 9:12], P0[9:12, 6:8])) / np.diag(P0[6:8, 6:8])
    assert np.all(expl > 0.999), expl


def test_white_noise_model_is_the_flight_acquisitions():
    """``ImuNoise.from_sensors(..., adc=)`` against the flight chain's own noise generators: the
    accelerometer current noise with averaged logging plus the DAQ's noise on every logged sample
    (quantisation and input noise of 10 averaged conversions, common-mode noise), and the FOG's ARW
    plus the same DAQ noise. The random-walk density N is measured from differences of 1-s means of
    2000 s of noise (σ_1s = N/√1 s; differences remove the FOG's slow bias instability, leaving
    <1 % of it); bound: 4 standard errors of the sample σ (√(1/2n))."""
    from imurig.campaigns import flight as R
    from imurig.flights.imu import flight_lab as acquisition

    lab = R.flight_lab(2005)
    fs, n = 100.0, 200_000
    noise = R.imu_noise(lab, fs)
    adc = acquisition(lab, fs).adc
    rng = np.random.default_rng(5)
    t = np.arange(n) / fs
    acc = lab.accelerometers
    v_acc = acc.noise_current(n, fs, rng, averaged=True)[:, 2] * acc.load_resistor_ohm[2] + 1.0
    v_gyro = lab.gyros.noise_rate(n, fs, rng)[:, 0] * lab.gyros.scale_V_per_rad_s[0] + 1.0
    out, _ = adc.convert({c: (v_acc if c == "acc_z" else v_gyro if c == "gyro_p" else np.ones(n))
                          for c in adc.scan_list}, t, rng)
    m = n // 100
    se = 4 * math.sqrt(1 / (2 * m))
    # The model divides by the smallest sensitivity of the three axes (k1 of the current noise, the
    # gyro scale of the DAQ noise); the channels here are read with acc_z's nominal sensitivity and
    # gyro_p's own scale. The density the model predicts for exactly these readings: the same
    # formula with those sensitivities on all three axes.
    from dataclasses import replace

    from imurig.sensors.gyro import FOGTriad

    k1_nom = acc.nominal_sensitivity_V_per_m_s2()[2] / acc.load_resistor_ohm[2]
    same = ekf.ImuNoise.from_sensors(replace(acc, k1_A_per_m_s2=np.full(3, k1_nom)),
                                     FOGTriad(**{**lab.gyros.__dict__,
                                                 "scale_V_per_rad_s": np.full(3, lab.gyros.scale_V_per_rad_s[0])}),
                                     fs, adc=adc)
    for ch, sens, dens, expected in (("acc_z", acc.nominal_sensitivity_V_per_m_s2()[2], noise.vrw, same.vrw),
                                     ("gyro_p", lab.gyros.scale_V_per_rad_s[0], noise.arw, same.arw)):
        x = (out[ch] - 1.0) / sens
        s1 = np.diff(x.reshape(m, 100).mean(1)).std() / math.sqrt(2)   # differences: no slow bias drift
        ratio = s1 / expected
        assert 1 - se < ratio < 1 + se, (ch, ratio, se)
        assert expected <= dens * (1 + 1e-12)      # the smallest sensitivity: the model is never optimistic
    assert noise.vrw < 1e-4    # the 0.5-10 kHz current noise averages out in the 1 kHz conversions


def test_nonlinearity_states_estimate_an_injected_second_order_term(truth):
    """Specific force measured as f + k2 ⊙ f² (k2 = [3, −4, 5]e-6 s²/m, the Q-Flex's datasheet order):
    the filter with ``estimate_nonlinearity`` (prior σ 5e-6) ends with every δk2 within 3σ of the
    truth, and its mean NEES over the run is below that of the same filter without the states."""
    k2 = np.array([3e-6, -4e-6, 5e-6])
    noise = ekf.ImuNoise(vrw=5e-4)
    rng = np.random.default_rng(np.random.SeedSequence([61, 0]))
    imu, gps, _tb = synthetic_sensors(truth, noise, rng, lever_gps_B=LEVER, mag_sigma_rad=1 * D, outages=())
    imu.f_B = imu.f_B + k2 * np.asarray(truth.f_B) ** 2
    out = {}
    for est in (True, False):
        cfg = ekf.FilterConfig(nav_rate_hz=20.0, mag_heading_sigma_rad=1 * D, sigma0_heading_rad=5 * D,
                               sigma0_acc_bias_m_s2=0.05, sigma0_gyro_bias_rad_s=0.003 * D,
                               estimate_nonlinearity=est, sigma0_acc_nonlinearity_s2_m=5e-6)
        f = ekf.LooseEKF(cfg, noise, lever_gps_B=LEVER)
        res = f.fit(imu, gps, ins.state_at(truth, 0)).solution_
        idx = np.arange(res.time_s.size) * res.meta["samples_per_step"]
        out[est] = (res, ekf.nees_nav(res, truth, idx))
    res, nees = out[True]
    sl = res.state_names.index("acc.scale_nonlinearity.k2_x")
    sig = np.sqrt(res.P_diag[-1, sl:sl + 3])
    assert np.all(np.abs(np.asarray(res.meta["nonlinearity_acc_s2_m"]) - k2) < 3 * sig), (res.meta, sig)
    assert nees.mean() < out[False][1].mean(), (nees.mean(), out[False][1].mean())


def test_gyro_turn_on_bias_is_a_random_constant_beside_the_instability(truth):
    """``gyro_bias_gm_states``: the gyro bias is b_0 (turn-on, a random constant) + b_GM (the
    instability, Gauss-Markov σ, τ). (1) Without any aiding the covariance of b_0 keeps its prior
    exactly while that of b_GM tends to σ² (the single Gauss-Markov state shrinks a turn-on bias
    prior to σ², the over-confidence this fixes). (2) On data drawn from exactly that model
    (``synthetic_sensors``: turn-on bias + Gauss-Markov + ARW) the turn-on bias states end
    consistent with the injected b_0: Σ eᵀP⁻¹e over 4 runs inside the 99.9 % χ²(12) interval."""
    noise = ekf.ImuNoise(vrw=5e-4, gyro_bias_tau_s=5.0)
    short = ins.s_turn_truth(40.0, 100.0, yaw_amp_rad=60 * D, yaw_period_s=80.0)
    rng = np.random.default_rng(np.random.SeedSequence([62, 0]))
    imu, _gps, _tb = synthetic_sensors(short, noise, rng)
    for split in (True, False):
        cfg = ekf.FilterConfig(nav_rate_hz=20.0, use_magnetometer=False, sigma0_gyro_bias_rad_s=0.003 * D,
                               gyro_bias_gm_states=split)
        f = ekf.LooseEKF(cfg, noise)
        res = f.fit(imu, None, ins.state_at(short, 0)).solution_
        bg = res.P_diag[-1, 12:15]
        if split:
            gm = res.P_diag[-1, cfg.gyro_gm_slice()]
            assert np.allclose(bg, (0.003 * D) ** 2, rtol=1e-12), bg
            assert np.allclose(gm, noise.gyro_bias_sigma ** 2, rtol=1e-3), gm
        else:
            assert np.allclose(bg, noise.gyro_bias_sigma ** 2, rtol=1e-3), bg   # the old model's belief
    stat, dof = 0.0, 0
    for seed in range(4):
        noise = ekf.ImuNoise(vrw=5e-4)
        rng = np.random.default_rng(np.random.SeedSequence([63, seed]))
        imu, gps, tb = synthetic_sensors(truth, noise, rng, lever_gps_B=LEVER, mag_sigma_rad=1 * D, outages=())
        cfg = ekf.FilterConfig(nav_rate_hz=20.0, mag_heading_sigma_rad=1 * D, sigma0_heading_rad=5 * D,
                               sigma0_acc_bias_m_s2=0.05, sigma0_gyro_bias_rad_s=0.003 * D,
                               gyro_bias_gm_states=True)
        f = ekf.LooseEKF(cfg, noise, lever_gps_B=LEVER)
        P0 = f.initial_covariance()
        P0[:9, :9] = 0.0
        P0[:9, :9] += np.diag(np.full(9, 1e-12))    # start on the truth (no alignment error)
        res = f.fit(imu, gps, ins.state_at(truth, 0), P0=P0).solution_
        # b0 estimate = total bias estimate − its Gauss-Markov part (meta) against the injected b_0
        b0_hat = res.gyro_bias_rad_s[-1] - np.asarray(res.meta["gyro_bias_gm_rad_s"])
        e = b0_hat - tb["gyro_bias_rad_s"]
        stat += float(np.sum(e ** 2 / res.P_diag[-1, 12:15]))
        dof += 3
    lo, hi = chi2.ppf([0.0005, 0.9995], dof)
    assert lo < stat < hi, (stat, dof)


def test_attitude_reset_jacobian_against_the_exact_rotation_composition():
    """Injecting ψ̂ into Ĉ = exp(−[ψ×]) C leaves the error ψ' with exp(−[ψ'×]) = exp([ψ̂×]) exp(−[ψ×]);
    G (ψ − ψ̂) reproduces it to third order: the BCH terms it leaves, (1/12)([X,[X,Y]] + [Y,[Y,X]]),
    are at most (|ψ̂| + |ψ|)/6 of the second-order term ½ ψ̂ × ψ that the plain reset ψ − ψ̂ leaves
    (a 4 deg heading correction with mrad tilts)."""
    from scipy.spatial.transform import Rotation

    from imurig.flights.ekf import attitude_reset_jacobian

    rng = np.random.default_rng(11)
    for _ in range(50):
        psi = np.r_[rng.normal(0, 5e-3, 2), rng.normal(0, 0.07)]        # tilt mrad, heading ~4 deg
        psi_hat = psi + rng.normal(0, [1e-3, 1e-3, 5e-3])                # the update's estimate of it
        exact = -Rotation.from_matrix(Rotation.from_rotvec(psi_hat).as_matrix()
                                      @ Rotation.from_rotvec(-psi).as_matrix()).as_rotvec()
        plain = psi - psi_hat
        with_g = attitude_reset_jacobian(psi_hat) @ plain
        second = np.linalg.norm(0.5 * np.cross(psi_hat, psi))
        assert np.linalg.norm(exact - plain) > 0.5 * second
        assert np.linalg.norm(exact - with_g) <= (np.linalg.norm(psi_hat) + np.linalg.norm(psi)) / 6 * second
