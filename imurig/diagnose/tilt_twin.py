"""The tilt table's dynamic twin: the recording's set-points replayed through the table.

The table's controller turns each step of the set-points (theta, phi) into a cosine slew
(:func:`slew_commands`, the law of :func:`imurig.rigs.tilt_schedule.command_profile`); the twin
(:func:`tilt_table_twin`) feeds those commands, offset by the surveyed table errors, to the rig's
own MuJoCo model and servo at the site's gravity and returns the specific force f_C and the
angular rate w_C at the 'imu' site, plus the linear response of f_C to a command offset per
set-point window (the nuisance of :func:`imurig.diagnose.tilt_dynamics.diagnose_tilt_dynamics`):
five replays, the commands and four window-offset perturbations.

Physics only where the table moves. MuJoCo steps from each change of the commands (any of the five)
until the servo's transient is below SETTLE_TOL of the move, N = ceil(ln(1 / SETTLE_TOL) / (min(kp / kv) dt))
samples after the last change (the servo's slow pole kp / kv = 20 /s in the MJCF:
:func:`imurig.rigs.mujoco_rig.servo_settle_samples`; 1.6 s); a hold shorter than that, or a logged ramp,
is stepped through, and so is a command at a joint's limit (the constraint, not the servo, sets the
rest). Each move starts at rest at the previous command; moves of equal length are batched into one
``mujoco.rollout`` call (:func:`imurig.rigs.tilt_truth.rollout_moves`, as the campaign's truth). At rest,
at the held command (theta, phi) of each replay, the closed form:

    f_C = R_CW (0, 0, g),   R_CW = R_MC^T Rz(phi)^T Ry(theta)^T R_WB^T,   w_C = 0

(Earth's rate left out), so the responses there are (f_C(command + delta) - f_C(command)) / delta of the
closed form. :func:`tilt_table_twin_full` steps every sample (the reference; tests/test_tilt_twin.py).
"""
from __future__ import annotations

import mujoco
import numpy as np

from imurig.kernel.errors import RecordingError
from imurig.kernel.recording import Recording
from imurig.kernel.site import Site
from imurig.kernel.units import DEG
from imurig.rigs.mujoco_rig import load_model, rollout_servo, sensor_slices, servo_settle_samples
from imurig.rigs.tilt_table import MOUNTS, _copy_model, _quat_wxyz, rot_x, rot_z
from imurig.rigs.tilt_truth import rest_attitude, rollout_moves

#: the servo's transient left, of the move, where the twin takes the table as at rest (closed form): at
#: 1e-14 the closed form equals MuJoCo's settled replay to a few ulp of g (tests/test_tilt_twin.py)
SETTLE_TOL = 1e-14
#: commands this far inside a joint's range keep the overdamped servo off the limit (its response is a
#: weighted mean of past commands): MuJoCo steps such a move without the constraint stage
LIMIT_MARGIN_RAD = 0.01


def slew_commands(setpoints: np.ndarray, slew_rate_rad_s: float, dt: float, min_slew_s: float = 0.5) -> np.ndarray:
    """The table controller's command (n, 2) rad for step set-points (n, 2) rad sampled every ``dt`` s.

    At every set-point change (sample i0, from p to q) the command follows the cosine slew of
    :func:`imurig.rigs.tilt_schedule.command_profile`: over N = max(round(min_slew / dt),
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


def tilt_table_twin(rec: Recording, gravity_m_s2: float | None = None, delta_rad: float = 1e-5,
                    settle_tol: float = SETTLE_TOL, stops: str = "infer") -> dict:
    """Replay the recording's set-points through the twin of the table (MuJoCo, the rig's own
    model and servo) with the surveyed table errors and the site's gravity; per contiguous run.

    Returns f_C (n, 3) m/s^2 and w_C (n, 3) rad/s at the 'imu' site (Earth's rate left out),
    r0_C (n, 3) m: the site's position from the axes' intersection in C (the lever arm the twin
    assumes), the set-point windows (start sample of each; a window runs to the next change),
    and the linear responses of f_C to a command offset of each window (see module doc of
    :func:`diagnose_tilt_dynamics`): ``resp`` (4, n, 3) for (theta, even windows), (theta,
    odd), (phi, even), (phi, odd), per rad: (f_C(command + delta_rad) - f_C(command)) / delta_rad.

    MuJoCo steps only where the table moves (module doc): from each change of the commands until
    ``settle_tol`` of the servo's transient is left (:func:`imurig.rigs.mujoco_rig.servo_settle_samples`);
    at rest, the closed form f_C = R_CW (0, 0, g), w_C = 0. :func:`tilt_table_twin_full` steps every sample.

    ``stops``: "model" keeps the MJCF's joint ranges (the Delft table's theta stops at +-1.75 rad); "infer"
    (the default) removes a joint's stops when the recording commands it beyond them: another lab's table
    evidently reaches its own set-points (:func:`_widen_stops`; ``stops_removed`` in the result names them).
    """
    plan = _plan(rec, gravity_m_s2, delta_rad, stops)
    f = np.empty((5, rec.n, 3))
    w = np.empty((rec.n, 3))
    up = np.array([0.0, 0.0, plan["gravity_m_s2"]])
    moves = []  # (model, commands, initial qpos, (replay, first sample))
    for b, mnt, m, ctrl in plan["replays"]:
        ns = servo_settle_samples(m, settle_tol)
        near = _near_limits(m, ctrl, LIMIT_MARGIN_RAD)
        free = _copy_model(m)  # no joint limit is reached: the constraint stage changes no number (skipped)
        free.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONSTRAINT
        for a, e, hold in _pieces(ctrl, ns, _near_limits(m, ctrl, 0.0)):
            if hold:  # at rest at the held command (theta, phi) of each replay: the closed form
                for v in range(5):
                    f[v, b.start + a:b.start + e] = rest_attitude(mnt, plan["R_WB"], *ctrl[v, a]) @ up
                w[b.start + a:b.start + e] = 0.0
            else:     # a move: from rest at the previous command (the first: as the full replay starts)
                mv = m if near[max(a - 1, 0):e].any() else free
                moves += [(mv, ctrl[v, a:e], ctrl[v, max(a - 1, 0)], (v, b.start + a)) for v in range(5)]

    def sink(tag, sd, knots, length):
        v, a = tag
        f[v, a:a + length] = sd[:, plan["sl"]["f_C"]]
        if v == 0:
            w[a:a + length] = sd[:, plan["sl"]["w_C"]]

    rollout_moves(moves, sink, desc="tilt-table twin moves (MuJoCo)")
    return _result(plan, f, w, delta_rad)


def tilt_table_twin_full(rec: Recording, gravity_m_s2: float | None = None, delta_rad: float = 1e-5,
                         stops: str = "infer") -> dict:
    """:func:`tilt_table_twin` with MuJoCo stepping every sample of the record (the reference the
    stitched twin is tested against)."""
    plan = _plan(rec, gravity_m_s2, delta_rad, stops)
    f = np.empty((5, rec.n, 3))
    w = np.empty((rec.n, 3))
    sl = plan["sl"]
    for b, _, m, ctrl in plan["replays"]:
        sd = rollout_servo([m] * 5, ctrl[:, 0], ctrl, desc="tilt-table twin (MuJoCo)")
        f[:, b] = sd[:, :, sl["f_C"]]
        w[b] = sd[0][:, sl["w_C"]]
    return _result(plan, f, w, delta_rad)


def _pieces(ctrl: np.ndarray, settle: int, limited: np.ndarray) -> list[tuple[int, int, bool]]:
    """(start, stop, hold) pieces of a replay's samples: a move from each change of the commands ``ctrl``
    (5, n, 2) to ``settle`` samples after the last change that follows within ``settle`` samples (a short
    hold or a ramp is stepped through), holds (at rest) in between. A sample whose command reaches a
    joint's limit (``limited`` (n,) True) counts as a change: the limit's constraint, not the servo,
    sets where the table rests, and MuJoCo steps it."""
    n = ctrl.shape[1]
    changed = np.any(ctrl[:, 1:] != ctrl[:, :-1], axis=(0, 2))
    ev = np.flatnonzero(np.concatenate(([bool(limited[0])], changed | limited[1:])))
    if ev.size == 0:
        return [(0, n, True)]
    new = np.concatenate(([True], np.diff(ev) >= settle))   # a change after the last one has settled
    starts, last = ev[new], ev[np.append(np.flatnonzero(new)[1:] - 1, ev.size - 1)]
    out, pos = [], 0
    for a, e in zip(starts.tolist(), np.minimum(n, last + settle).tolist()):
        if a > pos:
            out.append((pos, a, True))
        out.append((a, e, False))
        pos = e
    if pos < n:
        out.append((pos, n, True))
    return out


def _near_limits(m, ctrl: np.ndarray, margin: float) -> np.ndarray:
    """(n,) whether any of the commands ``ctrl`` (5, n, 2) rad comes within ``margin`` rad of the range
    of a limited joint."""
    jnt = m.actuator_trnid[:, 0]
    lo, hi = m.jnt_range[jnt].T
    lim = m.jnt_limited[jnt].astype(bool)
    return np.any(lim & ((ctrl <= lo + margin) | (ctrl >= hi - margin)), axis=(0, 2))


def _widen_stops(m, rec: Recording, theta_zero_rad: float) -> list[str]:
    """Remove the stops of each limited joint that the recording's set-points (plus the surveyed zero
    offset for theta) command beyond, less :data:`LIMIT_MARGIN_RAD`: the lab's table reaches where it is
    commanded, so the Delft table's stops do not apply. Returns the joints whose stops were removed."""
    out = []
    for name, zero in (("theta", theta_zero_rad), ("phi", 0.0)):
        j = m.joint(name).id
        sp = np.asarray(rec.channels[name], float) + zero
        lo, hi = m.jnt_range[j]
        if m.jnt_limited[j] and sp.size and (sp.min() < lo + LIMIT_MARGIN_RAD or sp.max() > hi - LIMIT_MARGIN_RAD):
            m.jnt_limited[j] = 0
            out.append(f"{name}: set-points {np.degrees(sp.min()):.1f} to {np.degrees(sp.max()):.1f} deg reach past "
                       f"the model's stops ({np.degrees(lo):.1f} to {np.degrees(hi):.1f} deg): stops removed")
    return out


def _plan(rec: Recording, gravity_m_s2: float | None, delta_rad: float, stops: str = "infer") -> dict:
    """Per contiguous run of the record: (slice, mounting, model, commands (5, n, 2) rad: the commanded
    trajectory and its four window-offset perturbations), with the window starts, the lever arm r0_C and
    the sensor slices."""
    site = Site.from_dict(rec.meta.get("site", {}))
    g = site.gravity_m_s2 if gravity_m_s2 is None else gravity_m_s2
    sv = rec.meta.get("table_survey") or {}
    proto = rec.meta.get("protocol") or {}
    rate = float(proto.get("slew_rate_deg_s", 6.0)) * DEG
    dt = 1.0 / rec.sample_rate_hz
    base = load_model("tilt_table.xml")
    if stops not in ("infer", "model"):
        raise ValueError(f"stops must be 'infer' or 'model', not {stops!r}")
    removed = _widen_stops(base, rec, float(sv.get("theta_zero_rad", 0.0))) if stops == "infer" else []
    base.opt.timestep = dt
    base.opt.gravity[:] = (0.0, 0.0, -g)
    bid_base, bid_mount = base.body("base").id, base.body("imu_mount").id
    R_WB = rot_z(np.float64(float(rec.meta.get("table_azimuth_deg", 0.0)) * DEG)) @ rot_x(
        np.float64(sv.get("level_x_rad", 0.0)))
    blocks = rec.blocks()
    mounts = _run_mounts(rec, blocks)
    r0 = np.empty((rec.n, 3))
    replays, starts = [], []
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
        replays.append((b, mnt, m, np.array(ctrl)))
        r0[b] = MOUNTS[mnt].T @ base.body_pos[bid_mount] + base.site_pos[base.site("imu").id]
        starts.append(b.start + ch)
    return {"replays": replays, "R_WB": R_WB, "sl": sensor_slices(base), "gravity_m_s2": g, "mounts": mounts,
            "r0_C": r0, "window_start": np.concatenate(starts), "stops_removed": removed}


def _result(plan: dict, f: np.ndarray, w: np.ndarray, delta_rad: float) -> dict:
    """The twin's output from the five replays' f_C (5, n, 3) (overwritten) and the commanded one's w_C."""
    resp = f[1:]
    resp -= f[0][None]
    resp /= delta_rad
    return {"f_C": f[0], "w_C": w, "r0_C": plan["r0_C"], "resp": resp, "window_start": plan["window_start"],
            "gravity_m_s2": plan["gravity_m_s2"], "mounts": plan["mounts"], "stops_removed": plan["stops_removed"]}


def _ramped(sp: np.ndarray) -> bool:
    """Whether the logged set-points ramp: some change lasts three or more consecutive samples
    (a stepped log changes once per move)."""
    moving = np.any(np.diff(sp, axis=0) != 0, axis=1).astype(np.int8)
    return bool(np.any(np.convolve(moving, np.ones(3, np.int8), mode="valid") == 3))
