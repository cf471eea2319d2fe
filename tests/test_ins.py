"""Strapdown INS against closed-form trajectories on the WGS-84 ellipsoid.

The trajectories' IMU signals are exact (``ins.kinematic_truth``): f_B and w_IB_B include the
Earth rate, transport rate, Coriolis and normal gravity. The INS is second order in the
navigation step T, so its global error must fall by 4 when T halves.
"""
import math

import numpy as np
import pytest
from imurig.flights import earth as E
from imurig.flights import ins

from imurig.kernel.errors import RecordingError

D = np.pi / 180
LAT0, LON0 = 52.0 * D, 4.37 * D


def _z(t):
    return np.zeros((len(t), 3))


def _stationary(T=600.0, rate=100.0):
    return ins.kinematic_truth(T, rate, LAT0, LON0, 10.0, _z, _z,
                               lambda t: np.tile([0.1, -0.2, 1.0], (len(t), 1)), _z)


def _straight(vn, ve, yaw, T=600.0, rate=100.0):
    return ins.kinematic_truth(T, rate, LAT0, LON0, 1000.0, lambda t: np.tile([vn, ve, 0.0], (len(t), 1)),
                               _z, lambda t: np.tile([0.0, 0.02, yaw], (len(t), 1)), _z)


def _turn(T=300.0, rate=100.0, V=120.0, r=3 * D):
    bank = math.atan(V * r / 9.81)

    def v(t):
        return V * np.stack([np.cos(r * t), np.sin(r * t), np.zeros_like(t)], 1)

    def a(t):
        return V * r * np.stack([-np.sin(r * t), np.cos(r * t), np.zeros_like(t)], 1)

    def e(t):
        return np.stack([np.full_like(t, bank), np.zeros_like(t), r * t], 1)

    def de(t):
        return np.stack([np.zeros_like(t), np.zeros_like(t), np.full_like(t, r)], 1)

    return ins.kinematic_truth(T, rate, LAT0, LON0, 3000.0, v, a, e, de)


def _run(tr, K):
    inc = ins.preintegrate(tr.time_s, tr.w_IB_B, tr.f_B, K)
    sol = ins.navigate(inc, ins.state_at(tr, 0))
    idx = np.arange(0, tr.time_s.size, K)[: sol.time_s.size]
    err = ins.nav_errors(sol, tr, idx)
    return {k: float(np.max(np.linalg.norm(v, axis=1))) for k, v in err.items()}


def test_preintegration_constant_rotation_closed_form():
    # constant w, f in B: exact Δv_B = ∫ exp([w t ×]) f dt = fT + ½[θ×]fT + 1/6 [θ×]² fT + O(θ³)
    dt, K = 0.01, 10
    w = np.array([0.3, -0.2, 0.5])
    f = np.array([1.0, 2.0, -9.8])
    t = np.arange(K * 3 + 1) * dt
    inc = ins.preintegrate(t, np.tile(w, (t.size, 1)), np.tile(f, (t.size, 1)), K)
    T = K * dt
    th = w * T
    np.testing.assert_allclose(inc.dtheta_B, np.tile(th, (3, 1)), atol=1e-16)
    S = E.skew(th)
    exact = (np.eye(3) + S / 2 + S @ S / 6 + S @ S @ S / 24) @ f * T
    # second-order algorithm: residual is the 1/6 [θ×]² term, |θ|² |f| T / 6 ≈ 6e-5 m/s
    np.testing.assert_allclose(inc.dv_B[0], exact, atol=abs(th @ th) * np.linalg.norm(f) * T / 6 * 1.01)
    assert np.linalg.norm(inc.dv_B[0] - exact) > 0.5 * abs(th @ th) * np.linalg.norm(f) * T / 6 * 0.1
    assert inc.T_s == pytest.approx(T) and inc.t_s.size == 4


def test_stationary_on_earth_holds_still():
    """The leading residual of the velocity update for a body fixed on the rotating Earth is
    ε = ¼ (Ω cos φ T)² g (the second-order term of the frame-rotation correction), plus a rounding
    floor of 1e-11 m/s². Bound over t: |δv| ≤ ε t, |δp| ≤ ½ ε t², times the vertical channel's
    growth cosh(t/τ), τ = √(R/2g)."""
    tr = _stationary()
    K = 10
    err = _run(tr, K)
    t, T, g = tr.time_s[-1], K / tr.rate_hz, 9.81
    eps = 0.25 * (E.OMEGA_E_RAD_S * math.cos(LAT0) * T) ** 2 * g + 1e-11
    amp = math.cosh(t / math.sqrt(E.A_M / (2 * g)))
    assert err["vel_N_m_s"] < eps * t * amp
    assert err["pos_N_m"] < 0.5 * eps * t ** 2 * amp
    assert err["att_N_rad"] < 1e-11


@pytest.mark.parametrize("vn,ve,yaw", [(100.0, 0.0, 0.0), (0.0, 100.0, np.pi / 2)])
def test_constant_velocity_along_meridian_and_parallel(vn, ve, yaw):
    tr = _straight(vn, ve, yaw)
    err = _run(tr, 10)
    # same leading terms as the stationary case plus the transport rate (ρ = v/R = 1.6e-5 rad/s)
    t, T, g = tr.time_s[-1], 0.1, 9.81
    rate = E.OMEGA_E_RAD_S + 100.0 / E.A_M
    eps = 0.25 * (rate * T) ** 2 * g + 1e-11
    amp = math.cosh(t / math.sqrt(E.A_M / (2 * g)))
    assert err["pos_N_m"] < 0.5 * eps * t ** 2 * amp
    assert err["vel_N_m_s"] < eps * t * amp
    assert err["att_N_rad"] < 1e-10


def test_coordinated_turn_error_is_second_order_in_the_step():
    tr = _turn()
    e1 = _run(tr, 10)      # T = 0.1 s
    e2 = _run(tr, 5)       # T = 0.05 s
    for k in ("pos_N_m", "vel_N_m_s", "att_N_rad"):
        assert 3.5 < e1[k] / e2[k] < 4.5, (k, e1[k], e2[k])
    # absolute level at T = 0.05 s over 300 s of a 3 deg/s turn at 120 m/s
    assert e2["pos_N_m"] < 0.05 and e2["att_N_rad"] < 5e-8


def test_bad_imu_input_refused():
    t = np.arange(11) * 0.01
    w = np.zeros((11, 3))
    f = np.zeros((11, 3))
    w[4, 1] = np.nan
    with pytest.raises(RecordingError, match="NaN"):
        ins.preintegrate(t, w, f, 2)
    with pytest.raises(RecordingError, match="uniform"):
        ins.preintegrate(t ** 2, np.zeros((11, 3)), f, 2)
    with pytest.raises(RecordingError, match="shape"):
        ins.preintegrate(t, np.zeros((11, 2)), f, 2)


def test_held_body_mean_is_the_integral_of_the_turning_body_frame():
    """Flight truth samples (MuJoCo step: f_N held, the body turning at w over Δt): the sample is the
    body-frame mean (1/Δt)∫ exp(−[φ×]s) ds f0 — against a 2000-point midpoint quadrature of the
    rotation (within the rule's own error bound), the small-angle series (to rounding) and the ½[φ×] first order."""
    from imurig.flights.truth import held_body_mean

    rng = np.random.default_rng(3)
    phi = rng.standard_normal((4, 3)) * np.array([[0.3], [0.01], [1e-6], [1e-9]])
    f0 = rng.standard_normal((4, 3)) * 20.0
    got = held_body_mean(phi, f0)
    s = (np.arange(2000) + 0.5) / 2000
    for k in range(4):
        ref = np.mean([E.C_from_q(E.q_from_rotvec(-si * phi[k])) @ f0[k] for si in s], axis=0)
        # midpoint rule error ≤ max|g''|/(24 n²), |g''| ≤ |φ|² |f0|
        tol = (np.linalg.norm(phi[k]) ** 2 / (24 * 2000 ** 2) + 1e-14) * np.linalg.norm(f0[k])
        np.testing.assert_allclose(got[k], ref, rtol=0, atol=tol)
        first = f0[k] - 0.5 * np.cross(phi[k], f0[k])
        assert np.linalg.norm(got[k] - first) <= np.linalg.norm(phi[k]) ** 2 * np.linalg.norm(f0[k]) / 5
