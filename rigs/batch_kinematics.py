"""Forward kinematics of a MuJoCo model's hinge-and-slide trees for many joint states at once.

For each body i (parent p), as ``mj_kinematics`` computes it, row by row over T states::

    x_i = x_p + R_p r_i,   q_i = q_p (x) q0_i                    (body_pos r_i, body_quat q0_i)
    for each joint j of body i, in order (axis a_j, anchor s_j in the body frame, angle or shift
    u = qpos[j] - qpos0[j]):
        anchor  c = x_i + rot(q_i, s_j)
        hinge:  q_i <- q_i (x) quat(a_j, u),  x_i <- c - rot(q_i, s_j)
        slide:  x_i <- x_i + rot(q_i, a_j) u
    q_i <- q_i / |q_i|

vectorised over the T rows (a loop over the few bodies, none over the rows). It agrees with MuJoCo's
``mj_kinematics`` to rounding (tests/test_batch_kinematics.py); models with free or ball joints or mocap
bodies are not covered (:func:`forward_kinematics` returns None): :func:`kinematics_by_row` steps MuJoCo's
kinematics row by row for them.
"""
from __future__ import annotations

import mujoco
import numpy as np

from imurig.kernel.quaternion import q_mult, q_rotate


def forward_kinematics(model: mujoco.MjModel, qpos: np.ndarray, body_quat: dict | None = None):
    """(xpos (T, nbody, 3), xquat (T, nbody, 4)) for the joint states ``qpos`` (T, nq); ``body_quat``:
    {body id: (T, 4) unit quaternions} in place of those bodies' ``body_quat``. None where the model has
    a free or ball joint or a mocap body (module doc)."""
    if np.any(np.isin(model.jnt_type, (mujoco.mjtJoint.mjJNT_FREE, mujoco.mjtJoint.mjJNT_BALL))) or \
            np.any(model.body_mocapid >= 0):
        return None
    qpos = np.asarray(qpos, float)
    T, nb = qpos.shape[0], model.nbody
    xpos, xquat = np.zeros((T, nb, 3)), np.zeros((T, nb, 4))
    xquat[:, 0, 0] = 1.0
    for i in range(1, nb):
        p = model.body_parentid[i]
        q0 = (body_quat or {}).get(i, model.body_quat[i])
        x = xpos[:, p] + q_rotate(xquat[:, p], model.body_pos[i])
        q = q_mult(xquat[:, p], np.broadcast_to(q0, (T, 4)))
        for j in range(model.body_jntadr[i], model.body_jntadr[i] + model.body_jntnum[i]):
            adr, axis, anchor = model.jnt_qposadr[j], model.jnt_axis[j], model.jnt_pos[j]
            u = qpos[:, adr] - model.qpos0[adr]
            if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_SLIDE:
                x = x + q_rotate(q, axis) * u[:, None]
            else:   # hinge
                c = x + q_rotate(q, anchor)
                half = 0.5 * u[:, None]
                q = q_mult(q, np.concatenate([np.cos(half), np.sin(half) * axis], axis=1))
                x = c - q_rotate(q, anchor)
        xpos[:, i] = x
        xquat[:, i] = q / np.linalg.norm(q, axis=1, keepdims=True)
    return xpos, xquat


def kinematics_by_row(model: mujoco.MjModel, qpos: np.ndarray, overrides: dict):
    """(xpos, xquat) of every body for each row of ``qpos``, ``mj_kinematics`` row by row (free or ball
    joints, mocap bodies); a row equal to the one before takes its poses."""
    data = mujoco.MjData(model)
    T, nb = len(qpos), model.nbody
    xpos, xquat = np.empty((T, nb, 3)), np.empty((T, nb, 4))
    saved = {bid: model.body_quat[bid].copy() for bid in overrides}
    # rows equal to the one before (a rig at rest) take its poses: one comparison over the whole record
    same = np.concatenate([[False], np.all([(x[1:] == x[:-1]).all(axis=1) for x in (qpos, *overrides.values())],
                                           axis=0)])[:T]
    try:
        for k in np.flatnonzero(~same).tolist():
            for bid, q in overrides.items():
                model.body_quat[bid] = q[k]
            data.qpos[:] = qpos[k]
            mujoco.mj_kinematics(model, data)
            xpos[k], xquat[k] = data.xpos, data.xquat
    finally:
        for bid, q in saved.items():
            model.body_quat[bid] = q
    # the rows at rest take the poses of the last row computed before them (one gather, no Python per row)
    last = np.maximum.accumulate(np.where(same, 0, np.arange(T)))
    return xpos[last], xquat[last]
