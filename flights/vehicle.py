"""A wheeled MuJoCo vehicle (the van, the Citation on its landing gear): the free body stepped
sample by sample with tyre forces, its state, its control inputs.

Tyre model (per wheel, horizontal body axes, SI):

    alpha  = atan2(v_lat, max(|v_long|, v_min))                  [rad]  slip angle (regularised)
    F_lat  = -mu N tanh(C_alpha alpha / (mu N))                  [N]    saturating cornering force
    F_long = F_drive - (b mu + c_rr) N tanh(v_long / v_stick)    [N]    brake fraction b, rolling resistance

v_long, v_lat: the contact point's velocity along / across the wheel (steered by delta).
N: the wheel load, from the sprung strut (stiffness k, damping c, deflection q < 0 when
compressed): N = max(0, -k q - c dq/dt). The wheels themselves are frictionless spheres in
MuJoCo (condim 1): MuJoCo carries the vertical contact, these forces carry the rest, so
steering, drive and braking are real control inputs and pitch/roll arise from the struts.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from imurig.flights.truth import BodyKinematics
from imurig.kernel.errors import ConfigError
from imurig.rigs.mujoco_clock import untimed
from imurig.rigs.mujoco_rig import load_model

ROW = 26   # a recorded sample: t, qpos[0:7], qvel[0:6], dv/dt[0:6], controls de, da, dr, thr, steer, brake


@dataclass(frozen=True)
class TyreModel:
    """Linear-then-saturating tyre (parameters in SI)."""

    cornering_stiffness_N_per_rad: float = 60_000.0
    mu: float = 0.8
    rolling_resistance: float = 0.015
    v_min_m_s: float = 3.0
    v_stick_m_s: float = 0.3

    def force(self, v_long: float, v_lat: float, load_N: float, drive_N: float = 0.0,
              brake: float = 0.0) -> tuple[float, float]:
        """(F_long, F_lat) N on the vehicle, in the wheel's axes."""
        if load_N <= 0.0:
            return 0.0, 0.0
        fmax = self.mu * load_N
        alpha = math.atan2(v_lat, max(abs(v_long), self.v_min_m_s))
        f_lat = -fmax * math.tanh(self.cornering_stiffness_N_per_rad * alpha / fmax)
        f_long = drive_N - (brake * self.mu + self.rolling_resistance) * load_N * math.tanh(v_long / self.v_stick_m_s)
        return f_long, f_lat


class State:
    """The vehicle's state at one sample, as plain floats (fast in the per-step loop)."""

    __slots__ = (
        "C",
        "V",
        "alpha",
        "beta",
        "chi",
        "gamma",
        "gs",
        "h",
        "p",
        "pD",
        "pE",
        "pN",
        "phi",
        "psi",
        "q",
        "r",
        "t",
        "theta",
        "u",
        "v",
        "vD",
        "vE",
        "vN",
        "w",
    )


@dataclass
class Cmd:
    """Control inputs: elevator, aileron, rudder (rad), throttle (0-1), nose-wheel steering (rad),
    brake (0-1), flaps (0-1, fraction of take-off flap)."""

    de: float = 0.0
    da: float = 0.0
    dr: float = 0.0
    thr: float = 0.0
    steer: float = 0.0
    brake: float = 0.0
    flaps: float = 0.0


@dataclass(frozen=True)
class Wheel:
    body: str
    joint: str
    radius_m: float
    tyre: TyreModel
    steered: bool = False
    driven: bool = False
    braked: bool = True


def quat_to_C(w, x, y, z):
    """Row-major 3x3 rotation matrix (body to world) of the unit quaternion (w, x, y, z), as 9 floats."""
    return (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y))


class VehicleSim:
    """A MuJoCo free body stepped at ``rate_hz`` (``substeps`` physics steps per sample), with
    tyre forces and a vehicle-specific force callback; records the kinematics of the body
    origin (the IMU) at every sample: position, velocity, acceleration, attitude, body rate.
    The recorded acceleration is (v_{k+1} − v_k)/Δt: exactly what MuJoCo's semi-implicit Euler
    step applied (its implicit strut damping makes that differ slightly from qacc), so the
    samples obey v_{k+1} = v_k + Δt a_k to rounding."""

    body_name = "vehicle"

    def __init__(self, asset: str, wheels: list[Wheel], rate_hz: float = 100.0, substeps: int = 1,
                 h0_m: float = 0.0):
        if rate_hz <= 0 or substeps < 1:
            raise ConfigError(f"rate_hz must be > 0 and substeps >= 1 (got {rate_hz}, {substeps})")
        self.model = load_model(asset)
        self.model.opt.timestep = 1.0 / (rate_hz * substeps)
        self.data = mujoco.MjData(self.model)
        self.rate_hz, self.substeps, self.h0_m = float(rate_hz), int(substeps), float(h0_m)
        self.dt = 1.0 / self.rate_hz
        self.bid = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, self.body_name)
        self.wheels = []
        for w in wheels:
            b = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, w.body)
            j = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_JOINT, w.joint)
            pos = self.model.body_pos[b]
            self.wheels.append((w, b, int(self.model.jnt_qposadr[j]), int(self.model.jnt_dofadr[j]),
                                float(self.model.jnt_stiffness[j]), float(self.model.dof_damping[self.model.jnt_dofadr[j]]),
                                (float(pos[0]), float(pos[1]), float(pos[2] + w.radius_m))))
        self._blocks: list = []          # the recorded samples: [block (BLOCK, ROW), rows used]
        self.t = 0.0
        self.s = State()
        self._update_state()

    # ----------------------------------------------------------------- state
    def _update_state(self):
        d, s = self.data, self.s
        s.pN, s.pE, s.pD, qw, qx, qy, qz = d.qpos[0:7].tolist()     # plain floats: 10x faster maths
        C = quat_to_C(qw, qx, qy, qz)
        s.t = self.t
        s.vN, s.vE, s.vD, s.p, s.q, s.r = d.qvel[0:6].tolist()
        s.C = C
        s.h = self.h0_m - s.pD
        s.phi = math.atan2(C[7], C[8])
        s.theta = -math.asin(max(-1.0, min(1.0, C[6])))
        s.psi = math.atan2(C[3], C[0])
        return self._ground_track(s)

    @staticmethod
    def _ground_track(s):
        """Ground speed, track and flight-path angle of the state ``s``."""
        s.gs = math.hypot(s.vN, s.vE)
        s.chi = math.atan2(s.vE, s.vN) if s.gs > 0.5 else s.psi
        s.gamma = math.atan2(-s.vD, max(s.gs, 1e-3))
        return s

    def body_velocity(self, x, y, z):
        """Velocity (body axes) of the body-fixed point (x, y, z)."""
        s, C = self.s, self.s.C
        ub = C[0] * s.vN + C[3] * s.vE + C[6] * s.vD
        vb = C[1] * s.vN + C[4] * s.vE + C[7] * s.vD
        wb = C[2] * s.vN + C[5] * s.vE + C[8] * s.vD
        return ub + s.q * z - s.r * y, vb + s.r * x - s.p * z, wb + s.p * y - s.q * x

    # ----------------------------------------------------------------- forces
    def _apply_tyres(self, cmd: Cmd):
        d, C = self.data, self.s.C
        for w, b, qa, da_, k, c, (x, y, z) in self.wheels:
            load = -k * d.qpos[qa] - c * d.qvel[da_]
            if load <= 0.0:
                d.xfrc_applied[b] = 0.0
                continue
            u, v, _ = self.body_velocity(x, y, z)
            delta = cmd.steer if w.steered else 0.0
            cd, sd = math.cos(delta), math.sin(delta)
            fl, ft = w.tyre.force(u * cd + v * sd, -u * sd + v * cd, load,
                                  drive_N=cmd.thr * self.drive_force_N / self.n_driven if w.driven else 0.0,
                                  brake=cmd.brake if w.braked else 0.0)
            fx, fy = fl * cd - ft * sd, fl * sd + ft * cd
            FN = (C[0] * fx + C[1] * fy, C[3] * fx + C[4] * fy, C[6] * fx + C[7] * fy)
            rr = w.radius_m
            rc = (C[2] * rr, C[5] * rr, C[8] * rr)   # contact point below the wheel centre
            d.xfrc_applied[b] = (FN[0], FN[1], FN[2], rc[1] * FN[2] - rc[2] * FN[1],
                                 rc[2] * FN[0] - rc[0] * FN[2], rc[0] * FN[1] - rc[1] * FN[0])

    drive_force_N = 0.0
    n_driven = 1

    def body_forces(self, cmd: Cmd):
        """Vehicle-specific force (N) and moment (N m) about the body's CoM, body axes."""
        return (0.0,) * 6

    def step(self, cmd: Cmd):
        """Advance one sample with the commands held; record the sample's kinematics."""
        d, m = self.data, self.model
        untimed()   # steps without MuJoCo's profiling clock (imurig.rigs.mujoco_clock): the same samples
        for k in range(self.substeps):
            if k:
                self._update_state()
            f = self.body_forces(cmd)
            C = self.s.C
            d.xfrc_applied[self.bid] = (
                C[0] * f[0] + C[1] * f[1] + C[2] * f[2], C[3] * f[0] + C[4] * f[1] + C[5] * f[2],
                C[6] * f[0] + C[7] * f[1] + C[8] * f[2], C[0] * f[3] + C[1] * f[4] + C[2] * f[5],
                C[3] * f[3] + C[4] * f[4] + C[5] * f[5], C[6] * f[3] + C[7] * f[4] + C[8] * f[5])
            if self.wheels:
                self._apply_tyres(cmd)
            if k == 0:
                block, i = self._reserve(1)
                row = block[i]
                row[0] = self.t
                row[1:8] = d.qpos[0:7]
                row[8:14] = d.qvel[0:6]
            mujoco.mj_step(m, d)
        # the acceleration the integrator applied over the sample (with implicit strut damping
        # this differs from qacc): v_{k+1} = v_k + dt a_k holds exactly
        row[14:20] = (d.qvel[0:6] - row[8:14]) * self.rate_hz
        row[20:26] = (cmd.de, cmd.da, cmd.dr, cmd.thr, cmd.steer, cmd.brake)
        self.t += self.dt
        self._update_state()

    def settle(self, seconds: float = 3.0):
        """Let the struts settle without recording (initial condition at rest), then zero velocities."""
        untimed()
        for _ in range(int(seconds * self.rate_hz * self.substeps)):
            self._apply_tyres(Cmd(brake=1.0))
            mujoco.mj_step(self.model, self.data)
            self._update_state()
        self.data.qvel[:] = 0.0
        self.data.time = 0.0
        self.t = 0.0
        self._update_state()

    def _reserve(self, n: int):
        """Room for ``n`` more consecutive samples in the record: (block, index of the first)."""
        if not self._blocks or self._blocks[-1][1] + n > self._blocks[-1][0].shape[0]:
            # untouched rows cost no memory: one block holds 8.7 min at 1 kHz (87 at 100 Hz), so the record is
            # not copied
            self._blocks.append([np.empty((max(n, 1 << 19), ROW)), 0])
        last = self._blocks[-1]
        i = last[1]
        last[1] = i + n
        return last[0], i

    def kinematics(self):
        """The recorded samples as :class:`imurig.flights.truth.BodyKinematics` plus controls."""
        a = (np.concatenate([b[:n] for b, n in self._blocks]) if len(self._blocks) > 1
             else self._blocks[0][0][:self._blocks[0][1]] if self._blocks else np.empty((0, ROW)))
        controls = {k: a[:, 20 + i] for i, k in enumerate(("de", "da", "dr", "thr", "steer", "brake"))}
        return BodyKinematics(time_s=a[:, 0], p_N=a[:, 1:4], q_NB=a[:, 4:8], v_N=a[:, 8:11],
                              w_NB_B=a[:, 11:14], a_N=a[:, 14:17], wdot_NB_B=a[:, 17:20],
                              rate_hz=self.rate_hz, controls=controls)
