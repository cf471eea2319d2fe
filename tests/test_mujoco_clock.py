"""MuJoCo stepped without the bindings' profiling clock (imurig.rigs.mujoco_clock): the same bits, no clock
read, a user's own timer kept."""
from __future__ import annotations

import mujoco
import numpy as np

from imurig.rigs.mujoco_clock import _STATE, _callback, untimed
from imurig.rigs.mujoco_rig import load_model


def _fly(model, steps: int, plain: bool = False) -> np.ndarray:
    d = mujoco.MjData(model)   # (newer bindings install their clock again here)
    if plain:
        assert untimed()
    d.qpos[2], d.qvel[0], d.qvel[4] = -1000.0, 100.0, 0.05
    d.xfrc_applied[1] = (1e3, -2e3, 5e4, 10.0, 2e3, -30.0)
    mujoco.mj_step(model, d, nstep=steps)
    return np.concatenate([d.qpos, d.qvel, d.qacc, d.sensordata]), d.timer[mujoco.mjtTimer.mjTIMER_STEP].duration


def test_the_library_and_its_callback_are_found():
    assert _callback() is not None   # MuJoCo's library ships with the package and exports mjcb_time


def test_steps_are_the_same_bits_without_the_clock():
    """With the bindings' default clock (or, in a release without one, a clock of the test's own) the
    timers run; after untimed() the clock is not read, and the state is the same to the bit."""
    model = load_model("citation.xml")
    model.opt.timestep = 1e-3
    cb = _callback()
    saved = cb.value
    ticks = []
    try:
        if _STATE["default"] is not None:
            cb.value = _STATE["default"]   # the bindings' clock, as at import (an earlier test may have cleared it)
        else:
            mujoco.set_mjcb_time(lambda: float(ticks.append(1) or len(ticks)))
        timed, t_on = _fly(model, 3000)
        if _STATE["default"] is None:
            mujoco.set_mjcb_time(None)
            cb.value = None
        plain, t_off = _fly(model, 3000, plain=True)
        assert cb.value is None
    finally:
        cb.value = saved
    assert t_on > 0 and t_off == 0.0            # the clock was read before, and not after
    assert timed.tobytes() == plain.tobytes()   # the state, to the bit


def test_a_timer_the_user_set_stays():
    calls = []

    def clock():
        calls.append(1)
        return float(len(calls))

    cb = _callback()
    saved = cb.value
    mujoco.set_mjcb_time(clock)
    try:
        assert untimed() is False and cb.value is not None
        model = load_model("citation.xml")
        _, t = _fly(model, 2)
        assert calls and t > 0
    finally:
        mujoco.set_mjcb_time(None)
        cb.value = saved
