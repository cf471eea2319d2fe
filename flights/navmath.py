"""Plain-float kernels of the navigation equations for the per-epoch loops of the INS and the filter.

At 3 and 4 elements a numpy call costs more than the arithmetic (one ``np.array`` is ~20 float
operations), so the per-epoch maths of :func:`imurig.flights.ins.nav_step` and of the filter's
propagation (:mod:`imurig.flights.ekf_model`) works on Python floats and tuples; the numpy
versions (:mod:`imurig.flights.earth`, vectorised over epochs) stay for everything else.
Vectors are tuples (x, y, z), quaternions (w, x, y, z), matrices 9-tuples in row-major order.
"""
from __future__ import annotations

import math

import numpy as np
from imurig.flights import earth as E

_OMEGA = E.OMEGA_E_RAD_S


def rates(lat: float, h: float, v_n: float, v_e: float) -> tuple:
    """(ω_IE_N (3,), ω_EN_N (3,), g_d, R_N, R_E) at latitude ``lat`` rad, height ``h`` m and
    velocity (v_n, v_e) m/s on WGS-84 (the same formulas as :mod:`imurig.flights.earth`):

        ω_IE = Ω (cos φ, 0, −sin φ),   ω_EN = (v_e/(R_E+h), −v_n/(R_N+h), −v_e tan φ/(R_E+h))
        g_d  = γ(φ) (1 − 2/a (1 + f + m − 2 f sin²φ) h + 3 h²/a²)   (Somigliana, free-air)"""
    s, c = math.sin(lat), math.cos(lat)
    w = 1.0 - E.E2 * s * s
    R_N, R_E = E.A_M * (1.0 - E.E2) / w ** 1.5, E.A_M / math.sqrt(w)
    g0 = E.GAMMA_E_M_S2 * (1.0 + E.K_SOMIGLIANA * s * s) / math.sqrt(w)
    g = g0 * (1.0 - 2.0 / E.A_M * (1.0 + E.F + E.M_GEODETIC - 2.0 * E.F * s * s) * h + 3.0 * h * h / E.A_M ** 2)
    return ((_OMEGA * c, 0.0, -_OMEGA * s), (v_e / (R_E + h), -v_n / (R_N + h), -v_e * s / c / (R_E + h)),
            g, R_N, R_E)


def dcm(q) -> tuple:
    """C_NB(q) (9-tuple, row-major) of the unit quaternion ``q`` = (w, x, y, z)."""
    w, x, y, z = q
    return (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y))


def mat_vec(C, v) -> tuple:
    """C v of a row-major 9-tuple and a 3-vector."""
    x, y, z = v
    return (C[0] * x + C[1] * y + C[2] * z, C[3] * x + C[4] * y + C[5] * z, C[6] * x + C[7] * y + C[8] * z)


def cross(a, b) -> tuple:
    """a × b."""
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def qmul(p, q) -> tuple:
    """Hamilton product p ⊗ q."""
    pw, px, py, pz = p
    qw, qx, qy, qz = q
    return (pw * qw - px * qx - py * qy - pz * qz, pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx, pw * qz + px * qy - py * qx + pz * qw)


def qrot(phi) -> tuple:
    """The quaternion of the rotation vector ``phi`` (rad): (cos(a/2), sin(a/2) φ/a), a = |φ|
    (series below 1e-4 rad)."""
    a = math.sqrt(phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2])
    k = 0.5 - a * a / 48.0 if a < 1e-4 else math.sin(0.5 * a) / a
    return (math.cos(0.5 * a), k * phi[0], k * phi[1], k * phi[2])


def qnormalised(q) -> tuple:
    """q / |q|."""
    s = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return (q[0] / s, q[1] / s, q[2] / s, q[3] / s)


def nav_step(lat0: float, lon0: float, h0: float, v0, q0, dtheta_B, dv_B, T: float, rates0) -> tuple:
    """One step of the navigation equations (:mod:`imurig.flights.ins`, module doc) over T seconds on
    floats: (lat, lon, h, v_N, q_NB) after the body increments ``dtheta_B``, ``dv_B`` from the state
    ``lat0, lon0, h0, v0`` (3,), ``q0`` (4,), with ``rates0`` = :func:`rates` at the start. Mid-interval
    rates from one predictor-corrector pass::

        v_new = v + C Δv − ½ ζ × C Δv + (g_N − (2ω_IE + ω_EN) × v_mid) T,   ζ = (ω_IE + ω_EN)_mid T
        q_new = q(−ζ) ⊗ q ⊗ q(Δθ)"""
    vn0, ve0, vd0 = v0[0], v0[1], v0[2]
    dn, de, dd = mat_vec(dcm(q0), dv_B)          # C Δv_B
    lat_m, h_m, vn, ve, vd = lat0, h0, vn0, ve0, vd0
    vn1, ve1, vd1, h_new = vn0, ve0, vd0, h0
    w_ie, w_en, g, R_N, R_E = rates0
    for it in range(2):                          # predictor, then corrector at the mid-point
        if it == 1:
            w_ie, w_en, g, R_N, R_E = rates(lat_m, h_m, vn, ve)
        zn, ze, zd = (w_ie[0] + w_en[0]) * T, (w_ie[1] + w_en[1]) * T, (w_ie[2] + w_en[2]) * T      # ζ
        an, ae, ad = 2.0 * w_ie[0] + w_en[0], 2.0 * w_ie[1] + w_en[1], 2.0 * w_ie[2] + w_en[2]   # 2ω_IE + ω_EN
        vn1 = vn0 + dn - 0.5 * (ze * dd - zd * de) + (0.0 - (ae * vd - ad * ve)) * T
        ve1 = ve0 + de - 0.5 * (zd * dn - zn * dd) + (0.0 - (ad * vn - an * vd)) * T
        vd1 = vd0 + dd - 0.5 * (zn * de - ze * dn) + (g - (an * ve - ae * vn)) * T
        vn, ve, vd = 0.5 * (vn0 + vn1), 0.5 * (ve0 + ve1), 0.5 * (vd0 + vd1)
        h_new = h0 - vd * T
        h_m = 0.5 * (h0 + h_new)
        lat_new = lat0 + vn / (R_N + h_m) * T
        lat_m = 0.5 * (lat0 + lat_new)
    w_ie, w_en, g, R_N, R_E = rates(lat_m, h_m, vn, ve)
    lon_new = lon0 + ve / ((R_E + h_m) * math.cos(lat_m)) * T
    zeta = (-(w_ie[0] + w_en[0]) * T, -(w_ie[1] + w_en[1]) * T, -(w_ie[2] + w_en[2]) * T)
    q = qnormalised(qmul(qmul(qrot(zeta), q0), qrot(dtheta_B)))
    return lat_new, lon_new, h_new, (vn1, ve1, vd1), q


def ecef(lat: float, lon: float, h: float) -> tuple:
    """WGS-84 ECEF position (m) of one geodetic point (as :func:`imurig.flights.earth.ecef_from_geodetic`)."""
    s, c = math.sin(lat), math.cos(lat)
    R_E = E.A_M / math.sqrt(1.0 - E.E2 * s ** 2)
    return ((R_E + h) * c * math.cos(lon), (R_E + h) * c * math.sin(lon), (R_E * (1.0 - E.E2) + h) * s)


def ned_offset(lat: float, lon: float, h: float, lat0: float, lon0: float, h0: float) -> tuple:
    """NED offset (m) of a point from a reference point on the reference's NED axes,
    C_EN(φ0, λ0)ᵀ (r_E − r_E0) (as :func:`imurig.flights.earth.ned_from_geodetic`)."""
    x, y, z = ecef(lat, lon, h)
    x0, y0, z0 = ecef(lat0, lon0, h0)
    dx, dy, dz = x - x0, y - y0, z - z0
    sl, cl, so, co = math.sin(lat0), math.cos(lat0), math.sin(lon0), math.cos(lon0)
    return (-sl * co * dx - sl * so * dy + cl * dz, -so * dx + co * dy, -cl * co * dx - cl * so * dy - sl * dz)


def inv_small(S: np.ndarray) -> np.ndarray:
    """S⁻¹ of a (1, 1) or (3, 3) innovation covariance by the adjugate, S⁻¹ = adj(S)/det(S) (a
    LAPACK call costs ~10x more at this size); larger S by :func:`numpy.linalg.inv`."""
    m = S.shape[0]
    if m == 1:
        return 1.0 / S
    if m != 3:
        return np.linalg.inv(S)
    a, b, c, d, e, f, g, h, i = S.ravel().tolist()
    A, B, C = e * i - f * h, f * g - d * i, d * h - e * g     # cofactors of the first row
    det = a * A + b * B + c * C
    return np.array([[A, c * h - b * i, b * f - c * e],
                     [B, a * i - c * g, c * d - a * f],
                     [C, b * g - a * h, a * e - b * d]]) / det
