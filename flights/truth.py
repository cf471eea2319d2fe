"""Navigation truth at the IMU: the flat-world MuJoCo kinematics mapped onto the WGS-84 Earth.

MuJoCo integrates the vehicle in a flat, non-rotating world whose axes are NED at the
departure point, with constant gravity. That world is the *dynamics*; the *truth* is built
from its kinematics as follows, per IMU sample k (frames: B body FRD with origin at the
IMU, N local NED at the IMU, E Earth-fixed, I inertial):

    v_N        := MuJoCo's velocity of the body origin (the IMU)                  [m/s]
    dv_N/dt    := MuJoCo's qacc (exactly the acceleration the integrator used)    [m/s^2]
    q_NB       := MuJoCo's attitude;  w_NB_B := MuJoCo's body rate                [-, rad/s]
    (φ, λ, h)  := ∫ [v_n/(R_N+h), v_e/((R_E+h) cos φ), −v_d] dt  (trapezoid, WGS-84 radii)
    f_N        = dv_N/dt + (2 ω_IE_N + ω_EN_N) × v_N − g_N(φ, h)                 [m/s^2]
    f_B        = C_BN f_N
    w_IB_B     = w_NB_B + C_BN (ω_IE_N + ω_EN_N)  (+ ½ ζ×a when held, see below)   [rad/s]
    B_B        = C_BN B_N(IGRF at the magnetometer's φ, λ, h, date)               [T]

so f_B and w_IB_B satisfy the NED mechanisation exactly (kinematically exact Earth terms):
Earth rate, transport rate, Coriolis and WGS-84 normal gravity (Somigliana + free-air, from
:mod:`imurig.flights.earth`). What is *not* modelled: the vehicle's dynamics do not feel
Coriolis or the variation of gravity (a flat-world approximation of the forces, ≲ 2e-3 m/s²
for a 120 m/s aircraft: it changes the path flown, not the consistency of the truth);
deflection of the vertical and gravity anomalies (≈ 1e-4 and 3e-4 m/s²); crustal and
external magnetic fields (IGRF main field only, bilinear in time along the route, errors
< 0.1 nT between 10-s nodes).

Sample semantics (zero-order hold): MuJoCo's semi-implicit Euler step holds the linear
acceleration (in the navigation frame) and the body rate constant over each IMU interval, while
positions, velocities and attitudes are exact at t_k:
v_{k+1} = v_k + Δt dv_N/dt_k,  q_{k+1} = q_k ⊗ exp(Δt w_NB_B,k). w_IB_B[k] is the rate held over
[t_k, t_k+1) relative to inertial space, Δθ/Δt with exp(Δθ) = exp(ζ) exp(a), ζ = Δt C_BN ω_IN_N the
navigation frame's turn and a = Δt w_NB_B the body's (:func:`held_inertial_rate`; the plain sum
misses ½ ζ × a), and f_B[k] the body-frame MEAN of the specific force over it, what an integrating IMU
reports as Δθ/Δt and Δv/Δt: f_B[k] = W(φ) C_BN,k f_N,k with φ = Δt w_NB_B,k (the body turns
under the held f_N; :func:`held_body_mean`, W = I − ½[φ×] + O(φ²)). :func:`mechanise` with
``scheme="euler"`` reproduces the truth to rounding error (4e-7 m after the 15-min default
flight); a scheme that reads the samples as instantaneous values of smooth signals
(``scheme="trapezoid"``) is off by half a sample and drifts by its O(Δt) error.
"""
from __future__ import annotations

import datetime as _dt
from dataclasses import dataclass, field

import numpy as np
from imurig.flights import earth, truth_kernel
from imurig.flights.mechanise_steps import euler_step, trapezoid_step

from imurig.kernel.errors import ConfigError
from imurig.kernel.navdata import FlightTruth
from imurig.kernel.site import decimal_year, parse_time
from imurig.kernel.units import T_REF_K

DEG = np.pi / 180.0


@dataclass
class BodyKinematics:
    """Kinematics of the body origin (the IMU) in the flat MuJoCo world (axes NED at the origin).

    time_s (N,), p_N (N,3) m, v_N (N,3) m/s, a_N (N,3) m/s^2 = dv_N/dt, q_NB (N,4) wxyz,
    w_NB_B (N,3) rad/s, wdot_NB_B (N,3) rad/s^2; ``controls``: name -> (N,) inputs."""

    time_s: np.ndarray
    p_N: np.ndarray
    q_NB: np.ndarray
    v_N: np.ndarray
    w_NB_B: np.ndarray
    a_N: np.ndarray
    wdot_NB_B: np.ndarray
    rate_hz: float
    controls: dict = field(default_factory=dict)


def offset_position(lat, lon, h, d_N):
    """Geodetic position of points displaced by d_N (N,3) m (NED) from (lat, lon, h)."""
    R_N, R_E = earth.radii(lat)
    return (lat + d_N[:, 0] / (R_N + h), lon + d_N[:, 1] / ((R_E + h) * np.cos(lat)), h - d_N[:, 2])


def _cumtrapz(y: np.ndarray, dt: float) -> np.ndarray:
    out = np.zeros_like(y)
    out[1:] = np.cumsum(0.5 * (y[1:] + y[:-1]) * dt, axis=0)
    return out


def integrate_position(v_N: np.ndarray, dt: float, lat0: float, lon0: float, h0: float):
    """(lat, lon, h) from the NED velocity (N,3) by the trapezoidal rule; the radii depend on the
    unknown latitude, solved by fixed-point iteration (converges to rounding in 3 passes)."""
    h = h0 + _cumtrapz(-v_N[:, 2], dt)
    lat = np.full(v_N.shape[0], lat0)
    for _ in range(4):
        R_N, R_E = earth.radii(lat)
        lat = lat0 + _cumtrapz(v_N[:, 0] / (R_N + h), dt)
    R_N, R_E = earth.radii(lat)
    lon = lon0 + _cumtrapz(v_N[:, 1] / ((R_E + h) * np.cos(lat)), dt)
    return lat, lon, h


def igrf_N(lat, lon, h, when: _dt.datetime, time_s, step_s: float = 10.0) -> np.ndarray:
    """IGRF main field (N,3) tesla in NED along a track, evaluated every ``step_s`` seconds
    with pyIGRF (as :meth:`imurig.kernel.site.Site.magnetic_field_W`) and interpolated linearly."""
    import pyIGRF

    t = np.asarray(time_s, float)
    nodes = np.arange(t[0], t[-1] + step_s, step_s)
    idx = np.clip(np.searchsorted(t, nodes), 0, t.size - 1)
    B = np.empty((nodes.size, 3))
    for j, (i, tn) in enumerate(zip(idx, nodes)):
        yr = decimal_year(when + _dt.timedelta(seconds=float(tn - t[0])))
        _, _, _, north, east, down, _ = pyIGRF.igrf_value(np.degrees(lat[i]), np.degrees(lon[i]), h[i] / 1000.0, yr)
        B[j] = (north, east, down)
    return 1e-9 * np.stack([np.interp(t, nodes, B[:, c]) for c in range(3)], axis=1)


def cabin_temperature_K(time_s: np.ndarray, h_m: np.ndarray, start_K: float = 293.15, warm_K: float = 6.0,
                        tau_s: float = 600.0, lapse_K_per_m: float = 0.003) -> np.ndarray:
    """Air temperature in the IMU box (K): warms by ``warm_K`` with time constant ``tau_s`` after
    switch-on and cools with height above the start (cabin air): T = T0 + ΔT (1 − e^{−t/τ}) − L (h − h0)."""
    t = time_s - time_s[0]
    return start_K + warm_K * (1.0 - np.exp(-t / tau_s)) - lapse_K_per_m * (h_m - h_m[0])


def truth_from_kinematics(kin: BodyKinematics, origin_deg: tuple, start_time: str, vehicle: str,
                          lever_gps_B, lever_mag_B, phases: tuple = (), meta: dict | None = None,
                          T_imu_K: np.ndarray | None = None, field_step_s: float = 10.0,
                          zoh: bool = True, compiled: bool = True) -> FlightTruth:
    """Build the :class:`FlightTruth` (equations in the module docstring) from flat-world kinematics.

    ``origin_deg`` = (lat deg, lon deg, ellipsoidal height m) of the flat world's origin; the
    IMU starts at the origin displaced by the kinematics' first position p_N[0]. ``zoh``: the
    samples are MuJoCo steps (body rate held over each step, see the module docstring); pass
    False for analytic kinematics sampled instantaneously. ``compiled``: the per-sample maths in one
    compiled pass (:mod:`imurig.flights.truth_kernel`); False: the numpy reference path
    (:func:`held_terms_numpy`), the same equations.
    """
    t = np.asarray(kin.time_s, float)
    if t.size < 2 or not np.all(np.isfinite(t)):
        raise ConfigError("kinematics need at least two finite samples")
    dt = 1.0 / kin.rate_hz
    if np.max(np.abs(np.diff(t) - dt)) > 1e-6 * dt + 1e-9 * abs(t[-1]):
        raise ConfigError(f"kinematics are not uniform at {kin.rate_hz:g} Hz; resample them first")
    lat0, lon0, h0 = origin_deg
    la0, lo0, hh0 = offset_position(np.array([lat0 * DEG]), np.array([lon0 * DEG]), np.array([float(h0)]),
                                    kin.p_N[:1])
    if compiled:   # one compiled pass (flights/truth_kernel.py), the numpy path's maths to the last bits
        lat, lon, h = truth_kernel.geodetic_track(np.asarray(kin.v_N, float), dt, float(la0[0]), float(lo0[0]),
                                                  float(hh0[0]))
        q, f_B, w_IB_B, mlat, mlon, mh = truth_kernel.held_terms(
            lat, lon, h, *(np.asarray(x, float) for x in (kin.v_N, kin.a_N, kin.q_NB, kin.w_NB_B, kin.wdot_NB_B)),
            float(kin.rate_hz), bool(zoh), np.asarray(lever_mag_B, float))
    else:
        lat, lon, h = integrate_position(kin.v_N, dt, float(la0[0]), float(lo0[0]), float(hh0[0]))
        q, f_B, w_IB_B, mlat, mlon, mh = held_terms_numpy(lat, lon, h, kin, zoh, lever_mag_B)
    lever_mag_B = np.asarray(lever_mag_B, float)
    when = parse_time(start_time)
    B_N = igrf_N(mlat, mlon, mh, when, t, field_step_s)
    B_B = truth_kernel.to_body(q, B_N) if compiled else np.einsum("nji,nj->ni", earth.C_from_q(q), B_N)
    if T_imu_K is None:
        T_imu_K = cabin_temperature_K(t, h)
    m = {"start_time": start_time, "origin_deg": list(origin_deg), "earth_model": "WGS-84 (imurig.flights.earth)",
         "magnetic_model": "IGRF (pyIGRF 0.3.3)", "kinematics": "MuJoCo flat world, semi-implicit Euler",
         "imu_samples": "held" if zoh else "instantaneous"}
    m.update(meta or {})
    return FlightTruth(time_s=t, rate_hz=float(kin.rate_hz), lat_rad=lat, lon_rad=lon, h_m=h, v_N=kin.v_N.copy(),
                       q_NB=q, f_B=f_B, w_IB_B=w_IB_B, B_B=B_B, T_imu_K=np.asarray(T_imu_K, float),
                       lever_gps_B=np.asarray(lever_gps_B, float), lever_mag_B=lever_mag_B,
                       phases=tuple(phases), vehicle=vehicle, meta=m)


def held_terms_numpy(lat, lon, h, kin: BodyKinematics, zoh: bool, lever_mag_B):
    """The per-sample truth in numpy (the reference of :func:`imurig.flights.truth_kernel.held_terms`):
    (q_NB, f_B, w_IB_B, and the magnetometer's lat, lon, h); equations in the module docstring."""
    dt = 1.0 / kin.rate_hz
    q = earth.q_normalize(kin.q_NB)
    C_NB = earth.C_from_q(q)
    w_ie = earth.omega_IE_N(lat)
    w_en = earth.omega_EN_N(lat, h, kin.v_N)
    f_N = kin.a_N + _cross(2 * w_ie + w_en, kin.v_N) - earth.gravity_N(lat, h)
    f_B = np.einsum("nji,nj->ni", C_NB, f_N)
    # zero-order hold: MuJoCo's step k rotates the body with the rate it has at the END of the step
    # (semi-implicit Euler), w_k + dt wdot_k; that is the rate held over [t_k, t_k+1)
    w_hold = kin.w_NB_B + kin.wdot_NB_B / kin.rate_hz if zoh else kin.w_NB_B
    if zoh:
        # the step holds f_N while the body turns by φ = w_hold dt: an integrating accelerometer
        # reports the body-frame mean of the specific force over the interval
        f_B = held_body_mean(w_hold * dt, f_B)
        # the navigation frame's exact turn over each step, from the positions it moves between
        zeta_N = (w_ie + w_en) * dt
        zeta_N[:-1] = earth.nav_frame_turn(lat[:-1], lon[:-1], lat[1:], lon[1:], dt)
        w_IN_B = np.einsum("nji,nj->ni", C_NB, zeta_N) / dt
        w_IB_B = held_inertial_rate(w_IN_B * dt, w_hold * dt) / dt
    else:
        w_IB_B = w_hold + np.einsum("nji,nj->ni", C_NB, w_ie + w_en)
    mlat, mlon, mh = offset_position(lat, lon, h, C_NB @ np.asarray(lever_mag_B, float))
    return q, f_B, w_IB_B, mlat, mlon, mh


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a × b of (N, 3) arrays: :func:`numpy.cross`'s arithmetic (the same bits) without its copies."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def held_inertial_rate(zeta_B: np.ndarray, a_B: np.ndarray) -> np.ndarray:
    """The body's rotation vector Δθ (N, 3) rad relative to inertial space over a held step, in which
    the navigation frame turns by ζ (ζ_B = Δt C_BN,k ω_IN_N,k, seen in the body at t_k) and the
    body turns relative to it by a_B = Δt w_NB_B (held):

        exp([Δθ×]) = C_BN,k C_N(k)N(k+1) C_NB,k+1 = exp([ζ_B×]) exp([a_B×]),
        Δθ = ζ_B + a_B + ½ ζ_B × a_B + O(|ζ||a|², |ζ|²|a|)        (Baker-Campbell-Hausdorff)

    computed exactly with quaternions. A strapdown that applies Δθ in the body and −ζ in the
    navigation frame (q_k+1 = q(−ζ_N) ⊗ q_k ⊗ q(Δθ), e.g. :func:`imurig.flights.ins.nav_step`) then
    reproduces q_k+1 = q_k ⊗ q(a) to rounding. The plain sum ζ_B + a_B (the truth before) leaves out
    ½ ζ × a: about 1e-7 rad/s in a 0.3 rad/s turn at 100 Hz, which an independent strapdown
    integrating the ideal data of a 15-min flight turned into 4 m of drift."""
    dq = earth.q_mult(earth.q_from_rotvec(np.asarray(zeta_B, float)), earth.q_from_rotvec(np.asarray(a_B, float)))
    return earth.rotvec_from_q(dq)


def held_body_mean(phi_B: np.ndarray, f0_B: np.ndarray) -> np.ndarray:
    """Mean body-frame specific force (N, 3) m/s² over a sample interval in which the navigation-frame
    specific force is held (f0_B = C_BN,k f_N,k at the start) and the body turns at a constant rate
    by φ_B (N, 3) rad relative to the navigation frame: C_BN(τ) = exp(−[φ×] τ/Δt) C_BN,k, so

        f̄_B = W(φ) f0_B,   W(φ) = ∫₀¹ exp(−[φ×] s) ds = I − (1 − cos a)/a² [φ×] + (a − sin a)/a³ [φ×]²,

    a = |φ| (series for a < 1e-4). This is what an integrating IMU reports as Δv/Δt: its second-order
    pre-integration (:func:`imurig.flights.ins.preintegrate`, ``"held"``) applies ½ Δθ×Δv for the
    rotation inside the interval. Using f0_B itself instead leaves ½ [w×] f Δt per sample
    (0.03 m/s² at 0.3 rad/s and 2 g, 100 Hz), which on the default flight was the largest error of
    the navigation filter fed with a perfect IMU (docs/flights-navigation.md)."""
    phi = np.asarray(phi_B, float)
    f0 = np.asarray(f0_B, float)
    a = np.linalg.norm(phi, axis=-1)
    small = a < 1e-4
    a_ = np.where(small, 1.0, a)
    c1 = np.where(small, 0.5 - a ** 2 / 24.0, (1.0 - np.cos(a_)) / a_ ** 2)
    c2 = np.where(small, 1.0 / 6.0 - a ** 2 / 120.0, (a_ - np.sin(a_)) / a_ ** 3)
    pf = _cross(phi, f0)
    return f0 - c1[..., None] * pf + c2[..., None] * _cross(phi, pf)


def mechanise(truth: FlightTruth, f_B: np.ndarray | None = None, w_IB_B: np.ndarray | None = None,
              scheme: str = "euler"):
    """Strapdown NED mechanisation from the truth's initial state, driven by f_B and w_IB_B
    (default: the truth's own). Returns (lat, lon, h, v_N, q_NB), each (N, ...).

        w_NB_B = w_IB_B − C_BN (ω_IE_N + ω_EN_N)
        dv_N/dt = C_NB f_B − (2 ω_IE_N + ω_EN_N) × v_N + g_N(φ, h)
        (φ, λ, h) from v_N and the WGS-84 radii (trapezoid, as the truth)

    ``scheme="euler"``: forward rectangles with the samples held over their interval,
    v_{k+1} = v_k + Δt v̇_k, q_{k+1} = q_k ⊗ exp(Δt w_NB_B,k): what the truth obeys to
    rounding; for held samples (``truth.meta["imu_samples"] == "held"``) v̇_k uses
    C_NB W(φ)⁻¹ f_B[k], the held navigation-frame specific force (:func:`held_body_mean`).
    ``"trapezoid"``: a generic second-order scheme (trapezoidal velocity, mid-point attitude),
    which treats the samples as instantaneous values of smooth signals: a half-sample
    interpretation offset, hence O(Δt) bounded velocity and attitude errors.
    A per-sample loop: a verification tool, not a hot path.
    """
    if scheme not in ("euler", "trapezoid"):
        raise ConfigError(f"scheme must be 'euler' or 'trapezoid', got {scheme!r}")
    f_B = truth.f_B if f_B is None else f_B
    w_IB_B = truth.w_IB_B if w_IB_B is None else w_IB_B
    n, dt = truth.n, 1.0 / truth.rate_hz
    held = (getattr(truth, "meta", None) or {}).get("imu_samples") == "held"
    lat, lon, h = np.empty(n), np.empty(n), np.empty(n)
    v = np.empty((n, 3))
    q = np.empty((n, 4))
    lat[0], lon[0], h[0], v[0], q[0] = truth.lat_rad[0], truth.lon_rad[0], truth.h_m[0], truth.v_N[0], truth.q_NB[0]
    fl, wl = np.asarray(f_B, float).tolist(), np.asarray(w_IB_B, float).tolist()   # per-sample maths on floats
    for k in range(n - 1):
        st = (float(lat[k]), float(lon[k]), float(h[k]), tuple(v[k].tolist()), tuple(q[k].tolist()))
        la1, lo1, h1, v1, q1 = (euler_step(st, fl[k], wl[k], dt, held) if scheme == "euler"
                                else trapezoid_step(st, fl[k], fl[k + 1], wl[k], wl[k + 1], dt))
        lat[k + 1], lon[k + 1], h[k + 1], v[k + 1], q[k + 1] = la1, lo1, h1, v1, q1
    return lat, lon, h, v, q


def static_tests_truth(attitudes_deg=((0.0, 0.0), (-30.0, 0.0), (0.0, -30.0)), dwell_s: float = 60.0,
                       transition_s: float = 10.0, rate_hz: float = 100.0, heading_deg: float = 234.0,
                       origin_deg: tuple = (52.31, 4.76, 43.0), start_time: str = "2005-06-26T08:00:00+02:00",
                       lever_gps_B=(0.5, 0.3, -1.1), lever_mag_B=(0.4, 0.0, 0.0),
                       T_imu_K: float = T_REF_K) -> FlightTruth:
    """The static attitude tests of the paper's section 4.2: the IMU on a fixture, parked, at
    (roll, pitch) = 0/0, −30/0, 0/−30 deg for ``dwell_s`` each, turned between them about its
    own centre by a minimum-jerk profile of ``transition_s`` (analytic kinematics, exact):
    v_N = 0, a_N = 0, w_NB_B = [φ̇, θ̇ cos φ, −θ̇ sin φ] at constant yaw."""
    att = np.asarray(attitudes_deg, float) * DEG
    if att.ndim != 2 or att.shape[1] != 2 or np.any(np.abs(att) > 90 * DEG):
        raise ConfigError("attitudes_deg must be ((roll, pitch), ...) pairs within +-90 deg")
    segs, phases, t0 = [], [], 0.0
    dt = 1.0 / rate_hz
    for i, (r, p) in enumerate(att):
        if i:
            segs.append(("move", att[i - 1], att[i], transition_s))
        segs.append((f"static_roll{np.degrees(r):+.0f}_pitch{np.degrees(p):+.0f}", att[i], att[i], dwell_s))
    n_tot = round(sum(s[3] for s in segs) * rate_hz)
    t = np.arange(n_tot) * dt
    roll, pitch = np.empty(n_tot), np.empty(n_tot)
    droll, dpitch = np.zeros(n_tot), np.zeros(n_tot)
    for name, a, b, dur in segs:
        i = (t >= t0 - 1e-9) & (t < t0 + dur - 1e-9)
        s = (t[i] - t0) / dur
        shape = 10 * s**3 - 15 * s**4 + 6 * s**5
        dshape = (30 * s**2 - 60 * s**3 + 30 * s**4) / dur
        roll[i] = a[0] + (b[0] - a[0]) * shape
        pitch[i] = a[1] + (b[1] - a[1]) * shape
        droll[i], dpitch[i] = (b[0] - a[0]) * dshape, (b[1] - a[1]) * dshape
        if name != "move":
            phases.append((name, t0, t0 + dur))
        t0 += dur
    q = earth.q_from_euler(roll, pitch, np.full(n_tot, heading_deg * DEG))
    w = np.stack([droll, dpitch * np.cos(roll), -dpitch * np.sin(roll)], axis=1)
    z = np.zeros((n_tot, 3))
    kin = BodyKinematics(time_s=t, p_N=z, q_NB=q, v_N=z, w_NB_B=w, a_N=z, wdot_NB_B=np.gradient(w, dt, axis=0),
                         rate_hz=rate_hz)
    return truth_from_kinematics(kin, origin_deg, start_time, "fixture", lever_gps_B, lever_mag_B, tuple(phases),
                                 {"test": "static attitude (paper section 4.2)"}, np.full(n_tot, T_imu_K), zoh=False)
