"""The flight truth's f_B and w_IB_B integrated by a strapdown that is not the project's own.

The project's mechanisation (``imurig.flights.truth.mechanise``) is written with the same
conventions as the truth, so it cannot see a convention the truth gets wrong: before, the truth's
w_IB_B was the plain sum of the body's turn and the navigation frame's, leaving out the ½ ζ × a
term of the held step, and an independent strapdown drifted 4.4 m over the 15-min flight.

Here a textbook Earth-fixed (ECEF) mechanisation written from scratch (Groves, *Principles of
GNSS, Inertial and Multisensor Integrated Navigation Systems*, 2nd ed., §5.2; its own WGS-84
constants, geodetic conversions, rotation matrices, and the standard ½ Δθ × Δv rotation
correction of a velocity increment) integrates the ideal IMU data of a flight:

    C_EB,k+1 = R_z(Ω Δt) C_EB,k exp([Δθ_k ×]),            Δθ_k = Δt w_IB_B,k
    v_E,k+1  = v_E,k + C_EB,k (Δv_k + ½ Δθ_k × Δv_k) + (g_E(r_k) − 2 Ω_IE × v_E,k) Δt,   Δv_k = Δt f_B,k
    r_E,k+1  = r_E,k + ½ Δt (v_E,k + v_E,k+1)

Nothing of ``imurig.flights`` is used but the truth itself. Bounds:
- attitude: the update is exact for a held rate, so only rounding remains, ≤ 10 n ε rad;
- position: the ½ Δθ × Δv correction truncates W(a)⁻¹ = I + ½[a×] + [a×]²/12 + ..., so each step
  leaves at most |a_k|² |f_k| Δt / 12 of velocity (a_k = Δθ_k); E-frame forward Euler of the
  Coriolis and transport terms leaves O(Δt² |ω_IN| |dv/dt|) per step; each velocity error
  integrates over the time left.
"""
from __future__ import annotations

import math

import numpy as np

A_M = 6378137.0
F = 1.0 / 298.257223563
E2 = F * (2.0 - F)
OMEGA = 7.292115e-5
GAMMA_E = 9.7803253359
K_SOM = 0.00193185265241
GM = 3.986004418e14
M_GEOD = OMEGA ** 2 * A_M ** 2 * A_M * (1.0 - F) / GM


def ecef(lat, lon, h):
    n = A_M / np.sqrt(1.0 - E2 * np.sin(lat) ** 2)
    return np.stack([(n + h) * np.cos(lat) * np.cos(lon), (n + h) * np.cos(lat) * np.sin(lon),
                     (n * (1.0 - E2) + h) * np.sin(lat)], axis=-1)


def geodetic(r):
    x, y, z = r
    p = math.hypot(x, y)
    lat, h = math.atan2(z, p * (1.0 - E2)), 0.0
    for _ in range(6):
        n = A_M / math.sqrt(1.0 - E2 * math.sin(lat) ** 2)
        h = p / math.cos(lat) - n
        lat = math.atan2(z, p * (1.0 - E2 * n / (n + h)))
    return lat, math.atan2(y, x), h


def ned_to_ecef(lat, lon):
    sl, cl, so, co = math.sin(lat), math.cos(lat), math.sin(lon), math.cos(lon)
    return np.array([[-sl * co, -so, -cl * co], [-sl * so, co, -cl * so], [cl, 0.0, -sl]])


def gravity_up(lat, h):
    """WGS-84 normal gravity (Somigliana with the second-order height term), m/s²."""
    s2 = math.sin(lat) ** 2
    g0 = GAMMA_E * (1.0 + K_SOM * s2) / math.sqrt(1.0 - E2 * s2)
    return g0 * (1.0 - 2.0 / A_M * (1.0 + F + M_GEOD - 2.0 * F * s2) * h + 3.0 * h * h / A_M ** 2)


def dcm_of_quaternion(q):
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def exp_so3(phi):
    a = math.sqrt(float(phi @ phi))
    k = np.array([[0.0, -phi[2], phi[1]], [phi[2], 0.0, -phi[0]], [-phi[1], phi[0], 0.0]])
    if a < 1e-6:
        return np.eye(3) + k + k @ k * (0.5 - a * a / 24.0)
    return np.eye(3) + math.sin(a) / a * k + (1.0 - math.cos(a)) / a ** 2 * k @ k


def strapdown_ecef(t_s, w_IB_B, f_B, lat0, lon0, h0, v0_N, q0_NB):
    """Positions r_E (n, 3) m and attitudes C_EB (n, 3, 3) of the ECEF mechanisation above."""
    dt = float(t_s[1] - t_s[0])
    c, s = math.cos(OMEGA * dt), math.sin(OMEGA * dt)
    r_z = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])      # E_k coordinates -> E_k+1
    w_ie_E = np.array([0.0, 0.0, OMEGA])
    c_en = ned_to_ecef(lat0, lon0)
    r_E, v_E, C_EB = ecef(lat0, lon0, h0), c_en @ v0_N, c_en @ dcm_of_quaternion(q0_NB)
    rs, cs = [r_E], [C_EB]
    for k in range(t_s.size - 1):
        dth, dv = w_IB_B[k] * dt, f_B[k] * dt
        lat, lon, h = geodetic(r_E)
        g_E = ned_to_ecef(lat, lon) @ np.array([0.0, 0.0, gravity_up(lat, h)])
        v1 = v_E + C_EB @ (dv + 0.5 * np.cross(dth, dv)) + (g_E - 2.0 * np.cross(w_ie_E, v_E)) * dt
        r_E, v_E = r_E + 0.5 * dt * (v_E + v1), v1
        C_EB = r_z @ C_EB @ exp_so3(dth)
        rs.append(r_E)
        cs.append(C_EB)
    return np.array(rs), np.array(cs)


def attitude_error_rad(C_EB, truth, every=25):
    errs = []
    for k in range(0, truth.n, every):
        ct = ned_to_ecef(truth.lat_rad[k], truth.lon_rad[k]) @ dcm_of_quaternion(truth.q_NB[k])
        e = C_EB[k] @ ct.T
        errs.append(0.5 * math.sqrt((e[2, 1] - e[1, 2]) ** 2 + (e[0, 2] - e[2, 0]) ** 2 + (e[1, 0] - e[0, 1]) ** 2))
    return max(errs)


def test_an_independent_strapdown_flies_the_truth(short_flight):
    tr = short_flight
    args = (tr.time_s, tr.w_IB_B, tr.f_B, tr.lat_rad[0], tr.lon_rad[0], tr.h_m[0], tr.v_N[0], tr.q_NB[0])
    r_E, C_EB = strapdown_ecef(*args)
    dt, n = 1.0 / tr.rate_hz, tr.n
    # attitude: exact update, rounding only
    att = attitude_error_rad(C_EB, tr)
    assert att <= 10 * n * np.finfo(float).eps
    # position: the rotation correction's truncation and the frame terms' Euler steps, integrated
    a = np.linalg.norm(tr.w_IB_B, axis=1) * dt
    acc = np.linalg.norm(np.gradient(tr.v_N, dt, axis=0), axis=1)
    per_step = a ** 2 * np.linalg.norm(tr.f_B, axis=1) * dt / 12 + dt ** 2 * 2 * OMEGA * acc
    bound = float(np.sum(per_step[:-1] * (tr.time_s[-1] - tr.time_s[:-1])))
    err = np.linalg.norm(r_E - ecef(tr.lat_rad, tr.lon_rad, tr.h_m), axis=1)
    assert err.max() <= bound

    # the test can fail: the plain-sum convention (the truth before) is 1000x off the attitude bound
    from imurig.flights import earth      # only to rebuild the old convention's rate from the truth
    C_NB = earth.C_from_q(tr.q_NB)
    w_in_B = np.einsum("nji,nj->ni", C_NB, earth.omega_IE_N(tr.lat_rad) + earth.omega_EN_N(tr.lat_rad, tr.h_m, tr.v_N))
    zeta = earth.q_from_rotvec(dt * w_in_B)
    w_nb_B = earth.rotvec_from_q(earth.q_mult(earth.q_conj(zeta), earth.q_from_rotvec(dt * tr.w_IB_B))) / dt
    _, C_old = strapdown_ecef(tr.time_s, w_nb_B + w_in_B, *args[2:])
    assert attitude_error_rad(C_old, tr) > 1000 * 10 * n * np.finfo(float).eps
