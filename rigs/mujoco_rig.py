"""Shared MuJoCo plumbing for rigs: load an MJCF asset, roll out servo commands in chunks.

MuJoCo's site sensors are noise-free; they give the ideal truth at the IMU. Errors are
added later by the sensor chain (:mod:`imurig.sensors`).
"""
from __future__ import annotations

from importlib import resources

import mujoco
import numpy as np
from mujoco import rollout

from imurig.kernel.errors import ConfigError
from imurig.kernel.progress import progress
from imurig.rigs.mujoco_clock import untimed


def load_model(asset: str) -> mujoco.MjModel:
    """Compile ``imurig/assets/<asset>`` (an MJCF file shipped with the package)."""
    xml = resources.files("imurig.assets").joinpath(asset).read_text()
    return mujoco.MjModel.from_xml_string(xml)


def sensor_slices(model: mujoco.MjModel) -> dict[str, slice]:
    """Name -> slice into ``sensordata`` for every named sensor."""
    out = {}
    for i in range(model.nsensor):
        name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_SENSOR, i)
        adr, dim = int(model.sensor_adr[i]), int(model.sensor_dim[i])
        out[name] = slice(adr, adr + dim)
    return out


def rollout_servo(models: list[mujoco.MjModel], qpos0: np.ndarray, ctrl: np.ndarray,
                  chunk: int = 200_000, desc: str = "MuJoCo rollout", sink=None) -> np.ndarray | None:
    """Roll out position-servo commands on a batch of models, in time chunks.

    Parameters
    ----------
    models : nbatch models of identical size (e.g. one per IMU mounting).
    qpos0 : (nbatch, nq) initial joint positions (velocities start at zero).
    ctrl : (nbatch, nstep, nu) servo commands, one row per time step.
    sink : optional ``sink(a, b, sensordata)``, called with each chunk's rows [a, b) (nbatch, b - a,
        nsensordata) instead of keeping them: the whole array is then never built (returns None).

    Returns
    -------
    sensordata : (nbatch, nstep, nsensordata). Row i is evaluated at time i * timestep,
        before step i integrates (MuJoCo computes sensors in mj_forward inside mj_step).
    """
    nbatch, nstep, _ = ctrl.shape
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    nthread = min(nbatch, 2)
    datas = [mujoco.MjData(models[0]) for _ in range(nthread)]
    state = np.zeros((nbatch, mujoco.mj_stateSize(models[0], spec)))
    for b, m in enumerate(models):
        d = mujoco.MjData(m)
        d.qpos[:] = qpos0[b]
        d.ctrl[:] = ctrl[b, 0]
        mujoco.mj_forward(m, d)
        mujoco.mj_getState(m, d, state[b], spec)
    out = None if sink is not None else np.empty((nbatch, nstep, models[0].nsensordata))
    untimed()   # after the MjData above (each installs the bindings' clock again): steps without timers
    with progress(total=nstep, desc=desc, unit="step") as bar:
        for a in range(0, nstep, chunk):
            b = min(nstep, a + chunk)
            st, sd = rollout.rollout(models, datas, state, np.ascontiguousarray(ctrl[:, a:b]))
            if sink is not None:
                sink(a, b, sd)
            else:
                out[:, a:b] = sd
            state = st[:, -1].copy()
            bar.update(b - a)
    return out


def servo_settle_samples(model: mujoco.MjModel, tol: float) -> int:
    """Time steps after the last change of the commands within which the position servos' transient
    falls below ``tol`` of the move.

    A position servo (stiffness kp, damping kv) on a joint of inertia I leaves an error e from its held
    command with I e'' + kv e' + kp e = 0: poles s = (-kv +- sqrt(kv^2 - 4 I kp)) / (2 I). Overdamped
    (kv^2 > 4 I kp; the tilt table's servos by a factor ~10), the slow pole decays at
    r = kv (1 - sqrt(1 - 4 I kp / kv^2)) / (2 I) >= kp / kv whatever I (coupled joints too: each mode v
    solves the scalar quadratic v^H (M s^2 + Kv s + Kp) v = 0 of the same form). So the transient is below
    ``tol`` of its start after N = ceil(ln(1 / tol) / (min(kp / kv) dt)) steps. MuJoCo's implicitly
    damped step (implicitfast) decays at least as fast: its slowest eigenvalue is below
    exp(-dt min(kp / kv)) (tests/test_tilt_twin.py).
    """
    if not 0 < tol < 1:
        raise ConfigError(f"the settling tolerance must lie in (0, 1), got {tol}")
    kp = model.actuator_gainprm[:, 0]
    kv = -model.actuator_biasprm[:, 2]
    if model.nu == 0 or np.any(kp <= 0) or np.any(kv <= 0) or np.any(model.actuator_biasprm[:, 1] != -kp):
        raise ConfigError("the model's actuators must all be position servos with kp > 0 and kv > 0")
    rate = float(np.min(kp / kv))
    return int(np.ceil(np.log(1.0 / tol) / (rate * model.opt.timestep)))
