"""The flight truth's per-sample maths (:func:`imurig.flights.truth.truth_from_kinematics`) in one
compiled pass per stage, with numba: the same equations, operation by operation, as the numpy path
(:func:`imurig.flights.truth.held_terms_numpy`, kept as the reference), so both agree to the last bit
or to a few ulp where numpy's vectorised sin/cos/atan2 round differently from the C library's
(tests/test_flight_kernel.py).

Per sample k (module docstring of :mod:`imurig.flights.truth` for the meaning):

    q      = q_NB / |q_NB|  (scalar part ≥ 0);  C_NB = C(q)
    f_N    = dv_N/dt + (2 ω_IE_N + ω_EN_N) × v_N − g_N(φ, h);      f_B = C_NBᵀ f_N
    w_hold = w_NB_B + Δt ẇ_NB_B                          (zoh; w_NB_B otherwise)
    f_B   ← W(Δt w_hold) f_B                              (zoh: the body-frame mean, held_body_mean)
    ζ_N    = nav_frame_turn(φ_k, λ_k, φ_k+1, λ_k+1)  (last sample: Δt (ω_IE_N + ω_EN_N))
    w_IB_B = log(exp(C_NBᵀ ζ_N) exp(Δt w_hold)) / Δt     (zoh; w_hold + C_NBᵀ(ω_IE_N + ω_EN_N) otherwise)
    d_mag  = C_NB l_mag  (the magnetometer's NED offset) -> its geodetic position

and the geodetic track by the trapezoidal rule with the fixed-point latitude iteration of
:func:`imurig.flights.truth.integrate_position`. Powers are written as numpy evaluates them (x**2 as
x*x, other exponents through ``pow``), sums in numpy's order. Compiled on first use and cached on
disk (``cache=True``), as :mod:`imurig.flights.flight_kernel`.
"""
from __future__ import annotations

import math

import numba
import numpy as np

from imurig.flights.earth import (
    A_M,
    E2,
    F,
    GAMMA_E_M_S2,
    K_SOMIGLIANA,
    M_GEODETIC,
    OMEGA_E_RAD_S,
)

_A2 = A_M ** 2


@numba.njit(cache=True, nogil=True)
def _radii(s):
    """:func:`imurig.flights.earth.radii` of one latitude φ, given sin φ: (R_N, R_E)."""
    w = 1.0 - E2 * (s * s)
    return A_M * (1.0 - E2) / w ** 1.5, A_M / math.sqrt(w)


@numba.njit(cache=True, nogil=True)
def _gravity(s, h):
    """:func:`imurig.flights.earth.normal_gravity` γ(φ, h), given sin φ."""
    s2 = s * s
    g0 = GAMMA_E_M_S2 * (1.0 + K_SOMIGLIANA * s2) / math.sqrt(1.0 - E2 * s2)
    return g0 * (1.0 - 2.0 / A_M * (1.0 + F + M_GEODETIC - 2.0 * F * s2) * h + 3.0 * (h * h) / _A2)


@numba.njit(cache=True, nogil=True)
def _cumtrapz(y, dt, y0, out):
    """out = y0 + ∫ y dt by the trapezoidal rule (:func:`imurig.flights.truth._cumtrapz`: a running sum)."""
    acc = 0.0
    out[0] = y0 + 0.0
    for k in range(1, y.shape[0]):
        acc += 0.5 * (y[k] + y[k - 1]) * dt
        out[k] = y0 + acc


@numba.njit(cache=True, nogil=True)
def geodetic_track(v_N, dt, lat0, lon0, h0):
    """:func:`imurig.flights.truth.integrate_position`: (lat, lon, h) of the NED velocity (N, 3)."""
    n = v_N.shape[0]
    y = np.empty(n)
    h, lat, lon = np.empty(n), np.full(n, lat0), np.empty(n)
    for k in range(n):
        y[k] = -v_N[k, 2]
    _cumtrapz(y, dt, h0, h)
    for _ in range(4):
        for k in range(n):
            R_N, _R_E = _radii(math.sin(lat[k]))
            y[k] = v_N[k, 0] / (R_N + h[k])
        _cumtrapz(y, dt, lat0, lat)
    for k in range(n):
        _R_N, R_E = _radii(math.sin(lat[k]))
        y[k] = v_N[k, 1] / ((R_E + h[k]) * math.cos(lat[k]))
    _cumtrapz(y, dt, lon0, lon)
    return lat, lon, h


@numba.njit(cache=True, nogil=True)
def _cross(a0, a1, a2, b0, b1, b2):
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@numba.njit(cache=True, nogil=True)
def _q_from_rotvec(p0, p1, p2):
    """:func:`imurig.flights.earth.q_from_rotvec` of one rotation vector."""
    a = math.sqrt(p0 * p0 + p1 * p1 + p2 * p2)
    if a < 1e-4:
        k = 0.5 - (a * a) / 48.0 + a ** 4.0 / 3840.0
    else:
        k = math.sin(a / 2) / a
    return math.cos(a / 2), k * p0, k * p1, k * p2


@numba.njit(cache=True, nogil=True)
def _rotvec_from_q(w, x, y, z):
    """:func:`imurig.flights.earth.rotvec_from_q` of one quaternion (normalised first)."""
    m = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / m, x / m, y / m, z / m
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    s = math.sqrt(x * x + y * y + z * z)
    k = 2.0 / w if s < 1e-12 else 2.0 * math.atan2(s, w) / s
    return k * x, k * y, k * z


@numba.njit(cache=True, nogil=True)
def _body(C, x0, x1, x2):
    """C_NBᵀ x (the einsum "nji,nj->ni" of one sample)."""
    return (C[0] * x0 + C[3] * x1 + C[6] * x2, C[1] * x0 + C[4] * x1 + C[7] * x2,
            C[2] * x0 + C[5] * x1 + C[8] * x2)


@numba.njit(cache=True, nogil=True)
def _unit_q(q_in, k, q, C):
    """q[k] = q_normalize(q_in[k]); C (9,) = C_from_q(q[k]), row-major."""
    w, x, y, z = q_in[k, 0], q_in[k, 1], q_in[k, 2], q_in[k, 3]
    m = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / m, x / m, y / m, z / m
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    q[k, 0], q[k, 1], q[k, 2], q[k, 3] = w, x, y, z
    _dcm(w, x, y, z, C)


@numba.njit(cache=True, nogil=True)
def _dcm(w, x, y, z, C):
    """C (9,) = :func:`imurig.flights.earth.C_from_q` of a unit quaternion, row-major."""
    C[0], C[1], C[2] = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)
    C[3], C[4], C[5] = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)
    C[6], C[7], C[8] = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)


@numba.njit(cache=True, nogil=True)
def _held_mean(p0, p1, p2, f0, f1, f2):
    """:func:`imurig.flights.truth.held_body_mean` of one sample: W(φ) f0."""
    a = math.sqrt(p0 * p0 + p1 * p1 + p2 * p2)
    if a < 1e-4:
        c1, c2 = 0.5 - (a * a) / 24.0, 1.0 / 6.0 - (a * a) / 120.0
    else:
        c1, c2 = (1.0 - math.cos(a)) / (a * a), (a - math.sin(a)) / a ** 3.0
    x0, x1, x2 = _cross(p0, p1, p2, f0, f1, f2)
    y0, y1, y2 = _cross(p0, p1, p2, x0, x1, x2)
    return f0 - c1 * x0 + c2 * y0, f1 - c1 * x1 + c2 * y1, f2 - c1 * x2 + c2 * y2


@numba.njit(cache=True, nogil=True)
def held_terms(lat, lon, h, v_N, a_N, q_NB, w_NB_B, wdot_NB_B, rate_hz, zoh, lever_mag_B):
    """The per-sample truth (module docstring): (q, f_B, w_IB_B, mag_lat, mag_lon, mag_h)."""
    n = lat.shape[0]
    dt = 1.0 / rate_hz
    q, f_B, w_IB = np.empty((n, 4)), np.empty((n, 3)), np.empty((n, 3))
    mlat, mlon, mh = np.empty(n), np.empty(n), np.empty(n)
    C = np.empty(9)
    l0, l1, l2 = lever_mag_B[0], lever_mag_B[1], lever_mag_B[2]
    for k in range(n):
        _unit_q(q_NB, k, q, C)
        la, hk, vn, ve, vd = lat[k], h[k], v_N[k, 0], v_N[k, 1], v_N[k, 2]
        sin_la, cos_la = math.sin(la), math.cos(la)     # each evaluated once, as the numpy path's values
        R_N, R_E = _radii(sin_la)
        # ω_IE_N = Ω [cos φ, 0, −sin φ] (its zero east term kept below: the numpy path's sums), ω_EN_N
        ie0, ie2 = OMEGA_E_RAD_S * cos_la, OMEGA_E_RAD_S * -sin_la
        en0, en1, en2 = ve / (R_E + hk), -vn / (R_N + hk), -ve * math.tan(la) / (R_E + hk)
        # f_N = dv_N/dt + (2 ω_IE_N + ω_EN_N) × v_N − [0, 0, γ],  f_B = C_NBᵀ f_N
        c0, c1, c2 = _cross(2 * ie0 + en0, 2 * (OMEGA_E_RAD_S * 0.0) + en1, 2 * ie2 + en2, vn, ve, vd)
        fn0, fn1, fn2 = a_N[k, 0] + c0 - 0.0, a_N[k, 1] + c1 - 0.0, a_N[k, 2] + c2 - _gravity(sin_la, hk)
        fb0, fb1, fb2 = _body(C, fn0, fn1, fn2)
        wh0, wh1, wh2 = w_NB_B[k, 0], w_NB_B[k, 1], w_NB_B[k, 2]
        if zoh:   # the rate held over the step, the body-frame mean of f, the inertial rate log(exp ζ exp a)
            wh0 = wh0 + wdot_NB_B[k, 0] / rate_hz
            wh1 = wh1 + wdot_NB_B[k, 1] / rate_hz
            wh2 = wh2 + wdot_NB_B[k, 2] / rate_hz
            fb0, fb1, fb2 = _held_mean(wh0 * dt, wh1 * dt, wh2 * dt, fb0, fb1, fb2)
            if k < n - 1:
                z0, z1, z2 = _nav_turn(la, lon[k], lat[k + 1], lon[k + 1], dt)
            else:
                z0, z1, z2 = (ie0 + en0) * dt, (OMEGA_E_RAD_S * 0.0 + en1) * dt, (ie2 + en2) * dt
            b0, b1, b2 = _body(C, z0, z1, z2)
            qz = _q_from_rotvec(b0 / dt * dt, b1 / dt * dt, b2 / dt * dt)
            qa = _q_from_rotvec(wh0 * dt, wh1 * dt, wh2 * dt)
            r0, r1, r2 = _rotvec_from_q(*_q_mult(qz, qa))
            w_IB[k, 0], w_IB[k, 1], w_IB[k, 2] = r0 / dt, r1 / dt, r2 / dt
        else:
            b0, b1, b2 = _body(C, ie0 + en0, OMEGA_E_RAD_S * 0.0 + en1, ie2 + en2)
            w_IB[k, 0], w_IB[k, 1], w_IB[k, 2] = wh0 + b0, wh1 + b1, wh2 + b2
        f_B[k, 0], f_B[k, 1], f_B[k, 2] = fb0, fb1, fb2
        d0 = C[0] * l0 + C[1] * l1 + C[2] * l2     # C_NB l_mag (matmul's order)
        d1 = C[3] * l0 + C[4] * l1 + C[5] * l2
        d2 = C[6] * l0 + C[7] * l1 + C[8] * l2
        mlat[k], mlon[k], mh[k] = la + d0 / (R_N + hk), lon[k] + d1 / ((R_E + hk) * cos_la), hk - d2
    return q, f_B, w_IB, mlat, mlon, mh


@numba.njit(cache=True, nogil=True)
def _q_mult(p, q):
    pw, px, py, pz = p
    qw, qx, qy, qz = q
    return (pw * qw - px * qx - py * qy - pz * qz, pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx, pw * qz + px * qy - py * qx + pz * qw)


@numba.njit(cache=True, nogil=True)
def _nav_turn(lat0, lon0, lat1, lon1, dt):
    """:func:`imurig.flights.earth.nav_frame_turn` of one step."""
    al = 0.5 * (lon1 - lon0 + OMEGA_E_RAD_S * dt)
    d, m = 0.5 * (lat1 - lat0), 0.5 * (lat0 + lat1)
    ca, sa = math.cos(al), math.sin(al)
    return _rotvec_from_q(ca * math.cos(d), sa * math.cos(m), -ca * math.sin(d), -sa * math.sin(m))


@numba.njit(cache=True, nogil=True)
def to_body(q, x_N):
    """C_NBᵀ x_N (N, 3) with C_NB = C(q) for unit quaternions q (N, 4)."""
    n = q.shape[0]
    out = np.empty((n, 3))
    C = np.empty(9)
    for k in range(n):
        _dcm(q[k, 0], q[k, 1], q[k, 2], q[k, 3], C)
        out[k, 0], out[k, 1], out[k, 2] = _body(C, x_N[k, 0], x_N[k, 1], x_N[k, 2])
    return out
