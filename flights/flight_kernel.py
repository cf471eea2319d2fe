"""The Citation's physics steps between two control updates, compiled with numba: per MuJoCo step the
same force model as the per-step Python path of :class:`imurig.flights.aircraft.CitationSim`
(actuator and engine lags, the aerodynamic and thrust force of :meth:`CitationAero.forces` at the
state of that step, the tyre forces of :class:`imurig.flights.vehicle.TyreModel`), then ``mj_step``
of MuJoCo's own library, then the sample's record (the rows of :meth:`VehicleSim.step`).

So the forces still follow the state at every physics step (the α̇, q̂, p̂ damping terms act at
1 kHz exactly as before); only the pilot and the autopilot, which set the held commands, run at
their own rate in Python (:mod:`imurig.flights.pilot`). The maths is written operation by
operation as in the Python path: for the same commands both give the same samples to the last bit
(tested), and the same seed gives the same flight.

``mj_step`` is called through its C symbol (``numba.types.ExternalFunction``, resolved in MuJoCo's
shared library that the ``mujoco`` package ships), with the addresses of the MjModel and MjData the
Python bindings hold (``._address``); the state is read from and the forces written to the
bindings' numpy views of that same memory (``qpos``, ``qvel``, ``xfrc_applied``).

Cost: ~0.3 CPU-s to import numba (paid once per process, at import), ~0.25 CPU-s for numba's typing and
target registries at the first call of any compiled function in the process, a few ms to load the cached
machine code; on the first run after an install or an edit ~2 CPU-s of
compilation, cached on disk next to the sources (``cache=True``). Without a MuJoCo shared library to
link (:data:`AVAILABLE` False) the Python path steps the flight (same samples, slower).
"""
from __future__ import annotations

import math

import llvmlite.binding as llb
import numba
import numpy as np
from numba import types

from imurig.rigs.mujoco_clock import mujoco_library

#: aerodynamic parameter vector (``aero_params``) layout
AERO_FIELDS = ("S_m2", "c_m", "b_m", "CL0", "CLa", "CLq", "CLadot", "CLde", "CD0", "oswald", "CL_flaps",
               "CD_flaps", "Cm0", "Cma", "Cmq", "Cmadot", "Cmde", "Cm_flaps", "CYb", "CYp", "CYr", "CYda", "CYdr",
               "Clb", "Clp", "Clr", "Clda", "Cldr", "Cnb", "Cnp", "Cnr", "Cnda", "Cndr", "thrust_max_N",
               "engine_tau_s", "surface_tau_s", "de_min", "de_max", "da_limit_rad", "dr_limit_rad",
               "steer_limit_rad", "x_cg", "y_cg", "z_cg", "aspect_ratio")
#: one row per wheel (``wheel_params``)
WHEEL_FIELDS = ("body", "qposadr", "dofadr", "k", "c", "x", "y", "z", "radius", "C_alpha", "mu", "c_rr",
                "v_min", "v_stick", "steered", "braked", "driven")
_ENGINE_TAU, _SURFACE_TAU, _DE_MIN, _DE_MAX, _DA_LIM, _DR_LIM, _STEER_LIM, _X_CG, _Y_CG, _Z_CG, _AR = (
    AERO_FIELDS.index(k) for k in ("engine_tau_s", "surface_tau_s", "de_min", "de_max", "da_limit_rad",
                                   "dr_limit_rad", "steer_limit_rad", "x_cg", "y_cg", "z_cg", "aspect_ratio"))
_THRUST_MAX = AERO_FIELDS.index("thrust_max_N")
ROW = 26          # t, qpos[0:7], qvel[0:6], dv/dt[0:6], controls de, da, dr, thr, steer, brake
IO_SIZE = 42      # commands [0:7], deflections [7:14], previous α [14], the state after the steps [15:42]


_LIB = mujoco_library()
AVAILABLE = _LIB is not None
if AVAILABLE:
    llb.load_library_permanently(str(_LIB))
# void mj_step(const mjModel* m, mjData* d): the pointers passed as address-sized integers
_mj_step = types.ExternalFunction("mj_step", types.void(types.intp, types.intp))


def aero_params(aero) -> np.ndarray:
    vals = dict(aero.__dict__)
    vals["de_min"], vals["de_max"] = aero.de_limits_rad
    vals["x_cg"], vals["y_cg"], vals["z_cg"] = aero.r_cg_B_m
    vals["aspect_ratio"] = aero.aspect_ratio
    return np.array([float(vals[k]) for k in AERO_FIELDS])


def wheel_params(wheels) -> np.ndarray:
    """``wheels``: the (Wheel, body, qposadr, dofadr, k, c, (x, y, z)) tuples of :class:`VehicleSim`."""
    out = np.zeros((len(wheels), len(WHEEL_FIELDS)))
    for i, (w, b, qa, da, k, c, (x, y, z)) in enumerate(wheels):
        t = w.tyre
        out[i] = (b, qa, da, k, c, x, y, z, w.radius_m, t.cornering_stiffness_N_per_rad, t.mu, t.rolling_resistance,
                  t.v_min_m_s, t.v_stick_m_s, w.steered, w.braked, w.driven)
    return out


@numba.njit(cache=True, nogil=True)
def _isa_density(h):
    return 1.225 * (1.0 - 2.25577e-5 * h) ** 4.2559


@numba.njit(cache=True, nogil=True)
def _clip(x, lo, hi):
    return max(lo, min(hi, x))


@numba.njit(cache=True, nogil=True)
def _actuate(a, cmd, act, dt):
    """:meth:`CitationSim._actuate`: first-order surface, engine and flap lags, limits."""
    ks = min(1.0, dt / a[_SURFACE_TAU])
    ke = min(1.0, dt / a[_ENGINE_TAU])
    act[0] += ks * (_clip(cmd[0], a[_DE_MIN], a[_DE_MAX]) - act[0])
    act[1] += ks * (_clip(cmd[1], -a[_DA_LIM], a[_DA_LIM]) - act[1])
    act[2] += ks * (_clip(cmd[2], -a[_DR_LIM], a[_DR_LIM]) - act[2])
    act[3] += ke * (_clip(cmd[3], 0.0, 1.0) - act[3])
    act[4] = _clip(cmd[4], -a[_STEER_LIM], a[_STEER_LIM])
    act[5] = _clip(cmd[5], 0.0, 1.0)
    act[6] += min(1.0, dt / 8.0) * (cmd[6] - act[6])


@numba.njit(cache=True, nogil=True)
def _air_velocity(a, qvel, C):
    """The air velocity at the aerodynamic centre in body axes (u, v, w) and its size V: the CG's NED
    velocity turned into the body by C (body <- NED, row-major 3x3) plus omega x r_cg."""
    vN, vE, vD, p, q, r = qvel[0], qvel[1], qvel[2], qvel[3], qvel[4], qvel[5]
    x, y, z = a[_X_CG], a[_Y_CG], a[_Z_CG]
    ub = C[0] * vN + C[3] * vE + C[6] * vD
    vb = C[1] * vN + C[4] * vE + C[7] * vD
    wb = C[2] * vN + C[5] * vE + C[8] * vD
    u, v, w = ub + q * z - r * y, vb + r * x - p * z, wb + p * y - q * x
    return u, v, w, math.sqrt(u * u + v * v + w * w)


@numba.njit(cache=True, nogil=True)
def _aero_wrench(a, qpos, qvel, C, h0, act, hist, rate_hz, substeps, f):
    """:meth:`CitationSim.body_forces` (state of :meth:`CitationSim._update_state`) into f[0:6], body FRD."""
    u, v, w, V = _air_velocity(a, qvel, C)
    alpha = math.atan2(w, u) if V > 1.0 else 0.0
    beta = math.asin(max(-1.0, min(1.0, v / V))) if V > 1.0 else 0.0
    adot = 0.0 if math.isnan(hist[0]) else (alpha - hist[0]) * rate_hz * substeps
    hist[0] = alpha
    h = h0 - qpos[2]
    rho = _isa_density(h)
    thrust = act[3] * (a[_THRUST_MAX] * (rho / 1.225) ** 0.75)
    de, da, dr, flaps = act[0], act[1], act[2], act[6]
    V = max(V, 1.0)
    qbar = 0.5 * rho * V * V
    S, c, b = a[0], a[1], a[2]
    p, q, r = qvel[3], qvel[4], qvel[5]
    ph, qh, rh, ah = p * b / (2 * V), q * c / V, r * b / (2 * V), adot * c / V
    CL = a[3] + a[4] * alpha + a[5] * qh + a[6] * ah + a[7] * de + a[10] * flaps
    CD = a[8] + CL * CL / (math.pi * a[_AR] * a[9]) + a[11] * flaps
    CY = a[18] * beta + a[19] * ph + a[20] * rh + a[21] * da + a[22] * dr
    Cl = a[23] * beta + a[24] * ph + a[25] * rh + a[26] * da + a[27] * dr
    Cm = a[12] + a[13] * alpha + a[14] * qh + a[15] * ah + a[16] * de + a[17] * flaps
    Cn = a[28] * beta + a[29] * ph + a[30] * rh + a[31] * da + a[32] * dr
    L, D = qbar * S * CL, qbar * S * CD
    ca, sa = math.cos(alpha), math.sin(alpha)
    f[0], f[1], f[2] = -D * ca + L * sa + thrust, qbar * S * CY, -D * sa - L * ca
    f[3], f[4], f[5] = qbar * S * b * Cl, qbar * S * c * Cm, qbar * S * b * Cn


@numba.njit(cache=True, nogil=True)
def _tyres(wp, qpos, qvel, C, act, drive_N, n_driven, xfrc):
    """:meth:`VehicleSim._apply_tyres` with :meth:`TyreModel.force`."""
    vN, vE, vD, p, q, r = qvel[0], qvel[1], qvel[2], qvel[3], qvel[4], qvel[5]
    for i in range(wp.shape[0]):
        b, qa, dadr = int(wp[i, 0]), int(wp[i, 1]), int(wp[i, 2])
        load = -wp[i, 3] * qpos[qa] - wp[i, 4] * qvel[dadr]
        if load <= 0.0:
            for j in range(6):
                xfrc[b, j] = 0.0
            continue
        x, y, z = wp[i, 5], wp[i, 6], wp[i, 7]
        ub = C[0] * vN + C[3] * vE + C[6] * vD
        vb = C[1] * vN + C[4] * vE + C[7] * vD
        u, v = ub + q * z - r * y, vb + r * x - p * z
        delta = act[4] if wp[i, 14] != 0.0 else 0.0
        cd, sd = math.cos(delta), math.sin(delta)
        v_long, v_lat = u * cd + v * sd, -u * sd + v * cd
        drive = act[3] * drive_N / n_driven if wp[i, 16] != 0.0 else 0.0
        brake = act[5] if wp[i, 15] != 0.0 else 0.0
        mu = wp[i, 10]
        fmax = mu * load
        slip = math.atan2(v_lat, max(abs(v_long), wp[i, 12]))
        ft = -fmax * math.tanh(wp[i, 9] * slip / fmax)
        fl = drive - (brake * mu + wp[i, 11]) * load * math.tanh(v_long / wp[i, 13])
        fx, fy = fl * cd - ft * sd, fl * sd + ft * cd
        F0, F1, F2 = C[0] * fx + C[1] * fy, C[3] * fx + C[4] * fy, C[6] * fx + C[7] * fy
        rr = wp[i, 8]
        r0, r1, r2 = C[2] * rr, C[5] * rr, C[8] * rr
        xfrc[b, 0], xfrc[b, 1], xfrc[b, 2] = F0, F1, F2
        xfrc[b, 3], xfrc[b, 4], xfrc[b, 5] = r1 * F2 - r2 * F1, r2 * F0 - r0 * F2, r0 * F1 - r1 * F0


@numba.njit(cache=True, nogil=True)
def _rotation(qpos, C):
    """:func:`imurig.flights.vehicle.quat_to_C` of qpos[3:7] into C (row-major, body to world)."""
    w, x, y, z = qpos[3], qpos[4], qpos[5], qpos[6]
    C[0], C[1], C[2] = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)
    C[3], C[4], C[5] = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)
    C[6], C[7], C[8] = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)


@numba.njit(cache=True, nogil=True)
def run_steps(m_addr, d_addr, qpos, qvel, xfrc, n, substeps, rate_hz, t, h0, bid, io, a, wp,
              drive_N, n_driven, rows, row0):
    """``n`` samples of ``substeps`` MuJoCo steps with the commands io[0:7] held (de, da, dr, thr, steer,
    brake, flaps); the actual deflections io[7:14] and the previous α io[14] (NaN: none) carry over;
    the state after the steps goes to io[15:42] (:func:`_snapshot`). Sample i goes to rows[row0 + i]
    (:data:`ROW` columns). Returns the time after the last."""
    cmd, act, hist = io[0:7], io[7:14], io[14:15]
    dt = 1.0 / rate_hz
    C = np.empty(9)
    f = np.empty(6)
    for i in range(n):
        _actuate(a, cmd, act, dt)
        row = rows[row0 + i]
        for k in range(substeps):
            _rotation(qpos, C)
            _aero_wrench(a, qpos, qvel, C, h0, act, hist, rate_hz, substeps, f)
            xfrc[bid, 0] = C[0] * f[0] + C[1] * f[1] + C[2] * f[2]
            xfrc[bid, 1] = C[3] * f[0] + C[4] * f[1] + C[5] * f[2]
            xfrc[bid, 2] = C[6] * f[0] + C[7] * f[1] + C[8] * f[2]
            xfrc[bid, 3] = C[0] * f[3] + C[1] * f[4] + C[2] * f[5]
            xfrc[bid, 4] = C[3] * f[3] + C[4] * f[4] + C[5] * f[5]
            xfrc[bid, 5] = C[6] * f[3] + C[7] * f[4] + C[8] * f[5]
            if wp.shape[0]:
                _tyres(wp, qpos, qvel, C, act, drive_N, n_driven, xfrc)
            if k == 0:
                row[0] = t
                for j in range(7):
                    row[1 + j] = qpos[j]
                for j in range(6):
                    row[8 + j] = qvel[j]
            _mj_step(m_addr, d_addr)
        for j in range(6):
            row[14 + j] = (qvel[j] - row[8 + j]) * rate_hz
        for j in range(6):
            row[20 + j] = act[j]
        t += dt
    _snapshot(a, qpos, qvel, C, io)
    return t


@numba.njit(cache=True, nogil=True)
def _snapshot(a, qpos, qvel, C, io):
    """The controller's view of the state after the steps (:meth:`CitationSim._update_state`) into
    io[15:42]: C_NB (9, row-major), φ, θ, ψ, the CG's body velocity u, v, w, V, α, β, then qpos[0:3]
    and qvel[0:6]."""
    _rotation(qpos, C)
    for j in range(9):
        io[15 + j] = C[j]
    io[24] = math.atan2(C[7], C[8])
    io[25] = -math.asin(max(-1.0, min(1.0, C[6])))
    io[26] = math.atan2(C[3], C[0])
    u, v, w, V = _air_velocity(a, qvel, C)
    io[27], io[28], io[29], io[30] = u, v, w, V
    io[31] = math.atan2(w, u) if V > 1.0 else 0.0
    io[32] = math.asin(max(-1.0, min(1.0, v / V))) if V > 1.0 else 0.0
    for j in range(3):
        io[33 + j] = qpos[j]
    for j in range(6):
        io[36 + j] = qvel[j]
