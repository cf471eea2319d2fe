"""Truth-based tests of imurig.calibration.magnetometer (seed sections 4.6-4.7, [Elk01]): the
MagnetometerCalibration estimator with methods 'ellipse', 'ellipsoid' and 'swing'.

Synthetic data follow the bench's sensor model ``m = A B_C + b + e`` (tesla) with a known
``A``, ``b`` and white noise; every estimate is compared with the injected truth, either
exactly (noise-free data) or against its own standard error (noisy data, several seeds).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from imurig.calibration.heading import heading_from_field, wrap_2pi, wrap_pi
from imurig.calibration.magnetometer import ELLIPSE_PARAMS, SWING_TERMS, MagnetometerCalibration
from imurig.kernel.errors import RecordingError, ScheduleError
from imurig.sensors.magnetometer import FluxgateTriad

H = 19010e-9           # horizontal intensity [T] (paper section 3.2: ~19018 nT)
F = 48724e-9           # total intensity [T] (paper section 3.2: ~48723 nT)
SIGMA = 20e-9          # sensor noise [T] rms per axis
B2 = np.array([3000e-9, -1500e-9])   # hard iron [T], |b| = 3354 nT
SEEDS = range(8)


# ---------------------------------------------------------------------------
# synthetic data


def _A2(sx=1.04, sy=0.955, rho=0.02) -> np.ndarray:
    return np.array([[sx, rho], [0.0, sy]])


def level_swing(rng, *, n=720, arc_deg=360.0, noise=SIGMA, A2=None, b2=B2):
    """Level swing, FRD axes: h = H (cos psi, -sin psi); m = A2 h + b2 + e. Returns psi (n,), m (n, 2)."""
    A2 = _A2() if A2 is None else A2
    psi = rng.uniform(0, 2 * np.pi) + np.radians(arc_deg) * np.arange(n) / n
    h = H * np.column_stack([np.cos(psi), -np.sin(psi)])
    m = h @ A2.T + b2 + noise * rng.standard_normal((n, 2))
    return wrap_2pi(psi), m


def random_A(rng) -> np.ndarray:
    """A = diag(s) S_soft (I + M): scale 1 +- 3 %, symmetric soft iron I +- 5 %, misalignment +- 5 mrad."""
    s = 1.0 + rng.uniform(-0.03, 0.03, 3)
    S = np.eye(3) + rng.uniform(-0.05, 0.05, (3, 3))
    S = 0.5 * (S + S.T)
    M = rng.uniform(-5e-3, 5e-3, (3, 3))
    np.fill_diagonal(M, 0.0)
    return np.diag(s) @ S @ (np.eye(3) + M)


def random_units(rng, n) -> np.ndarray:
    v = rng.standard_normal((n, 3))
    return v / np.linalg.norm(v, axis=1)[:, None]


def cone_units(rng, n, half_angle_deg) -> np.ndarray:
    """Unit vectors uniform in a spherical cap of the given half-angle around a random axis."""
    ax = random_units(rng, 1)[0]
    e1 = np.cross(ax, [1.0, 0.0, 0.0] if abs(ax[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(ax, e1)
    c = rng.uniform(math.cos(math.radians(half_angle_deg)), 1.0, n)
    s = np.sqrt(1.0 - c * c)
    phi = rng.uniform(0, 2 * np.pi, n)
    return c[:, None] * ax + s[:, None] * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2)


def tumble(rng, *, n=2000, noise=SIGMA, units=None):
    A = random_A(rng)
    b = rng.uniform(-3000e-9, 3000e-9, 3)
    B = F * (random_units(rng, n) if units is None else units)
    m = B @ A.T + b + noise * rng.standard_normal(B.shape)
    return A, b, B, m


def _upper(S: np.ndarray) -> np.ndarray:
    return S[np.triu_indices(3)]


def fit_ellipse_2d(mx, my, field_horizontal_T):
    return MagnetometerCalibration("ellipse").fit(np.column_stack([mx, my]), field_horizontal_T)


def fit_ellipsoid_3d(m, field_total_T):
    return MagnetometerCalibration("ellipsoid").fit(m, field_total_T)


def compass_swing(heading_true_rad, heading_indicated_rad):
    return MagnetometerCalibration("swing").fit(heading_indicated_rad, heading_true_rad)


# ---------------------------------------------------------------------------
# angles and heading convention


def test_wrap_pi_and_wrap_2pi_edges():
    assert wrap_pi(math.pi) == pytest.approx(math.pi)
    assert wrap_pi(-math.pi) == pytest.approx(math.pi)             # (-pi, pi]
    assert wrap_pi(3 * math.pi) == pytest.approx(math.pi)
    assert wrap_pi(-0.1) == pytest.approx(-0.1)
    assert wrap_pi(2 * math.pi + 0.25) == pytest.approx(0.25)
    a = np.linspace(-20, 20, 1001)
    w = wrap_pi(a)
    assert np.all(w > -math.pi) and np.all(w <= math.pi)
    np.testing.assert_allclose(np.sin(w), np.sin(a), atol=1e-12)
    np.testing.assert_allclose(np.cos(w), np.cos(a), atol=1e-12)
    w2 = wrap_2pi(a)
    assert np.all(w2 >= 0) and np.all(w2 < 2 * math.pi)
    assert wrap_2pi(-1e-18) < 2 * math.pi


def test_heading_from_field_frd_and_flu_conventions():
    # FRD (x fwd, y right, z down): nose north -> field along +x; nose east -> field on the left = -y
    assert heading_from_field(np.array([H, 0.0])) == pytest.approx(0.0)
    assert heading_from_field(0.0, -H) == pytest.approx(math.pi / 2)
    assert heading_from_field(-H, 0.0) == pytest.approx(math.pi)
    assert heading_from_field(0.0, H) == pytest.approx(3 * math.pi / 2)
    # FLU (x fwd, y left, z up): nose east -> north is on the left = +y
    assert heading_from_field(0.0, H, frame="FLU") == pytest.approx(math.pi / 2)
    psi = np.linspace(0, 2 * np.pi, 37, endpoint=False)
    frd = H * np.column_stack([np.cos(psi), -np.sin(psi)])
    np.testing.assert_allclose(heading_from_field(frd), psi, atol=1e-12)
    np.testing.assert_allclose(heading_from_field(frd[:, 0], -frd[:, 1], frame="FLU"), psi, atol=1e-12)
    # declination (east positive) turns magnetic into true heading, wrapped to [0, 2 pi)
    dec = math.radians(2.0)
    out = heading_from_field(frd, declination_rad=dec)
    np.testing.assert_allclose(np.cos(out - psi - dec), 1.0, atol=1e-12)
    assert np.all(out >= 0) and np.all(out < 2 * np.pi)
    with pytest.raises(ValueError, match="frame"):
        heading_from_field(frd, frame="NED")


# ---------------------------------------------------------------------------
# 2-D level swing


def test_ellipse_noise_free_recovers_truth_exactly():
    rng = np.random.default_rng(1)
    truth = dict(sx=1.04, sy=0.955, rho=0.02, bx=B2[0], by=B2[1])
    psi, m = level_swing(rng, noise=0.0, A2=_A2(truth["sx"], truth["sy"], truth["rho"]))
    res = fit_ellipse_2d(m[:, 0], m[:, 1], H)
    assert res.converged_ and res.n_iter_ <= 10
    for k in ("sx", "sy", "rho"):
        assert abs(res.params_[k] - truth[k]) <= 1e-9 * abs(truth[k]), k
    for k in ("bx", "by"):
        assert abs(res.params_[k] - truth[k]) <= 1e-9 * abs(truth[k]), k
    assert res.rms_residual_T_ <= 1e-9 * H
    np.testing.assert_allclose(res.A_, _A2(), rtol=1e-9)
    # the calibrated field is the true horizontal field, the heading the true heading
    hx, hy = res.apply(m).T
    np.testing.assert_allclose(np.hypot(hx, hy), H, rtol=1e-9)
    np.testing.assert_allclose(wrap_pi(res.heading(m) - psi), 0.0, atol=1e-9)
    assert res.coverage_deg_ > 359.0
    # step 1 (algebraic) is already exact on noise-free data: no initial guess needed
    for k in ELLIPSE_PARAMS:
        assert res.initial_[k] == pytest.approx(truth[k], rel=1e-8)


def test_ellipse_noisy_parameters_within_4_standard_errors():
    z = []
    for seed in SEEDS:
        rng = np.random.default_rng(100 + seed)
        truth = dict(sx=1 + rng.uniform(-0.05, 0.05), sy=1 + rng.uniform(-0.05, 0.05), rho=0.02,
                     bx=B2[0], by=B2[1])
        _, m = level_swing(rng, A2=_A2(truth["sx"], truth["sy"], truth["rho"]))
        res = fit_ellipse_2d(m[:, 0], m[:, 1], H)
        assert res.converged_
        assert res.sigma_ == pytest.approx(SIGMA, rel=0.1)   # radial residual = sensor noise
        for k in ELLIPSE_PARAMS:
            zk = (res.params_[k] - truth[k]) / res.std_errors_[k]
            assert abs(zk) < 4.0, (seed, k, zk)
            z.append(zk)
    rms = float(np.sqrt(np.mean(np.square(z))))
    assert 0.6 <= rms <= 1.5, rms


def test_ellipse_heading_error_at_noise_level_raw_heading_several_degrees_off():
    rng = np.random.default_rng(7)
    psi, m = level_swing(rng)
    res = fit_ellipse_2d(m[:, 0], m[:, 1], H)
    err_cal = wrap_pi(res.heading(m) - psi)
    err_raw = wrap_pi(heading_from_field(m) - psi)
    assert np.sqrt(np.mean(err_cal ** 2)) < 3 * SIGMA / H          # ~ noise / H rad = 0.06 deg
    assert np.max(np.abs(err_raw)) > math.radians(8.0)            # 3354 nT of hard iron on 19010 nT


def test_ellipse_short_arc_refused_with_heading_advice():
    for seed in range(5):
        for noise in (0.0, SIGMA):
            _, m = level_swing(np.random.default_rng(200 + seed), arc_deg=20.0, noise=noise)
            with pytest.raises(ScheduleError, match="heading"):
                fit_ellipse_2d(m[:, 0], m[:, 1], H)


def test_ellipse_half_turn_accepted_but_less_precise():
    rng = np.random.default_rng(3)
    _, m_half = level_swing(rng, arc_deg=200.0)
    _, m_full = level_swing(rng)
    half = fit_ellipse_2d(m_half[:, 0], m_half[:, 1], H)
    full = fit_ellipse_2d(m_full[:, 0], m_full[:, 1], H)
    assert half.coverage_deg_ == pytest.approx(200.0, abs=1.0)
    for k in ("bx", "by"):
        assert half.std_errors_[k] > full.std_errors_[k]
        assert abs(half.params_[k] - {"bx": B2[0], "by": B2[1]}[k]) < 4 * half.std_errors_[k]


def test_ellipse_hyperbola_is_not_an_ellipse():
    t = np.linspace(-1.5, 1.5, 60)
    mx = np.concatenate([H * np.cosh(t), -H * np.cosh(t)])
    my = np.concatenate([H * np.sinh(t), H * np.sinh(t)])
    with pytest.raises(ScheduleError, match="not an ellipse"):
        fit_ellipse_2d(mx, my, H)


def test_ellipse_refuses_too_few_points_and_bad_data():
    _, m = level_swing(np.random.default_rng(4), n=9)
    with pytest.raises(ScheduleError, match="at least 10"):
        fit_ellipse_2d(m[:, 0], m[:, 1], H)
    _, m = level_swing(np.random.default_rng(4))
    m[17, 1] = np.nan
    with pytest.raises(RecordingError, match="NaN"):
        fit_ellipse_2d(m[:, 0], m[:, 1], H)
    with pytest.raises(ValueError, match="nT"):
        fit_ellipse_2d(m[:, 0], m[:, 1], 19010.0)


# ---------------------------------------------------------------------------
# 3-D tumble


def test_ellipsoid_noise_free_recovers_b_and_AAt():
    A, b, B, m = tumble(np.random.default_rng(11), noise=0.0)
    res = fit_ellipsoid_3d(m, F)
    assert res.converged_
    AAt = A @ A.T
    assert np.max(np.abs(res.b_ - b)) <= 1e-9 * np.linalg.norm(b)
    assert np.max(np.abs(res.AAt_ - AAt)) <= 1e-9 * np.linalg.norm(AAt)
    # T = A^-1 upper triangular with a positive diagonal, A recovered up to a rotation
    assert np.allclose(np.tril(res.T_, -1), 0.0) and np.all(np.diag(res.T_) > 0)
    np.testing.assert_allclose(res.A_ @ res.T_, np.eye(3), atol=1e-12)
    R = np.linalg.solve(res.A_, A)          # A = A_hat R
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-9)
    cal = res.apply(m)
    np.testing.assert_allclose(cal, B @ R.T, atol=1e-9 * F)
    np.testing.assert_allclose(np.linalg.norm(cal, axis=1), F, rtol=1e-9)


def test_ellipsoid_noisy_invariants_within_4_standard_errors():
    z = []
    for seed in SEEDS:
        A, b, _, m = tumble(np.random.default_rng(300 + seed))
        res = fit_ellipsoid_3d(m, F)
        assert res.converged_
        zs = np.concatenate([(_upper(res.AAt_) - _upper(A @ A.T)) / _upper(res.AAt_std_), (res.b_ - b) / res.b_std_])
        assert np.all(np.abs(zs) < 4.0), (seed, zs)
        np.testing.assert_allclose(np.sqrt(np.diag(res.invariant_cov_)),
                                   np.concatenate([_upper(res.AAt_std_), res.b_std_]), rtol=1e-12)
        z.extend(zs)
        norm_std = float(np.std(np.linalg.norm(res.apply(m), axis=1)))
        assert SIGMA / 1.5 <= norm_std <= 1.5 * SIGMA, norm_std
        assert res.sigma_ == pytest.approx(SIGMA, rel=0.1)
    rms = float(np.sqrt(np.mean(np.square(z))))
    assert 0.6 <= rms <= 1.5, rms


def test_ellipsoid_bench_fluxgate_model():
    """Data from the bench's FluxgateTriad (volts / nominal sensitivity) give its injected A and b."""
    rng = np.random.default_rng(21)
    triad = FluxgateTriad.from_datasheet(rng, noise_nT_rms=20.0, hard_iron_max_nT=3000.0)
    B = F * random_units(rng, 2000)
    s_nom = 40.0e-3 / 1e-6
    m = triad.output_voltage(B, rng) / s_nom
    k = np.diag(triad.sensitivity_V_per_T / s_nom)
    A = k @ triad.soft_iron @ (np.eye(3) + triad.misalignment_rad)
    b = k @ triad.hard_iron_T
    res = fit_ellipsoid_3d(m, F)
    assert np.all(np.abs((_upper(res.AAt_) - _upper(A @ A.T)) / _upper(res.AAt_std_)) < 4.0)
    assert np.all(np.abs((res.b_ - b) / res.b_std_) < 4.0)


def test_ellipsoid_small_cone_refused():
    for seed in range(5):
        for noise in (0.0, SIGMA):
            rng = np.random.default_rng(400 + seed)
            _, _, _, m = tumble(rng, noise=noise, units=cone_units(rng, 2000, 10.0))
            with pytest.raises(ScheduleError, match="tumble the sensor through more orientations"):
                fit_ellipsoid_3d(m, F)


def test_ellipsoid_level_swing_alone_refused():
    """A level swing only traces a circle of the sphere (dip ~ 67 deg): not enough for 3-D."""
    rng = np.random.default_rng(5)
    psi = np.linspace(0, 2 * np.pi, 720, endpoint=False)
    dip = math.acos(H / F)
    units = np.column_stack([math.cos(dip) * np.cos(psi), -math.cos(dip) * np.sin(psi),
                             np.full(psi.size, math.sin(dip))])
    _, _, _, m = tumble(rng, units=units)
    with pytest.raises(ScheduleError, match="tumble"):
        fit_ellipsoid_3d(m, F)


def test_ellipsoid_refuses_too_few_points_and_nan():
    _, _, _, m = tumble(np.random.default_rng(6), n=19)
    with pytest.raises(ScheduleError, match="at least 20"):
        fit_ellipsoid_3d(m, F)
    _, _, _, m = tumble(np.random.default_rng(6), n=200)
    m[3, 2] = np.nan
    with pytest.raises(RecordingError):
        fit_ellipsoid_3d(m, F)
    with pytest.raises(RecordingError, match=r"\(n, 3\)"):
        fit_ellipsoid_3d(m[:, :2], F)


# ---------------------------------------------------------------------------
# heading-domain compass swing


TRUE_COEF = np.radians([1.5, 3.0, -2.0, 0.8, -0.6])     # A, B, C, D, E [rad]


def _deviation(psi, c=TRUE_COEF):
    return c[0] + c[1] * np.sin(psi) + c[2] * np.cos(psi) + c[3] * np.sin(2 * psi) + c[4] * np.cos(2 * psi)


def _rose(rng, noise_rad):
    psi_true = np.radians(np.arange(0.0, 360.0, 30.0))           # 12 compass-rose marks
    ind = wrap_2pi(psi_true + _deviation(psi_true) + noise_rad * rng.standard_normal(12))
    return psi_true, ind


def test_swing_noise_free_exact_and_inverse():
    psi_true, ind = _rose(np.random.default_rng(0), 0.0)
    assert np.any(ind > np.radians(350))                           # indicated heading wraps past north
    res = compass_swing(psi_true, ind)
    np.testing.assert_allclose(res.coef_, TRUE_COEF, atol=1e-12)
    dense = np.linspace(0, 2 * np.pi, 721)
    np.testing.assert_allclose(res.deviation(dense), _deviation(dense), atol=1e-12)
    back = res.correct(wrap_2pi(dense + _deviation(dense)))
    np.testing.assert_allclose(wrap_pi(back - dense), 0.0, atol=1e-10)
    assert np.all(back >= 0) and np.all(back < 2 * np.pi)


def test_swing_noisy_within_4_standard_errors_and_correct_to_noise_level():
    noise = math.radians(0.2)
    dense = np.linspace(0, 2 * np.pi, 720, endpoint=False)
    ind_dense = wrap_2pi(dense + _deviation(dense))
    raw_rms = float(np.sqrt(np.mean(wrap_pi(ind_dense - dense) ** 2)))
    assert raw_rms > 10 * noise
    for seed in SEEDS:
        rng = np.random.default_rng(500 + seed)
        psi_true, ind = _rose(rng, noise)
        res = compass_swing(psi_true, ind)
        for k, c in zip(SWING_TERMS, TRUE_COEF):
            assert abs(res.params_[k] - c) < 4 * res.std_errors_[k], (seed, k)
        err = wrap_pi(res.correct(ind_dense) - dense)
        # what is left is the estimation error of the 5 terms: rms ~ noise sqrt(5/12)
        assert np.sqrt(np.mean(err ** 2)) < 2 * noise


def test_swing_refuses_few_headings_and_nan():
    psi_true, ind = _rose(np.random.default_rng(1), 0.0)
    with pytest.raises(ScheduleError, match="at least 6"):
        compass_swing(psi_true[:5], ind[:5])
    ind[2] = np.nan
    with pytest.raises(RecordingError):
        compass_swing(psi_true, ind)
    with pytest.raises(RecordingError):
        compass_swing(psi_true, ind[:11])
