"""The tilt table's truth signals: MuJoCo where the table moves, the closed form where it rests.

In an acquisition window the table holds its command; the servo has settled (2 s) and the
IMU case frame C is at rest, so the truth is the closed form (seed eq. 4.33-4.38 with the
table's errors):

    R_CW = R_MC^T Rz(phi)^T Ry(theta)^T R_WB^T          (theta, phi: the held joint angles)
    f_C = R_CW (0, 0, g),   w_C = R_CW Omega_W,   B_C = R_CW B_W,   theta_true = theta, phi_true = phi

which the MuJoCo table reproduces to 1e-11 g (tests/test_tilt_table.py). MuJoCo steps only the
moves: from the end of one window (the table at rest at the previous command) through the slew
and the settling to the start of the next window. Moves of equal length are batched into one
``mujoco.rollout`` call (one model per mounting). ``full_truth`` steps every sample instead (the
reference the stitched truth is tested against).
"""
from __future__ import annotations

import mujoco
import numpy as np
from mujoco import rollout

from imurig.kernel.progress import progress
from imurig.rigs.mujoco_rig import rollout_servo
from imurig.rigs.tilt_kinematics import MOUNTS, rot_y, rot_z, rotate_to_body

#: truth signals of the rig, name -> (sensor name in the MJCF, component)
SIGNALS = {"theta_true": ("theta_true", 0), "phi_true": ("phi_true", 0),
           **{f"{s}_{a}": (s, j) for s in ("f_C", "w_C", "B_C") for j, a in enumerate("xyz")}}
#: bound on the sensor data of one batched rollout call (bytes)
MAX_BATCH_BYTES = 64 * 2**20


def _fill_from_sensordata(out: dict, dst: slice, sd: np.ndarray, sl: dict, earth_W: np.ndarray) -> None:
    """Copy MuJoCo sensor rows (n, nsensordata) into the truth arrays at ``dst``; the gyro gets the
    Earth rate R_CW Omega_W added (MuJoCo's world does not turn)."""
    w = sd[:, sl["w_C"]] + rotate_to_body(sd[:, sl["q_WC"]], earth_W)
    for name, (sensor, j) in SIGNALS.items():
        out[name][dst] = w[:, j] if sensor == "w_C" else sd[:, sl[sensor]][:, j]


def full_truth(models, qpos0, ctrl, sl, earth_W) -> dict:
    """Truth signals (name -> (nbatch * nstep,)) with MuJoCo stepping every sample."""
    nb, nstep, _ = ctrl.shape
    sd = rollout_servo(models, np.asarray(qpos0), ctrl, desc="tilt table (MuJoCo)")
    out = {k: np.empty(nb * nstep) for k in SIGNALS}
    for b in range(nb):
        _fill_from_sensordata(out, slice(b * nstep, (b + 1) * nstep), sd[b], sl, earth_W)
    return out


def _rest_state(model, qpos, ctrl) -> np.ndarray:
    """MuJoCo's full physics state of the table at rest at ``qpos`` with command ``ctrl``."""
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    d = mujoco.MjData(model)
    d.qpos[:] = qpos
    d.ctrl[:] = ctrl
    mujoco.mj_forward(model, d)
    s = np.empty(mujoco.mj_stateSize(model, spec))
    mujoco.mj_getState(model, d, s, spec)
    return s


def stitched_truth(models, mounts, R_WB, ctrl, windows, sl, g, earth_W, B_W) -> dict:
    """Truth signals (name -> (nbatch * nstep,)): closed form in the windows, MuJoCo for the moves.

    ``ctrl`` (nbatch, nstep, 2) rad: each mounting's servo commands; ``windows``: (start, stop)
    sample indices of the acquisition windows (the command is held in each); ``mounts``: the
    mounting of each batch row; ``R_WB``: the base attitude.
    """
    nb, nstep, _ = ctrl.shape
    out = {k: np.empty(nb * nstep) for k in SIGNALS}
    up = np.array([0.0, 0.0, g])
    moves = []  # (length, batch row, start, initial qpos)
    for b in range(nb):
        prev_stop = 0
        for a, e in windows:
            theta, phi = ctrl[b, a]
            R_CW = MOUNTS[mounts[b]].T @ rot_z(phi).T @ rot_y(theta).T @ R_WB.T
            dst = slice(b * nstep + a, b * nstep + e)
            for s, v in (("f_C", up), ("w_C", earth_W), ("B_C", B_W)):
                for j, x in enumerate(R_CW @ v):
                    out[f"{s}_{'xyz'[j]}"][dst] = x
            out["theta_true"][dst], out["phi_true"][dst] = theta, phi
            if a > prev_stop:  # the table rests at the previous command when the move starts
                moves.append((a - prev_stop, b, prev_stop, ctrl[b, prev_stop - 1] if prev_stop else ctrl[b, 0]))
            prev_stop = e
    _rollout_moves(models, ctrl, moves, out, nstep, sl, earth_W)
    return out


def _rollout_moves(models, ctrl, moves, out, nstep, sl, earth_W) -> None:
    """MuJoCo for every move, batched by length (bounded memory), written into ``out``."""
    nsd = models[0].nsensordata
    datas = [mujoco.MjData(models[0]) for _ in range(2)]
    by_len: dict[int, list] = {}
    for mv in moves:
        by_len.setdefault(mv[0], []).append(mv)
    with progress(total=sum(m[0] for m in moves), desc="tilt table moves (MuJoCo)", unit="step") as bar:
        for length, group in by_len.items():
            per = max(1, MAX_BATCH_BYTES // (length * nsd * 8))
            for i in range(0, len(group), per):
                batch = group[i:i + per]
                ms = [models[b] for _, b, _, _ in batch]
                state = np.stack([_rest_state(models[b], q0, ctrl[b, a]) for _, b, a, q0 in batch])
                c = np.stack([ctrl[b, a:a + length] for _, b, a, _ in batch])
                _, sd = rollout.rollout(ms, datas[:min(2, len(batch))], state, c)
                for k, (_, b, a, _) in enumerate(batch):
                    _fill_from_sensordata(out, slice(b * nstep + a, b * nstep + a + length), sd[k], sl, earth_W)
                bar.update(length * len(batch))
