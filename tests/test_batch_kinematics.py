"""The batched forward kinematics against MuJoCo's own mj_kinematics, row by row, on the rigs' models."""
import mujoco
import numpy as np
import pytest

from imurig.rigs.batch_kinematics import forward_kinematics
from imurig.rigs.mujoco_rig import load_model

EPS = np.finfo(float).eps


@pytest.mark.parametrize("name", ["tilt_table.xml", "turn_table.xml", "mag_rig.xml"])
def test_agrees_with_mj_kinematics(name):
    model, rng = load_model(name), np.random.default_rng(11)
    data = mujoco.MjData(model)
    T = 40
    qpos = rng.uniform(-3.5, 3.5, (T, model.nq))
    q = rng.normal(size=(T, 4))
    over = {model.nbody - 1: q / np.linalg.norm(q, axis=1, keepdims=True)}   # a per-row mounting
    xpos, xquat = forward_kinematics(model, qpos, over)
    scale = 1 + np.max(np.abs(model.body_pos)) * model.nbody
    for k in range(T):
        model.body_quat[model.nbody - 1] = over[model.nbody - 1][k]
        data.qpos[:] = qpos[k]
        mujoco.mj_kinematics(model, data)
        # rounding only: a few ulps of the positions' scale; quaternions up to their sign
        assert np.max(np.abs(xpos[k] - data.xpos)) <= 16 * EPS * scale
        sign = np.sign(np.sum(xquat[k] * data.xquat, axis=1))[:, None]
        assert np.max(np.abs(sign * xquat[k] - data.xquat)) <= 16 * EPS
    # a moved joint moves the bodies (the check above cannot pass on a constant answer)
    assert np.ptp(xquat[:, -1], axis=0).max() > 0.1


def test_free_joints_are_left_to_mujoco():
    model = load_model("citation.xml")
    assert forward_kinematics(model, np.zeros((3, model.nq))) is None


def test_row_by_row_fallback_agrees_and_restores_the_model():
    from imurig.rigs.batch_kinematics import kinematics_by_row

    model, rng = load_model("tilt_table.xml"), np.random.default_rng(5)
    qpos = np.repeat(rng.uniform(-1, 1, (6, model.nq)), 3, axis=0)   # rows at rest take the last poses
    b = model.nbody - 1
    before = model.body_quat[b].copy()
    q = np.tile([np.cos(0.3), np.sin(0.3), 0.0, 0.0], (qpos.shape[0], 1))
    xp, xq = kinematics_by_row(model, qpos, {b: q})
    fp, fq = forward_kinematics(model, qpos, {b: q})
    assert np.max(np.abs(xp - fp)) <= 16 * EPS * (1 + np.max(np.abs(model.body_pos)) * model.nbody)
    assert np.max(np.abs(np.abs(np.sum(xq * fq, axis=2)) - 1)) <= 16 * EPS
    assert np.array_equal(model.body_quat[b], before)
