"""The tilt table's dynamic twin: the recording's set-points replayed through the table.

The table's controller turns each step of the set-points (theta, phi) into a cosine slew
(:func:`slew_commands`, the law of :func:`imurig.rigs.tilt_table._command_profile`); the twin
(:func:`tilt_table_twin`) feeds those commands, offset by the surveyed table errors, to the rig's
own MuJoCo model and servo at the site's gravity and returns the specific force f_C and the
angular rate w_C at the 'imu' site, plus the linear response of f_C to a command offset per
set-point window (the nuisance of :func:`imurig.diagnose.tilt_dynamics.diagnose_tilt_dynamics`).
"""
from __future__ import annotations

import numpy as np

from imurig.kernel.errors import RecordingError
from imurig.kernel.recording import Recording
from imurig.kernel.site import Site
from imurig.kernel.units import DEG
from imurig.rigs.mujoco_rig import load_model, rollout_servo, sensor_slices
from imurig.rigs.tilt_table import MOUNTS, _copy_model, _quat_wxyz, rot_x, rot_z


def slew_commands(setpoints: np.ndarray, slew_rate_rad_s: float, dt: float, min_slew_s: float = 0.5) -> np.ndarray:
    """The table controller's command (n, 2) rad for step set-points (n, 2) rad sampled every ``dt`` s.

    At every set-point change (sample i0, from p to q) the command follows the cosine slew of
    :func:`imurig.rigs.tilt_table._command_profile`: over N = max(round(min_slew / dt),
    ceil(max|q - p| / rate * pi / 2 / dt)) samples, c(i0 + k - 1) = p + (1 - cos(pi k / N)) / 2 (q - p),
    k = 1..N (peak rate ``slew_rate_rad_s``); elsewhere the command is the set-point.
    """
    sp = np.asarray(setpoints, float)
    out = sp.copy()
    for i0 in np.flatnonzero(np.any(np.diff(sp, axis=0) != 0, axis=1)) + 1:
        p, q = sp[i0 - 1], sp[i0]
        n = max(round(min_slew_s / dt), int(np.ceil(float(np.max(np.abs(q - p))) / slew_rate_rad_s * np.pi / 2 / dt)))
        s = (1 - np.cos(np.pi * np.arange(1, n + 1) / n)) / 2
        k = min(n, sp.shape[0] - i0)
        out[i0:i0 + k] = p + s[:k, None] * (q - p)
    return out


def _run_mounts(rec: Recording, blocks) -> list[str]:
    runs = list(rec.meta.get("runs", ["z_up"]))
    seg = rec.segments
    mounts = seg.get("mount")
    out = []
    for b in blocks:
        t0, t1 = rec.time_s[b.start], rec.time_s[b.stop - 1]
        inside = np.flatnonzero((seg["start_s"] >= t0) & (seg["start_s"] <= t1))
        if inside.size == 0:
            out.append(runs[0])
        elif mounts is not None:
            out.append(str(mounts[inside[0]]))
        else:
            out.append(runs[int(seg.get("run", np.zeros(rec.n_segments, int))[inside[0]])])
    return out


def tilt_table_twin(rec: Recording, gravity_m_s2: float | None = None, delta_rad: float = 1e-5) -> dict:
    """Replay the recording's set-points through the twin of the table (MuJoCo, the rig's own
    model and servo) with the surveyed table errors and the site's gravity; per contiguous run.

    Returns f_C (n, 3) m/s^2 and w_C (n, 3) rad/s at the 'imu' site (Earth's rate left out),
    r0_C (n, 3) m: the site's position from the axes' intersection in C (the lever arm the twin
    assumes), the set-point windows (start sample of each; a window runs to the next change),
    and the linear responses of f_C to a command offset of each window (see module doc of
    :func:`diagnose_tilt_dynamics`): ``resp`` (4, n, 3) for (theta, even windows), (theta,
    odd), (phi, even), (phi, odd), per rad.
    """
    site = Site.from_dict(rec.meta.get("site", {}))
    g = site.gravity_m_s2 if gravity_m_s2 is None else gravity_m_s2
    sv = rec.meta.get("table_survey") or {}
    proto = rec.meta.get("protocol") or {}
    rate = float(proto.get("slew_rate_deg_s", 6.0)) * DEG
    fs = rec.sample_rate_hz
    dt = 1.0 / fs
    base = load_model("tilt_table.xml")
    base.opt.timestep = dt
    base.opt.gravity[:] = (0.0, 0.0, -g)
    bid_base, bid_mount = base.body("base").id, base.body("imu_mount").id
    R_WB = rot_z(np.float64(float(rec.meta.get("table_azimuth_deg", 0.0)) * DEG)) @ rot_x(
        np.float64(sv.get("level_x_rad", 0.0)))
    sl = sensor_slices(base)
    blocks = rec.blocks()
    mounts = _run_mounts(rec, blocks)
    n = rec.n
    f = np.empty((n, 3))
    w = np.empty((n, 3))
    r0 = np.empty((n, 3))
    resp = np.zeros((4, n, 3))
    starts = []
    for b, mnt in zip(blocks, mounts):
        if mnt not in MOUNTS:
            raise RecordingError(f"unknown mounting '{mnt}' in the recording; the tilt table knows {sorted(MOUNTS)}")
        m = _copy_model(base)
        m.body_quat[bid_base] = _quat_wxyz(R_WB)
        m.body_quat[bid_mount] = _quat_wxyz(MOUNTS[mnt])
        sp = np.stack([rec.channels["theta"][b], rec.channels["phi"][b]], 1)
        # a logger that writes the ramp (set-points changing on consecutive samples) gives the
        # trajectory itself: the twin's servo must not limit it to the protocol's slew rate
        ramp = np.max(np.abs(np.diff(sp, axis=0)), initial=0.0) / dt
        run_rate = max(rate, 1.5 * ramp) if _ramped(sp) else rate
        cmd = slew_commands(sp, run_rate, dt) + np.array([sv.get("theta_zero_rad", 0.0),
                                                      sv.get("phi_zero_rad", {}).get(mnt, 0.0)])
        # a window starts where the set-points start to change after a hold: a stepped log changes
        # once per move, a ramped one on every sample of the ramp, which is still one move
        moving = np.any(np.diff(sp, axis=0) != 0, axis=1)
        first = moving & ~np.concatenate(([False], moving[:-1]))
        ch = np.concatenate(([0], np.flatnonzero(first) + 1))
        win = np.searchsorted(ch, np.arange(sp.shape[0]), side="right") - 1
        ctrl = [cmd]
        for j in range(2):
            for parity in (0, 1):
                c = cmd.copy()
                c[:, j] += delta_rad * (win % 2 == parity)
                ctrl.append(c)
        ctrl = np.array(ctrl)
        sd = rollout_servo([m] * 5, ctrl[:, 0], ctrl, desc="tilt-table twin (MuJoCo)")
        f[b] = sd[0][:, sl["f_C"]]
        w[b] = sd[0][:, sl["w_C"]]
        resp[:, b] = (sd[1:, :, sl["f_C"]] - sd[0][None, :, sl["f_C"]]) / delta_rad
        r0[b] = MOUNTS[mnt].T @ base.body_pos[bid_mount] + base.site_pos[base.site("imu").id]
        starts.append(b.start + ch)
    return {"f_C": f, "w_C": w, "r0_C": r0, "resp": resp, "window_start": np.concatenate(starts), "gravity_m_s2": g,
            "mounts": mounts}


def _ramped(sp: np.ndarray) -> bool:
    """Whether the logged set-points ramp: some change lasts three or more consecutive samples
    (a stepped log changes once per move)."""
    moving = np.any(np.diff(sp, axis=0) != 0, axis=1).astype(np.int8)
    return bool(np.any(np.convolve(moving, np.ones(3, np.int8), mode="valid") == 3))
