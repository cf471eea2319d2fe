"""The turn table's truth signals: MuJoCo where the rate changes, the closed form where it is held.

The spindle is one hinge (spin axis e_z of the spindle frame S) turned by a velocity servo of gain kv
against the joint's inertia M (armature included); no damping, no friction, nothing touches, the
spindle is gravity-compensated. MuJoCo's implicit-fast step is then the linear recurrence

    omega_{k+1} = omega_k + h (kv c_k - kv omega_k) / (M + h kv),    theta_{k+1} = theta_k + h omega_{k+1}

(c_k the rate command of sample k, h the time step) and its site sensors at sample k are the rigid-body
kinematics of (theta_k, omega_k, omegadot_k = kv (c_k - omega_k) / M):

    R_WS = R_WB Rz(theta)        (base B: the levelling error; R_SC: the mount's wobble and mounting)
    w_C  = R_SC^T (omega e_z + R_WS^T Omega_W)                                       (Earth rate Omega_W)
    f_C  = R_SC^T (omegadot e_z x p_S + omega^2 e_z x (e_z x p_S) + R_WS^T (0, 0, g))  (site at p_S in S)

While a rate is held the command is the target times the once-per-round ripple of the command angle,
c_k = T (1 + a_rip sin(theta_cmd,k + phi_rip)); the rate follows from the recurrence's exact solution

    omega_k = (1 - beta)^k omega_0 + beta sum_{j<k} (1 - beta)^{k-1-j} c_j,    beta = h kv / (M + h kv)

(a first-order filter of the command; at constant rate omega = T once the ramp's transient has decayed)
and the angle is its running sum, theta = theta_0 + h sum omega, in MuJoCo's own order of additions.
MuJoCo (``mujoco.rollout``, the mountings batched) steps only the ramps between held rates; each ramp
starts from the state the closed form leaves, and the hold after it from the state MuJoCo leaves.
``full_truth`` steps every sample instead; the two agree to ~1e-15 relative (tests/test_turn_truth.py).
"""
from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
from mujoco import rollout
from scipy.signal import lfilter

from imurig.kernel.errors import ConfigError
from imurig.kernel.progress import progress
from imurig.rigs.mujoco_clock import untimed
from imurig.rigs.mujoco_rig import rollout_servo
from imurig.rigs.tilt_kinematics import rotate_to_body

#: rows per piece of the closed form's kinematics (bounded temporaries; results do not depend on it)
ROW_CHUNK = 1 << 16


def _mat(quat: np.ndarray) -> np.ndarray:
    R = np.empty(9)
    mujoco.mju_quat2Mat(R, np.asarray(quat, float) / np.linalg.norm(quat))
    return R.reshape(3, 3)


@dataclass(frozen=True)
class Spindle:
    """The constants of the closed form (module doc), read from one mounting's compiled model."""

    h: float
    kv: float
    M: float
    R_WB: np.ndarray
    R_SC: np.ndarray
    p_S: np.ndarray
    g_up_B: np.ndarray        # R_WB^T (0, 0, g): gravity's specific force in the base frame
    earth_B: np.ndarray       # R_WB^T Omega_W

    @classmethod
    def from_model(cls, model: mujoco.MjModel, earth_W: np.ndarray) -> "Spindle":
        """Read h, kv, M and the frames from ``model``; refuse a model the closed form does not hold for."""
        j = 0
        bad = []
        if model.nq != 1 or model.nv != 1 or model.nu != 1 or model.na != 0:
            bad.append("one hinge and one actuator")
        if model.dof_damping[j] != 0 or model.dof_frictionloss[j] != 0 or model.jnt_stiffness[j] != 0:
            bad.append("no damping, friction or stiffness on the spin joint")
        gain, bias = model.actuator_gainprm[0], model.actuator_biasprm[0]
        if bias[0] != 0 or bias[1] != 0 or bias[2] != -gain[0] or model.actuator_dyntype[0] != 0:
            bad.append("a velocity servo (force kv c - kv omega)")
        if model.opt.integrator != mujoco.mjtIntegrator.mjINT_IMPLICITFAST:
            bad.append("the implicit-fast integrator")
        if not np.array_equal(model.jnt_axis[j], [0, 0, 1]) or np.any(model.jnt_pos[j]):
            bad.append("the spin axis along the spindle's z through its origin")
        if bad:
            raise ConfigError("the turn table's closed-form truth needs " + "; ".join(bad) +
                              " (rigs/turn_table.xml); use TurnTable(truth='mujoco') for another model")
        d = mujoco.MjData(model)
        d.qpos[:] = 0.0
        mujoco.mj_forward(model, d)
        M = np.zeros(1)
        mujoco.mj_mulM(model, d, M, np.ones(1))
        spindle = model.jnt_bodyid[j]
        mount, site = model.body("imu_mount").id, model.site("imu").id
        if model.body_parentid[mount] != spindle or model.site_bodyid[site] != mount:
            raise ConfigError("the turn table's closed-form truth needs the IMU site on imu_mount on the spindle")
        R_WB = d.xmat[spindle].reshape(3, 3).copy()  # the spindle at theta = 0
        R_Sm = _mat(model.body_quat[mount])
        R_SC = R_Sm @ _mat(model.site_quat[site])
        p_S = model.body_pos[mount] + R_Sm @ model.site_pos[site]
        g_W = -np.asarray(model.opt.gravity, float)
        return cls(h=float(model.opt.timestep), kv=float(gain[0]), M=float(M[0]), R_WB=R_WB, R_SC=R_SC,
                   p_S=np.array(p_S, float), g_up_B=R_WB.T @ g_W, earth_B=R_WB.T @ np.asarray(earth_W, float))

    def hold(self, theta0: float, omega0: float, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(theta, omega), each (n + 1,), from the state (theta0, omega0) under the commands c (n,)."""
        beta = self.h * self.kv / (self.M + self.h * self.kv)
        omega = np.empty(c.size + 1)
        omega[0] = omega0
        omega[1:] = lfilter([beta], [1.0, -(1.0 - beta)], c, zi=[(1.0 - beta) * omega0])[0]
        steps = self.h * omega
        steps[0] = theta0
        return np.cumsum(steps), omega

    def sensors(self, theta: np.ndarray, omega: np.ndarray, c: np.ndarray, out: dict, dst: slice) -> None:
        """Write f_C_x/y/z, w_C_x/y/z at rows ``dst`` of ``out`` from (theta, omega, c) (n,) (module doc).

        Each output is a fixed combination, per axis j of C, of cos theta, sin theta, omegadot, omega^2
        (f_C) or omega (w_C) and a constant: the rows of R_SC^T applied to the terms of f_S and w_S."""
        u, e, R, (px, py) = self.g_up_B, self.earth_B, self.R_SC, self.p_S[:2]
        # f_S = (cos u_x + sin u_y - domega p_y - omega^2 p_x, cos u_y - sin u_x + domega p_x - omega^2 p_y, u_z)
        f_terms = np.array([[u[0], u[1], 0.0], [u[1], -u[0], 0.0], [-py, px, 0.0], [-px, -py, 0.0],
                            [0.0, 0.0, u[2]]]) @ R        # rows: cos, sin, domega, omega^2, 1
        # w_S = (cos e_x + sin e_y, cos e_y - sin e_x, e_z + omega)
        w_terms = np.array([[e[0], e[1], 0.0], [e[1], -e[0], 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, e[2]]]) @ R
        start = dst.start
        n = min(theta.size, ROW_CHUNK)
        cs, sn, dom, om2, tmp = (np.empty(n) for _ in range(5))  # scratch, reused piece after piece
        for a in range(0, theta.size, ROW_CHUNK):
            b = min(theta.size, a + ROW_CHUNK)
            m = b - a
            om = omega[a:b]
            np.cos(theta[a:b], out=cs[:m])
            np.sin(theta[a:b], out=sn[:m])
            np.multiply(c[a:b], self.kv, out=dom[:m])
            np.multiply(om, self.kv, out=tmp[:m])
            dom[:m] -= tmp[:m]
            dom[:m] /= self.M
            np.multiply(om, om, out=om2[:m])
            rows = slice(start + a, start + b)
            for j, ax in enumerate("xyz"):
                _combine(out[f"f_C_{ax}"][rows], f_terms[:, j], (cs[:m], sn[:m], dom[:m], om2[:m]), tmp[:m])
                _combine(out[f"w_C_{ax}"][rows], w_terms[:, j], (cs[:m], sn[:m], om), tmp[:m])


def _combine(dst: np.ndarray, k: np.ndarray, terms, tmp: np.ndarray) -> None:
    """dst = sum_i k_i terms_i + k_last, in place (terms with a zero coefficient skipped; ``tmp``: scratch)."""
    dst[...] = k[-1]
    for ki, x in zip(k[:-1], terms):
        if ki != 0.0:
            np.multiply(x, ki, out=tmp)
            dst += tmp


def _state(model, theta: float, omega: float, c: float) -> np.ndarray:
    """MuJoCo's full physics state of the spindle at (theta, omega) with command c."""
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    d = mujoco.MjData(model)
    d.qpos[0], d.qvel[0], d.ctrl[0] = theta, omega, c
    mujoco.mj_forward(model, d)
    s = np.empty(mujoco.mj_stateSize(model, spec))
    mujoco.mj_getState(model, d, s, spec)
    return s


def _qpos_qvel(model, state: np.ndarray) -> tuple[float, float]:
    d = mujoco.MjData(model)
    mujoco.mj_setState(model, d, state, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    return float(d.qpos[0]), float(d.qvel[0])


def stitched_truth(models, ctrls, ramps, arrays, off, sl, earth_W) -> None:
    """Fill ``arrays`` (f_C_x/y/z, w_C_x/y/z, spin_angle, each (n,); mounting b at rows off[b]:off[b + 1]):
    MuJoCo for the ramps, the closed form for the holds between them (module doc): the rows of
    :func:`stitched_states`, all at once."""
    states = stitched_states(models, ctrls, ramps, off, sl, earth_W)
    for a in range(0, off[-1], ROW_CHUNK):
        for k, v in states.rows(a, min(off[-1], a + ROW_CHUNK)).items():
            arrays[k][a:a + v.size] = v


@dataclass
class TurnStates:
    """The turn table's truth as states, its rows made on demand (:meth:`rows`): the spin angle theta and
    rate omega of every sample (omega where a rate is held), the rate commands c, the MuJoCo rows of each
    ramp (f_C, w_C with the Earth rate) and each mounting's :class:`Spindle` (the closed form's constants).
    Mounting b's rows are off[b]:off[b + 1]; ``spans`` lists (start, stop, b, ramp rows or None: a hold)."""

    theta: np.ndarray
    omega: np.ndarray
    ctrl: np.ndarray
    spans: list
    spindles: list

    def rows(self, a: int, b: int) -> dict:
        """f_C_x/y/z, w_C_x/y/z (the closed form's :meth:`Spindle.sensors` in a hold, MuJoCo's rows in a ramp)
        and spin_angle over samples [a, b): the same values for any split of the rows (pointwise)."""
        out = {f"{s}_{x}": np.empty(b - a) for s in ("f_C", "w_C") for x in "xyz"}
        for lo, hi, m, ramp in self.spans:
            lo_, hi_ = max(lo, a), min(hi, b)
            if lo_ >= hi_:
                continue
            if ramp is None:
                self.spindles[m].sensors(self.theta[lo_:hi_], self.omega[lo_:hi_], self.ctrl[lo_:hi_], out,
                                         slice(lo_ - a, hi_ - a))
            else:
                for k, v in ramp.items():
                    out[k][lo_ - a:hi_ - a] = v[lo_ - lo:hi_ - lo]
        out["spin_angle"] = self.theta[a:b].copy()
        return out


def stitched_states(models, ctrls, ramps, off, sl, earth_W) -> TurnStates:
    """The truth's states (:class:`TurnStates`): MuJoCo steps the ramps, the closed form the holds between
    them (module doc).

    ``ctrls``: each mounting's rate commands (rad/s); ``ramps``: each mounting's ramp starts (sample
    indices), every ramp ``n_ramp`` = the length of the last one (the spin-down, which ends the record)
    long; a hold runs from one ramp's end to the next ramp's start. The spindle starts at rest at 0."""
    spindles = [Spindle.from_model(m, earth_W) for m in models]
    n_ramp = ctrls[0].size - ramps[0][-1]
    theta, omega, ctrl = np.empty(off[-1]), np.zeros(off[-1]), np.empty(off[-1])
    for b, c in enumerate(ctrls):
        ctrl[off[b]:off[b + 1]] = c
    spans = []
    datas = [mujoco.MjData(models[0]) for _ in range(min(2, len(models)))]
    pos = [(0.0, 0.0) for _ in models]   # (theta, omega) at each mounting's next ramp
    with progress(total=sum(c.size for c in ctrls), desc="turn table (MuJoCo ramps, closed form)",
                  unit="sample") as bar:
        for k in range(max(len(r) for r in ramps)):
            batch = [b for b, r in enumerate(ramps) if k < len(r)]
            state = np.stack([_state(models[b], *pos[b], ctrls[b][ramps[b][k]]) for b in batch])
            c = np.stack([ctrls[b][ramps[b][k]:ramps[b][k] + n_ramp] for b in batch])[:, :, None]
            untimed()   # after _state's MjData: steps without MuJoCo's profiling clock (imurig.rigs.mujoco_clock)
            st, sd = rollout.rollout([models[b] for b in batch], datas[:len(batch)], state, c)
            done = 0
            for i, b in enumerate(batch):
                a = ramps[b][k]
                dst = slice(off[b] + a, off[b] + a + n_ramp)
                ramp = _ramp_rows(sd[i], sl, earth_W)
                theta[dst] = ramp.pop("spin_angle")
                spans.append((dst.start, dst.stop, b, ramp))
                pos[b] = _qpos_qvel(models[b], st[i, -1])
                stop = ramps[b][k + 1] if k + 1 < len(ramps[b]) else a + n_ramp
                if stop > a + n_ramp:
                    hold = slice(off[b] + a + n_ramp, off[b] + stop)
                    th, om = spindles[b].hold(pos[b][0], pos[b][1], ctrls[b][a + n_ramp:stop])
                    theta[hold], omega[hold] = th[:-1], om[:-1]
                    pos[b] = float(th[-1]), float(om[-1])
                    spans.append((hold.start, hold.stop, b, None))
                done += stop - a
            bar.update(done)
    return TurnStates(theta, omega, ctrl, sorted(spans, key=lambda s: s[0]), spindles)


def _ramp_rows(rows: np.ndarray, sl: dict, earth_W: np.ndarray) -> dict:
    """MuJoCo sensor rows (n, nsensordata) as truth columns; the gyro gets the Earth rate R_CW Omega_W added
    (MuJoCo's world does not turn)."""
    w = rows[:, sl["w_C"]] + rotate_to_body(rows[:, sl["q_WC"]], earth_W)
    out = {f"f_C_{ax}": rows[:, sl["f_C"].start + j].copy() for j, ax in enumerate("xyz")}
    out.update({f"w_C_{ax}": w[:, j].copy() for j, ax in enumerate("xyz")})
    out["spin_angle"] = rows[:, sl["spin_angle"].start].copy()
    return out


def _put_rows(arrays: dict, dst: slice, rows: np.ndarray, sl: dict, earth_W: np.ndarray) -> None:
    """MuJoCo sensor rows (n, nsensordata) into the truth columns at ``dst`` (:func:`_ramp_rows`)."""
    for k, v in _ramp_rows(rows, sl, earth_W).items():
        arrays[k][dst] = v


def full_truth(models, ctrl, arrays, off, sl, earth_W) -> None:
    """Fill ``arrays`` as :func:`stitched_truth` does, with MuJoCo stepping every sample (the reference).
    ``ctrl`` (nbatch, nstep, 1): the mountings' commands, zero-padded to the longest."""
    sizes = np.diff(off)

    def sink(a, b, sd):
        for k, n in enumerate(sizes):
            z = min(b, n)
            if z <= a:
                continue
            rows, dst = sd[k, :z - a], slice(off[k] + a, off[k] + z)
            _put_rows(arrays, dst, rows, sl, earth_W)

    rollout_servo(models, np.zeros((len(models), 1)), ctrl, desc="turn table (MuJoCo)", sink=sink)
