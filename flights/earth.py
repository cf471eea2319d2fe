"""The Earth for navigation: WGS-84 ellipsoid, normal gravity, Earth and transport rates, frames.

Frames: ``E`` Earth-centred Earth-fixed (ECEF), ``N`` local navigation frame north-east-down
(NED) at the vehicle, ``B`` body front-right-down (FRD), ``I`` inertial.
Quaternions are scalar-first ``(w, x, y, z)``; ``q_NB`` maps body to navigation coordinates,
``x_N = C_from_q(q_NB) @ x_B``. Euler angles are the aerospace z-y-x sequence
(yaw ψ, pitch θ, roll φ): ``C_NB = Rz(ψ) Ry(θ) Rx(φ)``.

Every function is vectorised: scalar arguments or arrays of shape ``(N,)`` (vectors ``(N, 3)``,
quaternions ``(N, 4)``, matrices ``(N, 3, 3)``).

What is modelled, and to what accuracy:

- the WGS-84 ellipsoid (a, f) and the Earth rate Ω (NIMA TR8350.2);
- normal gravity: Somigliana's closed form on the ellipsoid (exact for the WGS-84 level
  ellipsoid, <1e-9 relative), with the second-order free-air height correction of TR8350.2
  eq. 4-3 (error < 1e-6 m/s² below 20 km). It points along the local ellipsoidal normal
  (``g_N = [0, 0, γ]``); the deflection of the vertical of the real geoid (≈ 1e-4 m/s²
  horizontal, a few arcsec) and gravity anomalies (≈ 3e-4 m/s²) are not modelled;
- the Earth rate ω_IE and the transport rate ω_EN (exact for the ellipsoid);
- geodetic <-> ECEF: exact forward; the inverse by Bowring's iteration (5 passes,
  < 1e-9 m below 1000 km altitude).
"""
from __future__ import annotations

import numpy as np

from imurig.kernel.quaternion import q_conj, q_mult  # noqa: F401  (this module's names too)

# --- WGS-84 defining and derived constants (NIMA TR8350.2, 3rd ed.) ---------------------------
A_M = 6378137.0                       # semi-major axis, m
F = 1.0 / 298.257223563               # flattening
OMEGA_E_RAD_S = 7.292115e-5           # Earth rotation rate, rad/s
GM_M3_S2 = 3.986004418e14             # geocentric gravitational constant, m^3/s^2
B_M = A_M * (1.0 - F)                 # semi-minor axis, m
E2 = F * (2.0 - F)                    # first eccentricity squared
EP2 = E2 / (1.0 - E2)                 # second eccentricity squared
GAMMA_E_M_S2 = 9.7803253359           # normal gravity at the equator, m/s^2
GAMMA_P_M_S2 = 9.8321849378           # normal gravity at the poles, m/s^2
K_SOMIGLIANA = (B_M * GAMMA_P_M_S2) / (A_M * GAMMA_E_M_S2) - 1.0   # 0.00193185265241
M_GEODETIC = OMEGA_E_RAD_S ** 2 * A_M ** 2 * B_M / GM_M3_S2        # 0.00344978650684


# --- radii, gravity, rates -------------------------------------------------------------------
def radii(lat_rad):
    """Meridian and transverse radii of curvature ``(R_N, R_E)``, m, each shaped like ``lat_rad``.

    R_N = a (1 − e²) / (1 − e² sin²φ)^{3/2},  R_E = a / (1 − e² sin²φ)^{1/2}.
    """
    s2 = np.sin(lat_rad) ** 2
    w = 1.0 - E2 * s2
    return A_M * (1.0 - E2) / w ** 1.5, A_M / np.sqrt(w)


def normal_gravity(lat_rad, h_m=0.0):
    """Magnitude of WGS-84 normal gravity γ(φ, h), m/s² (gravitation plus centrifugal).

    γ0 = γ_e (1 + k sin²φ) / √(1 − e² sin²φ)  (Somigliana);
    γ = γ0 [1 − 2/a (1 + f + m − 2 f sin²φ) h + 3 h²/a²]  (TR8350.2 eq. 4-3).
    """
    s2 = np.sin(lat_rad) ** 2
    g0 = GAMMA_E_M_S2 * (1.0 + K_SOMIGLIANA * s2) / np.sqrt(1.0 - E2 * s2)
    h = np.asarray(h_m, dtype=float)
    return g0 * (1.0 - 2.0 / A_M * (1.0 + F + M_GEODETIC - 2.0 * F * s2) * h + 3.0 * h ** 2 / A_M ** 2)


def gravity_N(lat_rad, h_m=0.0):
    """Normal gravity vector in NED, m/s², shape (..., 3): ``[0, 0, γ(φ, h)]``."""
    g = np.asarray(normal_gravity(lat_rad, h_m), dtype=float)
    z = np.zeros_like(g)
    return np.stack([z, z, g], axis=-1)


def omega_IE_N(lat_rad):
    """Earth rate in NED, rad/s, shape (..., 3): Ω [cos φ, 0, −sin φ]."""
    lat = np.asarray(lat_rad, dtype=float)
    return OMEGA_E_RAD_S * np.stack([np.cos(lat), np.zeros_like(lat), -np.sin(lat)], axis=-1)


def omega_EN_N(lat_rad, h_m, v_N):
    """Transport rate (N w.r.t. E) in NED, rad/s, shape (..., 3).

    ω_EN = [v_E/(R_E+h), −v_N/(R_N+h), −v_E tanφ/(R_E+h)], ``v_N`` (..., 3) m/s NED.
    """
    R_N, R_E = radii(lat_rad)
    v = np.asarray(v_N, dtype=float)
    h = np.asarray(h_m, dtype=float)
    vn, ve = v[..., 0], v[..., 1]
    return np.stack([ve / (R_E + h), -vn / (R_N + h), -ve * np.tan(lat_rad) / (R_E + h)], axis=-1)


def geodetic_rates(lat_rad, h_m, v_N):
    """(dφ/dt, dλ/dt, dh/dt) from the NED velocity: v_n/(R_N+h), v_e/((R_E+h)cosφ), −v_d."""
    R_N, R_E = radii(lat_rad)
    v = np.asarray(v_N, dtype=float)
    return (v[..., 0] / (R_N + h_m), v[..., 1] / ((R_E + h_m) * np.cos(lat_rad)), -v[..., 2])


# --- geodetic <-> ECEF, local NED ---------------------------------------------------------------
def ecef_from_geodetic(lat_rad, lon_rad, h_m):
    """ECEF position, m, shape (..., 3), of WGS-84 geodetic latitude, longitude (rad), height (m)."""
    _, R_E = radii(lat_rad)
    cl, sl = np.cos(lat_rad), np.sin(lat_rad)
    return np.stack([(R_E + h_m) * cl * np.cos(lon_rad), (R_E + h_m) * cl * np.sin(lon_rad),
                     (R_E * (1.0 - E2) + h_m) * sl], axis=-1)


def geodetic_from_ecef(r_E):
    """WGS-84 ``(lat_rad, lon_rad, h_m)`` of ECEF positions ``r_E`` (..., 3) m (Bowring, 5 passes)."""
    r = np.asarray(r_E, dtype=float)
    x, y, z = r[..., 0], r[..., 1], r[..., 2]
    p = np.hypot(x, y)
    lon = np.arctan2(y, x)
    beta = np.arctan2(z, (1.0 - F) * p)                 # reduced latitude, first guess
    for _ in range(5):
        lat = np.arctan2(z + EP2 * B_M * np.sin(beta) ** 3, p - E2 * A_M * np.cos(beta) ** 3)
        beta = np.arctan2((1.0 - F) * np.sin(lat), np.cos(lat))
    _, R_E = radii(lat)
    sl, cl = np.sin(lat), np.cos(lat)
    h = p * cl + z * sl - A_M ** 2 / R_E                 # exact for any latitude (Bowring 1985)
    return lat, lon, h


def C_EN(lat_rad, lon_rad):
    """DCM from NED to ECEF axes, shape (..., 3, 3): ``x_E = C_EN @ x_N``."""
    sl, cl = np.sin(lat_rad), np.cos(lat_rad)
    so, co = np.sin(lon_rad), np.cos(lon_rad)
    row0 = np.stack([-sl * co, -so, -cl * co], axis=-1)
    row1 = np.stack([-sl * so, co, -cl * so], axis=-1)
    row2 = np.stack([cl, np.zeros_like(cl * co), -sl], axis=-1)
    return np.stack([row0, row1, row2], axis=-2)


def nav_frame_turn(lat0_rad, lon0_rad, lat1_rad, lon1_rad, dt_s: float):
    """Rotation vector ζ_N (..., 3) rad of the NED frame over a step of ``dt_s`` relative to inertial
    space, in the axes of the first frame: exp([ζ_N×]) = C_N0N1 = C_EN(φ0, λ0)ᵀ R_z(Ω dt)ᵀ C_EN(φ1, λ1),
    R_z(Ω dt) taking E coordinates of an inertially fixed vector from t0 to t1. Exact for any path
    between the two positions; to first order ζ_N = dt (ω_IE_N + ω_EN_N).

    In closed form, with C_EN(φ, λ) = R_z(λ) R_y(−φ − π/2), its quaternion is

        q_N0N1 = [cos α cos δ, sin α cos φ̄, −cos α sin δ, −sin α sin φ̄],
        α = (λ1 − λ0 + Ω dt)/2,  δ = (φ1 − φ0)/2,  φ̄ = (φ0 + φ1)/2,

    free of the cancellation of the matrix product (whose small off-diagonal terms are differences of
    O(1) products), and a few vector operations instead of two (N, 3, 3) stacks."""
    lat0, lat1 = np.asarray(lat0_rad, dtype=float), np.asarray(lat1_rad, dtype=float)
    al = 0.5 * (np.asarray(lon1_rad, dtype=float) - lon0_rad + OMEGA_E_RAD_S * dt_s)
    d, m = 0.5 * (lat1 - lat0), 0.5 * (lat0 + lat1)
    ca, sa = np.cos(al), np.sin(al)
    return rotvec_from_q(np.stack([ca * np.cos(d), sa * np.cos(m), -ca * np.sin(d), -sa * np.sin(m)], axis=-1))


def ned_from_geodetic(lat_rad, lon_rad, h_m, lat0_rad, lon0_rad, h0_m):
    """NED offsets, m (..., 3), of points from a reference point, on the reference's NED axes."""
    d_E = ecef_from_geodetic(lat_rad, lon_rad, h_m) - ecef_from_geodetic(lat0_rad, lon0_rad, h0_m)
    C = C_EN(lat0_rad, lon0_rad)
    return np.einsum("...ji,...j->...i", C, d_E)


def geodetic_from_ned(d_N, lat0_rad, lon0_rad, h0_m):
    """Inverse of :func:`ned_from_geodetic`: ``(lat, lon, h)`` of NED offsets ``d_N`` (..., 3) m."""
    C = C_EN(lat0_rad, lon0_rad)
    r_E = ecef_from_geodetic(lat0_rad, lon0_rad, h0_m) + np.einsum("...ij,...j->...i", C, d_N)
    return geodetic_from_ecef(r_E)


# --- rotations ----------------------------------------------------------------------------------
def skew(v):
    """Cross-product matrix [v×], shape (..., 3, 3), of vectors (..., 3)."""
    v = np.asarray(v, dtype=float)
    z = np.zeros_like(v[..., 0])
    return np.stack([np.stack([z, -v[..., 2], v[..., 1]], -1),
                     np.stack([v[..., 2], z, -v[..., 0]], -1),
                     np.stack([-v[..., 1], v[..., 0], z], -1)], -2)


def q_normalize(q):
    """Unit quaternion with non-negative scalar part, (..., 4)."""
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0.0, -q, q)


def C_from_q(q):
    """DCM (..., 3, 3) of a unit quaternion (..., 4) wxyz: ``C(q_NB) = C_NB``."""
    q = np.asarray(q, dtype=float)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], -2)


def q_from_C(C):
    """Unit quaternion (..., 4) wxyz of a DCM (..., 3, 3) (Shepperd's method, branch-free pick)."""
    C = np.asarray(C, dtype=float)
    tr = C[..., 0, 0] + C[..., 1, 1] + C[..., 2, 2]
    cand = np.stack([
        np.stack([1 + tr, C[..., 2, 1] - C[..., 1, 2], C[..., 0, 2] - C[..., 2, 0], C[..., 1, 0] - C[..., 0, 1]], -1),
        np.stack([C[..., 2, 1] - C[..., 1, 2], 1 + 2 * C[..., 0, 0] - tr, C[..., 0, 1] + C[..., 1, 0], C[..., 0, 2] + C[..., 2, 0]], -1),
        np.stack([C[..., 0, 2] - C[..., 2, 0], C[..., 0, 1] + C[..., 1, 0], 1 + 2 * C[..., 1, 1] - tr, C[..., 1, 2] + C[..., 2, 1]], -1),
        np.stack([C[..., 1, 0] - C[..., 0, 1], C[..., 0, 2] + C[..., 2, 0], C[..., 1, 2] + C[..., 2, 1], 1 + 2 * C[..., 2, 2] - tr], -1),
    ], -2)                                                  # (..., 4 candidates, 4)
    diag = np.stack([tr, C[..., 0, 0], C[..., 1, 1], C[..., 2, 2]], -1)
    k = np.argmax(diag, axis=-1)
    q = np.take_along_axis(cand, k[..., None, None], axis=-2)[..., 0, :]
    return q_normalize(q)


def q_from_euler(roll_rad, pitch_rad, yaw_rad):
    """Quaternion q_NB (..., 4) of z-y-x Euler angles: C_NB = Rz(yaw) Ry(pitch) Rx(roll)."""
    cr, sr = np.cos(np.asarray(roll_rad) / 2), np.sin(np.asarray(roll_rad) / 2)
    cp, sp = np.cos(np.asarray(pitch_rad) / 2), np.sin(np.asarray(pitch_rad) / 2)
    cy, sy = np.cos(np.asarray(yaw_rad) / 2), np.sin(np.asarray(yaw_rad) / 2)
    return np.stack([cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
                     cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy], axis=-1)


def euler_from_C(C_NB):
    """(roll, pitch, yaw) rad of a DCM C_NB (..., 3, 3); yaw in (−π, π]."""
    C = np.asarray(C_NB, dtype=float)
    roll = np.arctan2(C[..., 2, 1], C[..., 2, 2])
    pitch = -np.arcsin(np.clip(C[..., 2, 0], -1.0, 1.0))
    yaw = np.arctan2(C[..., 1, 0], C[..., 0, 0])
    return roll, pitch, yaw


def euler_from_q(q_NB):
    """(roll, pitch, yaw) rad of q_NB (..., 4) wxyz; inverse of :func:`q_from_euler`."""
    return euler_from_C(C_from_q(q_NB))


def q_from_rotvec(phi):
    """Quaternion (..., 4) of a rotation vector φ (..., 3) rad: [cos(|φ|/2), sin(|φ|/2) φ/|φ|].

    Uses the series sin(x/2)/x = 1/2 − x²/48 + x⁴/3840 below 1e-4 rad (no 0/0).
    """
    phi = np.asarray(phi, dtype=float)
    a = np.linalg.norm(phi, axis=-1)
    small = a < 1e-4
    a_safe = np.where(small, 1.0, a)
    k = np.where(small, 0.5 - a ** 2 / 48.0 + a ** 4 / 3840.0, np.sin(a_safe / 2) / a_safe)
    return np.concatenate([np.cos(a / 2)[..., None], k[..., None] * phi], axis=-1)


def rotvec_from_q(q):
    """Rotation vector (..., 3) rad of a unit quaternion (..., 4); inverse of :func:`q_from_rotvec`."""
    q = q_normalize(q)
    s = np.linalg.norm(q[..., 1:], axis=-1)
    a = 2.0 * np.arctan2(s, q[..., 0])
    small = s < 1e-12
    k = np.where(small, 2.0 / np.where(small, 1.0, q[..., 0]), a / np.where(small, 1.0, s))
    return k[..., None] * q[..., 1:]


def wrap_pi(a):
    """Angle(s) wrapped to [−π, π)."""
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi
