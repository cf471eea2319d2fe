"""The per-sample steps of the strapdown mechanisation :func:`imurig.flights.truth.mechanise` (the
truth's self-check), on Python floats with the kernels of :mod:`imurig.flights.navmath`: at 3 and 4
elements a numpy call costs more than the arithmetic (~10x less CPU than the numpy versions of
:mod:`imurig.flights.earth`, the same results to rounding). A state is (φ, λ, h, v_N (3,), q_NB (4,)).
"""
from __future__ import annotations

import math

import numpy as np
from imurig.flights import earth
from imurig.flights import navmath as nm


def _vdot(f, la, hh, vv, qq):
    """(dv_N/dt, C_NB (9-tuple), ω_IE + ω_EN) of :func:`imurig.flights.truth.mechanise` at one point, on floats."""
    C = nm.dcm(qq)
    wie, wen, g, _, _ = nm.rates(la, hh, vv[0], vv[1])
    Cf = nm.mat_vec(C, f)
    cor = nm.cross((2 * wie[0] + wen[0], 2 * wie[1] + wen[1], 2 * wie[2] + wen[2]), vv)
    a = (Cf[0] - cor[0], Cf[1] - cor[1], Cf[2] - cor[2] + g)
    return a, C, (wie[0] + wen[0], wie[1] + wen[1], wie[2] + wen[2])


def _radii(la):
    *_, R_N, R_E = nm.rates(la, 0.0, 0.0, 0.0)
    return R_N, R_E


def _pos_step(st, v1, dt):
    """(φ, λ, h) after a step from ``st`` = (φ, λ, h, v, q) to the velocity v1 (trapezoid, as the truth)."""
    la0, lo0, h0, v0 = st[0], st[1], st[2], st[3]
    la1, h1 = la0, h0 - 0.5 * dt * (v0[2] + v1[2])
    R_N0, R_E0 = _radii(la0)
    for _ in range(3):
        R_N1, _ = _radii(la1)
        la1 = la0 + 0.5 * dt * (v0[0] / (R_N0 + h0) + v1[0] / (R_N1 + h1))
    _, R_E1 = _radii(la1)
    lo1 = lo0 + 0.5 * dt * (v0[1] / ((R_E0 + h0) * math.cos(la0)) + v1[1] / ((R_E1 + h1) * math.cos(la1)))
    return la1, lo1, h1


def _unit(qq):
    """q / |q| with a non-negative scalar part (as :func:`imurig.flights.earth.q_normalize`)."""
    qq = nm.qnormalised(qq)
    return qq if qq[0] >= 0.0 else (-qq[0], -qq[1], -qq[2], -qq[3])


def _transpose_times(C, x):
    """Cᵀ x of a row-major 9-tuple."""
    return (C[0] * x[0] + C[3] * x[1] + C[6] * x[2], C[1] * x[0] + C[4] * x[1] + C[7] * x[2],
            C[2] * x[0] + C[5] * x[1] + C[8] * x[2])


def euler_step(st, f, w, dt, held):
    """One step of :func:`imurig.flights.truth.mechanise`'s ``"euler"`` scheme."""
    la0, lo0, _, v0, q0 = st
    a0, C0, wn0 = _vdot(f, la0, st[2], v0, q0)
    v1 = (v0[0] + dt * a0[0], v0[1] + dt * a0[1], v0[2] + dt * a0[2])
    la1, lo1, h1 = _pos_step(st, v1, dt)
    if not held:
        wnb = _transpose_times(C0, wn0)
        return la1, lo1, h1, v1, _unit(nm.qmul(q0, nm.qrot((dt * (w[0] - wnb[0]), dt * (w[1] - wnb[1]),
                                                                  dt * (w[2] - wnb[2])))))
    # Δθ = log(exp(ζ_B) exp(a)) (truth.held_inertial_rate), ζ the frame's exact turn: the body's own a
    zeta_B = _transpose_times(C0, _frame_turn(la0, lo0, la1, lo1, dt))
    zq = nm.qrot(zeta_B)
    dq = nm.qmul((zq[0], -zq[1], -zq[2], -zq[3]), nm.qrot((dt * w[0], dt * w[1], dt * w[2])))
    q1 = _unit(nm.qmul(q0, dq))
    # the sample is the body-frame mean over a step that holds f_N (truth.held_body_mean): f = W f0
    f0 = np.linalg.solve(_held_mean_matrix(_rotvec(_unit(dq))), f).tolist()
    d = nm.mat_vec(C0, (f0[0] - f[0], f0[1] - f[1], f0[2] - f[2]))
    v1 = (v0[0] + dt * (a0[0] + d[0]), v0[1] + dt * (a0[1] + d[1]), v0[2] + dt * (a0[2] + d[2]))
    la1, lo1, h1 = _pos_step(st, v1, dt)
    return la1, lo1, h1, v1, q1


def _rotvec(qq):
    """Rotation vector of a unit quaternion with non-negative scalar part (:func:`earth.rotvec_from_q`)."""
    s = math.sqrt(qq[1] * qq[1] + qq[2] * qq[2] + qq[3] * qq[3])
    k = 2.0 / qq[0] if s < 1e-12 else 2.0 * math.atan2(s, qq[0]) / s
    return (k * qq[1], k * qq[2], k * qq[3])


def _held_mean_matrix(phi):
    """W(φ) (3, 3) of :func:`imurig.flights.truth.held_body_mean`:
    I − (1 − cos a)/a² [φ×] + (a − sin a)/a³ [φ×]², a = |φ|."""
    a = math.sqrt(phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2])
    if a < 1e-4:
        c1, c2 = 0.5 - a * a / 24.0, 1.0 / 6.0 - a * a / 120.0
    else:
        c1, c2 = (1.0 - math.cos(a)) / a ** 2, (a - math.sin(a)) / a ** 3
    S = np.array([[0.0, -phi[2], phi[1]], [phi[2], 0.0, -phi[0]], [-phi[1], phi[0], 0.0]])
    return np.eye(3) - c1 * S + c2 * (S @ S)


def _frame_turn(la0, lo0, la1, lo1, dt):
    """ζ_N of :func:`earth.nav_frame_turn` at one step, on floats: the closed-form quaternion of
    C = C_EN(φ0, λ0)ᵀ R_z(Ω dt)ᵀ C_EN(φ1, λ1) and its rotation vector."""
    al = 0.5 * (lo1 - lo0 + earth.OMEGA_E_RAD_S * dt)
    d, m = 0.5 * (la1 - la0), 0.5 * (la0 + la1)
    ca, sa = math.cos(al), math.sin(al)
    return _rotvec(_unit((ca * math.cos(d), sa * math.cos(m), -ca * math.sin(d), -sa * math.sin(m))))


def trapezoid_step(st, f, f1, w, w1, dt):
    """One step of :func:`imurig.flights.truth.mechanise`'s ``"trapezoid"`` scheme (samples k and k+1: f, f1, w, w1)."""
    la0, lo0, h0, v0, q0 = st
    a0, C0, wn0 = _vdot(f, la0, h0, v0, q0)
    t0 = _transpose_times(C0, wn0)
    wnb0 = (w[0] - t0[0], w[1] - t0[1], w[2] - t0[2])
    q_mid = nm.qmul(q0, nm.qrot((0.5 * dt * wnb0[0], 0.5 * dt * wnb0[1], 0.5 * dt * wnb0[2])))
    t1 = _transpose_times(nm.dcm(q_mid), wn0)
    wnb1 = (w1[0] - t1[0], w1[1] - t1[1], w1[2] - t1[2])
    q1 = _unit(nm.qmul(q0, nm.qrot(tuple(0.5 * dt * (x + y) for x, y in zip(wnb0, wnb1)))))
    vp = (v0[0] + dt * a0[0], v0[1] + dt * a0[1], v0[2] + dt * a0[2])
    la1, _, h1 = _pos_step(st, vp, dt)
    a1, _, _ = _vdot(f1, la1, h1, vp, q1)
    v1 = tuple(v0[i] + 0.5 * dt * (a0[i] + a1[i]) for i in range(3))
    la1, lo1, h1 = _pos_step(st, v1, dt)
    return la1, lo1, h1, v1, q1
