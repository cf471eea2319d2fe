"""GPS receiver model (NovAtel Euro4): error statistics, latency and time tags, lever arm, outages,
refusals. Truth-based: every check compares with what was injected, with bounds from the
number of samples."""
import numpy as np
import pytest
from imurig.flights import earth
from imurig.flights.gps import CEP_TO_SIGMA, GpsReceiver, antenna_track
from imurig.flights.truth import BodyKinematics, truth_from_kinematics

from imurig.kernel.errors import ConfigError

ORIGIN = (52.0, 4.2, 50.0)


def _truth(duration_s, rate_hz, v_N=(0.0, 0.0, 0.0), w_B=(0.0, 0.0, 0.0), lever=(0.5, 0.3, -1.1)):
    """Constant velocity and body rate (exact kinematics: the attitude integrates w_B in closed form)."""
    n = round(duration_s * rate_hz)
    t = np.arange(n) / rate_hz
    v = np.tile(np.asarray(v_N, float), (n, 1))
    p = t[:, None] * v
    w = np.tile(np.asarray(w_B, float), (n, 1))
    q = earth.q_from_rotvec(t[:, None] * w)
    z = np.zeros((n, 3))
    kin = BodyKinematics(time_s=t, p_N=p, q_NB=q, v_N=v, w_NB_B=w, a_N=z, wdot_NB_B=z, rate_hz=rate_hz)
    return truth_from_kinematics(kin, ORIGIN, "2005-06-26T10:00:00+02:00", "van", lever, (0, 0, 0),
                                 field_step_s=1e7)


def _errors_N(fixes, truth):
    lat, lon, h, _ = antenna_track(truth, fixes.t_true_s)
    return np.stack([earth.ned_from_geodetic(fixes.lat_rad[k], fixes.lon_rad[k], fixes.h_m[k], lat[k], lon[k], h[k])
                     for k in range(fixes.n)]) if fixes.n < 50 else _ned_vec(fixes, lat, lon, h)


def _ned_vec(fixes, lat, lon, h):
    R_N, R_E = earth.radii(lat)
    return np.stack([(fixes.lat_rad - lat) * (R_N + h), (fixes.lon_rad - lon) * (R_E + h) * np.cos(lat),
                     -(fixes.h_m - h)], axis=1)


def test_datasheet_constructor_units():
    r = GpsReceiver.euro4("standalone")
    total = np.hypot(r.sigma_gm_N_m[0], r.sigma_white_N_m[0])
    assert total == pytest.approx(1.5 * CEP_TO_SIGMA, rel=1e-12)
    assert GpsReceiver.euro4("rtk").ppm_of_baseline == 1e-6
    assert GpsReceiver.euro4("differential").latency_s == 0.020


@pytest.mark.parametrize("mode", ["differential", "standalone"])
def test_gauss_markov_correlation_time_and_sigma_recovered(mode):
    """Drive only the correlated part; recover φ = e^{−Δt/τ} by regression of x_{k+1} on x_k and the
    stationary σ from the innovations, within 4 standard errors from the number of samples."""
    r0 = GpsReceiver.euro4(mode)
    rec = GpsReceiver(mode=mode, sigma_gm_N_m=r0.sigma_gm_N_m, tau_gm_s=r0.tau_gm_s, sigma_white_N_m=(0, 0, 0),
                      ppm_of_baseline=0.0)
    truth = _truth(40_000.0, 1.0)
    fx = rec.measure(truth, np.random.default_rng(11))
    e = _errors_N(fx, truth)
    n = e.shape[0] - 1
    phi_true = np.exp(-1.0 / rec.tau_gm_s)
    for j in range(3):
        x0, x1 = e[:-1, j], e[1:, j]
        phi = np.dot(x0, x1) / np.dot(x0, x0)
        se_phi = np.sqrt((1 - phi_true ** 2) / n)
        assert abs(phi - phi_true) < 4 * se_phi, (j, phi, phi_true, se_phi)
        tau = -1.0 / np.log(phi)
        se_tau = se_phi / (phi_true * np.log(phi_true) ** 2)
        assert abs(tau - rec.tau_gm_s) < 4 * se_tau
        q = np.mean((x1 - phi_true * x0) ** 2)            # innovation variance σ²(1−φ²), rel. SE √(2/n)
        q_true = rec.sigma_gm_N_m[j] ** 2 * (1 - phi_true ** 2)
        assert abs(q / q_true - 1) < 4 * np.sqrt(2.0 / n)


def test_white_part_and_velocity_noise():
    rec = GpsReceiver(mode="rtk", sigma_gm_N_m=(0, 0, 0), sigma_white_N_m=(0.01, 0.02, 0.03), ppm_of_baseline=0.0,
                      sigma_vel_m_s=(0.03, 0.04, 0.05))
    truth = _truth(20_000.0, 1.0, v_N=(0.0, 10.0, 0.0))
    fx = rec.measure(truth, np.random.default_rng(3))
    e = _errors_N(fx, truth)
    _, _, _, v = antenna_track(truth, fx.t_true_s)
    n = fx.n
    for j, (s_p, s_v) in enumerate(zip(rec.sigma_white_N_m, rec.sigma_vel_m_s)):
        assert abs(np.var(e[:, j]) / s_p ** 2 - 1) < 4 * np.sqrt(2.0 / n)
        assert abs(np.corrcoef(e[:-1, j], e[1:, j])[0, 1]) < 4 / np.sqrt(n)      # white
        assert abs(np.var(fx.v_N[:, j] - v[:, j]) / s_v ** 2 - 1) < 4 * np.sqrt(2.0 / n)
    np.testing.assert_allclose(fx.sigma_pos_N, np.tile(rec.sigma_white_N_m, (n, 1)))


def test_latency_time_tags_and_lever_arm_noise_free():
    """Noise-free receiver: each fix is the antenna's true position at t_k (lever arm included),
    stamped t_k + latency + offset, rounded up to the IMU clock."""
    lever = np.array([0.5, 0.3, -1.1])
    rec = GpsReceiver(mode="rtk", rate_hz=5.0, sigma_gm_N_m=(0, 0, 0), sigma_white_N_m=(0, 0, 0), ppm_of_baseline=0,
                      sigma_vel_m_s=(0, 0, 0), latency_s=0.020, time_offset_s=0.013, time_jitter_s=0.0,
                      epoch_phase_s=0.07)
    w = (0.0, 0.0, 0.05)
    truth = _truth(120.0, 100.0, v_N=(30.0, 20.0, -1.0), w_B=w, lever=lever)
    fx = rec.measure(truth, np.random.default_rng(0))
    assert fx.t_true_s[0] == pytest.approx(0.07)
    np.testing.assert_allclose(np.diff(fx.t_true_s), 0.2, atol=1e-9)
    delay = fx.time_s - fx.t_true_s
    assert np.all(delay >= 0.033 - 1e-9) and np.all(delay < 0.033 + 0.01 + 1e-9)
    np.testing.assert_allclose(np.round(fx.time_s * 100), fx.time_s * 100, atol=1e-6)   # on the IMU clock
    # the epochs fall on IMU samples: the fix minus the IMU's true position is C_NB l_B (rigid lever arm)
    idx = np.round(fx.t_true_s * 100).astype(int)
    t = truth.time_s[idx]
    d = earth.ned_from_geodetic(fx.lat_rad, fx.lon_rad, fx.h_m, truth.lat_rad[idx], truth.lon_rad[idx], truth.h_m[idx])
    q = earth.q_from_rotvec(t[:, None] * np.asarray(w))
    np.testing.assert_allclose(d, earth.C_from_q(q) @ lever, atol=1e-6)
    # velocity of the antenna: v + ω × (C l); the Earth-rate part Ω×(C l) is < 1e-4 m/s
    v_ant = np.array([30.0, 20.0, -1.0]) + np.cross(np.asarray(w), earth.C_from_q(q) @ lever)
    np.testing.assert_allclose(fx.v_N, v_ant, atol=2e-4)


def test_outages_have_no_valid_fixes_and_correlated_error_restarts():
    rec = GpsReceiver.euro4("differential", outages=((100.0, 160.0), (300.0, 301.5)))
    truth = _truth(600.0, 10.0)
    fx = rec.measure(truth, np.random.default_rng(5))
    inside = ((fx.t_true_s >= 100) & (fx.t_true_s < 160)) | ((fx.t_true_s >= 300) & (fx.t_true_s < 301.5))
    assert inside.sum() == 62
    assert not fx.valid[inside].any() and fx.valid[~inside].all()
    assert np.all(np.isnan(fx.lat_rad[inside])) and np.all(np.isfinite(fx.lat_rad[~inside]))


def test_same_seed_same_fixes_and_refusals():
    truth = _truth(30.0, 10.0)
    rec = GpsReceiver.euro4("rtk")
    a = rec.measure(truth, np.random.default_rng(9))
    b = rec.measure(truth, np.random.default_rng(9))
    np.testing.assert_array_equal(a.lat_rad, b.lat_rad)
    np.testing.assert_array_equal(a.time_s, b.time_s)
    with pytest.raises(ConfigError, match="above the IMU rate"):
        GpsReceiver.euro4("rtk", rate_hz=20.0).measure(truth, np.random.default_rng(0))
    with pytest.raises(ConfigError, match="unknown"):
        GpsReceiver.euro4("ppp")
    with pytest.raises(ConfigError, match="t_end > t_start"):
        GpsReceiver(outages=((5.0, 1.0),))
