"""Strapdown inertial navigation on the WGS-84 ellipsoid (NED mechanisation).

Two stages:

1. :func:`preintegrate` (vectorised numpy, no per-sample loop): IMU samples ``w_IB_B`` (N, 3)
   rad/s and ``f_B`` (N, 3) m/s² at rate 1/dt are turned into trapezoidal per-sample increments
   α_i = ½(ω_{i−1}+ω_i) dt, ν_i = ½(f_{i−1}+f_i) dt and summed over K samples into one
   navigation interval of length T = K dt with the coning and sculling corrections of Savage
   (Strapdown Analytics, eq. 7.1.1.1-11 and 7.2.2.2.2-15/-20):

       Δθ = Σα + Σ_i [½ Θ_{i−1} × α_i + 1/12 α_{i−1} × α_i]
       Δv = Σν + ½ Θ_K × V_K + ½ Σ_i [(Θ_{i−1} + α_{i−1}/6) × ν_i + (V_{i−1} + ν_{i−1}/6) × α_i]

   with Θ_{i−1}, V_{i−1} the sums over the interval before sample i.
2. :func:`navigate` / :class:`Strapdown` (a Python loop at the navigation rate 1/T):

       q_NB ← q(−ζ) ⊗ q_NB ⊗ q(Δθ_B),              ζ = (ω_IE + ω_EN)_mid T
       v_N  ← v_N + (I − ½[ζ×]) C_NB Δv_B + (g_N − (2 ω_IE + ω_EN) × v_N)_mid T
       φ, λ, h ← φ, λ, h + T (v_n/(R_N+h), v_e/((R_E+h)cosφ), −v_d)_mid

   with "mid" the mid-interval values from one predictor-corrector pass. The scheme is
   second order: a closed-form trajectory is followed with a global error ∝ T² (tested).
   Stationary on the Earth it holds exactly (up to rounding), Earth rate and gravity in.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from imurig.flights import earth as E
from imurig.flights import navmath as nm
from scipy.integrate import solve_ivp

from imurig.kernel.errors import ConfigError, RecordingError
from imurig.kernel.navdata import SAMPLE_SEMANTICS, FlightTruth


# --- pre-integration -----------------------------------------------------------------------------
@dataclass(frozen=True)
class Increments:
    """Coning/sculling-corrected increments over navigation intervals.

    ``dtheta_B`` (M, 3) rad and ``dv_B`` (M, 3) m/s are expressed in the body frame at the
    start of each interval; ``t_s`` (M+1,) are the interval boundaries; ``T_s`` the length.
    """

    t_s: np.ndarray
    dtheta_B: np.ndarray
    dv_B: np.ndarray
    T_s: float


def _check_imu(name, a, n=None):
    a = np.asarray(a, dtype=float)
    if a.ndim != 2 or a.shape[1] != 3:
        raise RecordingError(f"{name} must have shape (N, 3), got {a.shape}")
    if n is not None and a.shape[0] != n:
        raise RecordingError(f"{name} has {a.shape[0]} samples, expected {n} (same as the time axis)")
    if not np.all(np.isfinite(a)):
        bad = int(np.flatnonzero(~np.all(np.isfinite(a), axis=1))[0])
        raise RecordingError(f"{name} contains NaN/inf (first at sample {bad}); clean or cut the recording")
    return a




def preintegrate(time_s, w_IB_B, f_B, samples_per_step: int, samples: str = "instantaneous") -> Increments:
    """Coning/sculling pre-integration of uniformly sampled rates and specific forces.

    ``time_s`` (N,) s uniform; ``w_IB_B`` (N, 3) rad/s; ``f_B`` (N, 3) m/s²; K =
    ``samples_per_step`` ≥ 1. Returns M = (N−1)//K intervals starting at ``time_s[0]``.

    ``samples`` says what a sample is:

    - ``"instantaneous"``: values of smooth signals at t_i (closed-form trajectories):
      trapezoidal increments α_i = ½(ω_i + ω_{i+1}) dt with Savage's 1/12 and 1/6 terms;
    - ``"held"``: the value held over [t_i, t_{i+1}) (zero-order hold: what an integrating IMU
      reports as Δθ/Δt, Δv/Δt, and what the MuJoCo flight truth and the sensor chain give):
      α_i = ω_i dt, ν_i = f_i dt. With piecewise-constant rates the second-order terms
      ½ Σ Θ_{i−1}×α_i and ½ Θ×V + ½ Σ(Θ_{i−1}×ν_i + V_{i−1}×α_i) are exact to second order
      and the within-sample 1/12, 1/6 terms vanish. Reading held samples as instantaneous
      puts the increments half a sample (5 ms at 100 Hz) ahead: an attitude error of
      ½ dt ω (1.3 mrad at 15 deg/s of roll rate).
    """
    if samples not in SAMPLE_SEMANTICS:
        raise ConfigError(f"samples must be one of {SAMPLE_SEMANTICS}, got {samples!r}")
    t = np.asarray(time_s, dtype=float)
    if t.ndim != 1 or t.size < 2:
        raise RecordingError("time_s must be a 1-D array with at least 2 samples")
    w = _check_imu("w_IB_B", w_IB_B, t.size)
    f = _check_imu("f_B", f_B, t.size)
    dts = np.diff(t)
    dt = float(np.median(dts))
    if dt <= 0 or np.max(np.abs(dts - dt)) > 1e-6 * dt + 1e-9:
        raise RecordingError("time_s must be strictly increasing and uniformly sampled "
                             f"(median step {dt:g} s, worst deviation {np.max(np.abs(dts - dt)):g} s)")
    K = int(samples_per_step)
    if K < 1:
        raise ConfigError(f"samples_per_step must be >= 1, got {K}")
    M = (t.size - 1) // K
    if M < 1:
        raise RecordingError(f"only {t.size} samples: too short for one navigation step of {K} samples")
    held = samples == "held"
    if held:
        a = w[:-1] * dts[:, None]                                 # (N-1, 3) angle increments
        nu = f[:-1] * dts[:, None]                                # (N-1, 3) velocity increments
    else:
        a = 0.5 * (w[:-1] + w[1:]) * dts[:, None]
        nu = 0.5 * (f[:-1] + f[1:]) * dts[:, None]
    c12, c6 = (0.0, 0.0) if held else (1.0 / 12.0, 1.0 / 6.0)
    a_prev = np.concatenate([a[:1], a[:-1]])                      # previous-sample increment
    nu_prev = np.concatenate([nu[:1], nu[:-1]])
    sl = slice(0, M * K)
    a, nu, a_prev, nu_prev = (x[sl].reshape(M, K, 3) for x in (a, nu, a_prev, nu_prev))
    Th = np.cumsum(a, axis=1) - a                                  # sums before sample i
    V = np.cumsum(nu, axis=1) - nu
    ThK, VK = Th[:, -1] + a[:, -1], V[:, -1] + nu[:, -1]
    coning = np.sum(0.5 * np.cross(Th, a) + c12 * np.cross(a_prev, a), axis=1)
    scull = 0.5 * np.sum(np.cross(Th + c6 * a_prev, nu) + np.cross(V + c6 * nu_prev, a), axis=1)
    dtheta = ThK + coning
    dv = VK + 0.5 * np.cross(ThK, VK) + scull
    return Increments(t_s=t[: M * K + 1: K].copy(), dtheta_B=dtheta, dv_B=dv, T_s=K * dt)


# --- navigation equations ------------------------------------------------------------------------
@dataclass
class NavState:
    """Navigation state: WGS-84 ``lat_rad, lon_rad, h_m``; ``v_N`` (3,) m/s NED; ``q_NB`` (4,) wxyz."""

    lat_rad: float
    lon_rad: float
    h_m: float
    v_N: np.ndarray
    q_NB: np.ndarray

    def copy(self) -> NavState:
        return NavState(self.lat_rad, self.lon_rad, self.h_m, self.v_N.copy(), self.q_NB.copy())


def _cross(a, b):
    return np.array(nm.cross(a, b))


def _skew(v):
    """[v×] of one vector (3,) (scalar fast path of :func:`earth.skew`)."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _dcm(q):
    """C(q) of one quaternion (4,) (scalar fast path of :func:`earth.C_from_q`)."""
    return np.array(nm.dcm(q.tolist() if isinstance(q, np.ndarray) else q)).reshape(3, 3)


def _qmul(p, q):
    return np.array(nm.qmul(p, q))


def _qrot(phi):
    return np.array(nm.qrot(phi))


def _rates(lat, h, v):
    """(ω_IE_N, ω_EN_N, g_N) as (3,) arrays at one point (scalar fast path of :mod:`earth`)."""
    w_ie, w_en, g, R_N, R_E = nm.rates(lat, h, float(v[0]), float(v[1]))
    return np.array(w_ie), np.array(w_en), np.array([0.0, 0.0, g]), R_N, R_E


def _floats(a):
    """A vector as a list of Python floats (numpy scalars are slower in scalar arithmetic)."""
    return a.tolist() if isinstance(a, np.ndarray) else [float(e) for e in a]


def nav_step(x: NavState, dtheta_B, dv_B, T: float, rates0=None) -> NavState:
    """One navigation update over T seconds with body increments ``dtheta_B``, ``dv_B`` (3,)
    (module doc; plain-float arithmetic, :func:`imurig.flights.navmath.nav_step`); ``rates0`` the
    :func:`imurig.flights.navmath.rates` at ``x`` if the caller has them."""
    v0 = x.v_N.tolist()
    if rates0 is None:
        rates0 = nm.rates(x.lat_rad, x.h_m, v0[0], v0[1])
    lat, lon, h, v, q = nm.nav_step(x.lat_rad, x.lon_rad, x.h_m, v0, x.q_NB.tolist(), _floats(dtheta_B),
                                    _floats(dv_B), T, rates0)
    return NavState(lat, lon, h, np.array(v), np.array(q))


@dataclass
class NavSolution:
    """Navigation solution at the interval boundaries ``time_s`` (M+1,): arrays like FlightTruth."""

    time_s: np.ndarray
    lat_rad: np.ndarray
    lon_rad: np.ndarray
    h_m: np.ndarray
    v_N: np.ndarray
    q_NB: np.ndarray
    meta: dict = field(default_factory=dict)


def navigate(inc: Increments, x0: NavState) -> NavSolution:
    """Free-inertial navigation from ``x0`` at ``inc.t_s[0]`` through all increments."""
    M = inc.dtheta_B.shape[0]
    lat = np.empty(M + 1)
    lon = np.empty(M + 1)
    h = np.empty(M + 1)
    v = np.empty((M + 1, 3))
    q = np.empty((M + 1, 4))
    x = x0.copy()
    for k in range(M + 1):
        lat[k], lon[k], h[k], v[k], q[k] = x.lat_rad, x.lon_rad, x.h_m, x.v_N, x.q_NB
        if k < M:
            x = nav_step(x, inc.dtheta_B[k], inc.dv_B[k], inc.T_s)
    return NavSolution(inc.t_s, lat, lon, h, v, q)


def state_at(truth, i: int) -> NavState:
    """The navigation state of a truth record (FlightTruth-like) at sample ``i``."""
    return NavState(float(truth.lat_rad[i]), float(truth.lon_rad[i]), float(truth.h_m[i]),
                    np.array(truth.v_N[i], dtype=float), np.array(truth.q_NB[i], dtype=float))


# --- closed-form trajectories for tests ------------------------------------------------------------
def kinematic_truth(duration_s, rate_hz, lat0_rad, lon0_rad, h0_m, v_fn, a_fn, euler_fn, euler_rate_fn,
                    phases=()) -> FlightTruth:
    """Exact IMU signals along a prescribed trajectory on the WGS-84 ellipsoid, as a
    :class:`~imurig.kernel.navdata.FlightTruth` (vehicle "kinematic", samples instantaneous, no
    magnetic field or temperature, lever arms zero).

    ``v_fn(t)``/``a_fn(t)`` give v_N and dv_N/dt (N, 3); ``euler_fn(t)``/``euler_rate_fn(t)`` give
    (roll, pitch, yaw) and their rates (N, 3). Position is integrated from v_N with DOP853
    (rtol 1e-13). Then, exactly:

        f_B    = C_BN [dv_N/dt + (2 ω_IE + ω_EN) × v_N − g_N(φ, h)]
        w_IB_B = w_NB_B(Euler rates) + C_BN (ω_IE + ω_EN)
    """
    t = np.arange(round(duration_s * rate_hz) + 1) / rate_hz

    def rhs(tt, y):
        dlat, dlon, dh = E.geodetic_rates(y[0], y[2], v_fn(np.atleast_1d(tt))[0])
        return [dlat, dlon, dh]

    sol = solve_ivp(rhs, (0.0, t[-1]), [lat0_rad, lon0_rad, h0_m], method="DOP853", t_eval=t,
                    rtol=1e-13, atol=[1e-15, 1e-15, 1e-9])
    lat, lon, h = sol.y
    v = v_fn(t)
    a = a_fn(t)
    eul = euler_fn(t)
    deul = euler_rate_fn(t)
    q = E.q_from_euler(eul[:, 0], eul[:, 1], eul[:, 2])
    C_BN = np.swapaxes(E.C_from_q(q), -1, -2)
    w_ie, w_en = E.omega_IE_N(lat), E.omega_EN_N(lat, h, v)
    f_N = a + np.cross(2 * w_ie + w_en, v) - E.gravity_N(lat, h)
    r, p = eul[:, 0], eul[:, 1]
    dr, dp, dy = deul[:, 0], deul[:, 1], deul[:, 2]
    w_NB_B = np.stack([dr - np.sin(p) * dy,
                       np.cos(r) * dp + np.sin(r) * np.cos(p) * dy,
                       -np.sin(r) * dp + np.cos(r) * np.cos(p) * dy], axis=1)
    f_B = np.einsum("nij,nj->ni", C_BN, f_N)
    w_IB_B = w_NB_B + np.einsum("nij,nj->ni", C_BN, w_ie + w_en)
    return FlightTruth(time_s=t, rate_hz=float(rate_hz), lat_rad=lat, lon_rad=lon, h_m=h, v_N=v, q_NB=q, f_B=f_B,
                       w_IB_B=w_IB_B, phases=tuple(phases), vehicle="kinematic",
                       meta={"imu_samples": "instantaneous"})


def sample_semantics(truth) -> str:
    """What the IMU samples of ``truth`` are: ``"held"`` (zero-order hold over [t_k, t_k+1): the
    MuJoCo flight truth, the sensor chain) or ``"instantaneous"`` (closed-form trajectories and the
    analytic static tests). Read from ``truth.meta["imu_samples"]``; held without it."""
    m = getattr(truth, "meta", None) or {}
    return str(m.get("imu_samples", "held"))


def nav_errors(sol: NavSolution, truth, idx) -> dict:
    """Position (NED, m), velocity (m/s) and attitude (rad, small-angle) errors of ``sol`` against
    ``truth`` sampled at indices ``idx`` (M+1,). Attitude error ψ_N: C_NB,est ≈ (I − [ψ×]) C_NB,true."""
    d = E.ned_from_geodetic(sol.lat_rad, sol.lon_rad, sol.h_m,
                            truth.lat_rad[idx], truth.lon_rad[idx], truth.h_m[idx])
    dq = E.q_mult(truth.q_NB[idx], E.q_conj(sol.q_NB))           # q_true ⊗ q_est^-1 = q(ψ)
    psi = E.rotvec_from_q(dq)
    return {"pos_N_m": d, "vel_N_m_s": sol.v_N - truth.v_N[idx], "att_N_rad": psi}


def s_turn_truth(duration_s=300.0, rate_hz=100.0, *, lat0_rad=52.0 * math.pi / 180, lon0_rad=4.37 * math.pi / 180,
                 h0_m=1000.0, speed_m_s=100.0, yaw_amp_rad=0.0, yaw_period_s=120.0, yaw0_rad=0.0,
                 pitch_amp_rad=0.0, pitch_period_s=40.0, climb_amp_m_s=0.0) -> FlightTruth:
    """A closed-form manoeuvre: level flight at ``speed_m_s`` with S-turns
    ψ(t) = ψ0 + A sin(2πt/P) (bank φ = atan(V ψ̇ / g), the coordinated-turn bank), a pitch
    oscillation θ(t) = θ_a sin(2πt/P_θ) and a vertical velocity v_d = −c sin(2πt/P_θ).
    A = 0 gives a straight leg."""
    g = 9.81
    wy, wp = 2 * math.pi / yaw_period_s, 2 * math.pi / pitch_period_s
    V = speed_m_s

    def yaw(t):
        return yaw0_rad + yaw_amp_rad * np.sin(wy * t)

    def dyaw(t):
        return yaw_amp_rad * wy * np.cos(wy * t)

    def ddyaw(t):
        return -yaw_amp_rad * wy ** 2 * np.sin(wy * t)

    def v(t):
        y = yaw(t)
        return np.stack([V * np.cos(y), V * np.sin(y), -climb_amp_m_s * np.sin(wp * t)], 1)

    def a(t):
        y, dy = yaw(t), dyaw(t)
        return np.stack([-V * np.sin(y) * dy, V * np.cos(y) * dy, -climb_amp_m_s * wp * np.cos(wp * t)], 1)

    def eul(t):
        return np.stack([np.arctan(V * dyaw(t) / g), pitch_amp_rad * np.sin(wp * t), yaw(t)], 1)

    def deul(t):
        u = V * dyaw(t) / g
        return np.stack([V * ddyaw(t) / g / (1 + u ** 2), pitch_amp_rad * wp * np.cos(wp * t), dyaw(t)], 1)

    return kinematic_truth(duration_s, rate_hz, lat0_rad, lon0_rad, h0_m, v, a, eul, deul)
