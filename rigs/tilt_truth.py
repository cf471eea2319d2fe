"""The tilt table's truth signals: MuJoCo where the table moves, the closed form where it rests.

In an acquisition window the table holds its command; the servo has settled (2 s) and the
IMU case frame C is at rest, so the truth is the closed form (seed eq. 4.33-4.38 with the
table's errors):

    R_CW = R_MC^T Rz(phi)^T Ry(theta)^T R_WB^T          (theta, phi: the held joint angles)
    f_C = R_CW (0, 0, g),   w_C = R_CW Omega_W,   B_C = R_CW B_W,   theta_true = theta, phi_true = phi

which the MuJoCo table reproduces to 1e-11 g (tests/test_tilt_table.py). MuJoCo steps only the
moves: from the end of one window (the table at rest at the previous command) through the slew
and the settling to the start of the next window. Moves of equal length are batched into one
``mujoco.rollout`` call (one model per mounting; :func:`rollout_moves`, which the diagnosis's twin
:mod:`imurig.diagnose.tilt_twin` shares). ``full_truth`` steps every sample instead (the reference the
stitched truth is tested against).

A move may be stepped at a coarser time step h = k dt (``move_substeps`` k > 1): MuJoCo steps at dt
for FINE_HEAD samples from a move's start (the command's step at the move's start sets off the servo's
transients: the fast pole kv / armature ~ 1e3 /s and the slow one kp / kv = 20 /s) and around the slew's
end (where the commanded acceleration jumps), at h elsewhere, and the truth in between is linear in
time between the stepped samples (the last interval ends at the next window's first sample, the closed
form at rest):

    x(t_a + i dt) = x_j + (i - i_j) / (i_{j+1} - i_j) (x_{j+1} - x_j),   i_j <= i < i_{j+1}

Against k = 1, a 10 ms step (k = 10, the campaign's default) differs by < 5e-4 m/s^2 in f_C (a third
of the accelerometer channel's ADC step) and < 4e-6 rad in the joint angles (under the table survey's
2 arcsec) during a move, and not at all in the windows (tests/test_tilt_table.py); the 1 ms step
itself differs from a 0.25 ms one by 3e-3 m/s^2 in the same moves. MuJoCo steps ~ 9x fewer times.
"""
from __future__ import annotations

import copy
from contextlib import nullcontext
from types import SimpleNamespace

import mujoco
import numpy as np
from mujoco import rollout

from imurig.kernel.progress import progress
from imurig.rigs.mujoco_clock import untimed
from imurig.rigs.mujoco_rig import rollout_servo
from imurig.rigs.tilt_kinematics import MOUNTS, rot_y, rot_z, rotate_to_body
from imurig.rigs.truth_pieces import TruthPieces

#: truth signals of the rig, name -> (sensor name in the MJCF, component)
SIGNALS = {"theta_true": ("theta_true", 0), "phi_true": ("phi_true", 0),
           **{f"{s}_{a}": (s, j) for s in ("f_C", "w_C", "B_C") for j, a in enumerate("xyz")}}
#: bound on the sensor data of one batched rollout call (bytes)
MAX_BATCH_BYTES = 64 * 2**20
#: samples stepped at the full rate at the start of each move and after a slew's end (the servo's transients: its
#: slow pole kp / kv = 20 /s decays in ~ 50 ms)
FINE_HEAD = 300
#: samples stepped at the full rate before a slew's end
FINE_TAIL = 5


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


def _rest_state(model, qpos, ctrl, d=None) -> np.ndarray:
    """MuJoCo's full physics state of the table at rest at ``qpos`` with command ``ctrl`` (``d``: an MjData
    of ``model`` to reuse; reset first, so the state is that of a new one)."""
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    if d is None:
        d = mujoco.MjData(model)
    else:
        mujoco.mj_resetData(model, d)
    d.qpos[:] = qpos
    d.ctrl[:] = ctrl
    mujoco.mj_forward(model, d)
    s = np.empty(mujoco.mj_stateSize(model, spec))
    mujoco.mj_getState(model, d, s, spec)
    return s


def stitched_truth(models, mounts, R_WB, ctrl, windows, sl, g, earth_W, B_W, move_substeps: int = 1) -> dict:
    """Truth signals (name -> (nbatch * nstep,)): closed form in the windows, MuJoCo for the moves.

    ``ctrl`` (nbatch, nstep, 2) rad: each mounting's servo commands; ``windows``: (start, stop)
    sample indices of the acquisition windows (the command is held in each); ``mounts``: the
    mounting of each batch row; ``R_WB``: the base attitude; ``move_substeps``: samples per MuJoCo
    step in the moves (module doc). The whole record of :func:`stitched_pieces`.
    """
    pieces = stitched_pieces(models, mounts, R_WB, ctrl, windows, sl, g, earth_W, B_W, move_substeps)
    return pieces.rows(0, pieces.n)


def rest_attitude(mount: str, R_WB: np.ndarray, theta: float, phi: float) -> np.ndarray:
    """R_CW (3, 3) of the table at rest at the joint angles (theta, phi) rad, base attitude R_WB,
    mounting ``mount``: R_CW = R_MC^T Rz(phi)^T Ry(theta)^T R_WB^T (module doc)."""
    return MOUNTS[mount].T @ rot_z(phi).T @ rot_y(theta).T @ R_WB.T


def stitched_pieces(models, mounts, R_WB, ctrl, windows, sl, g, earth_W, B_W,
                    move_substeps: int = 1, defer=None) -> "TruthPieces":
    """The truth of :func:`stitched_truth` as :class:`TruthPieces` (constants in the windows, MuJoCo
    rows or knots in the moves): any rows on demand, in memory of the knots, not the record.

    ``defer``: MuJoCo later. The pieces are returned at once, their moves not yet stepped, and
    ``defer(job)`` is given the job that steps them (in record order, :data:`EPOCH_MOVES` moves at a time;
    :meth:`TruthPieces.rows` waits for the moves it reads). The same values either way."""
    nb, nstep, _ = ctrl.shape
    out = TruthPieces(nb * nstep, tuple(SIGNALS))
    up = np.array([0.0, 0.0, g])
    moves = []  # (model, commands, initial qpos, first sample of the record)
    for b in range(nb):
        prev_stop = 0
        for a, e in windows:
            theta, phi = ctrl[b, a]
            R_CW = rest_attitude(mounts[b], R_WB, theta, phi)
            vals = {}
            for s, v in (("f_C", up), ("w_C", earth_W), ("B_C", B_W)):
                for j, x in enumerate(R_CW @ v):
                    vals[f"{s}_{'xyz'[j]}"] = x
            vals["theta_true"], vals["phi_true"] = theta, phi
            out.hold(b * nstep + a, b * nstep + e, vals)
            if a > prev_stop:  # the table rests at the previous command when the move starts
                c, q0 = ctrl[b, prev_stop:a], ctrl[b, prev_stop - 1] if prev_stop else ctrl[b, 0]
                if defer is not None:   # copies: the whole command array need not outlive the caller
                    c, q0 = c.copy(), q0.copy()
                moves.append((models[b], c, q0, b * nstep + prev_stop))
                out.expect(b * nstep + prev_stop, b * nstep + a)
            prev_stop = e
    out.done()

    def fill(start, sd, knots, length):
        _fill_interpolated(out, slice(start, start + length), sd, knots, sl, earth_W)

    def job():
        try:
            rollout_moves(moves, fill, int(move_substeps), desc="tilt table moves (MuJoCo)",
                          epoch=EPOCH_MOVES if defer is not None else None,
                          reached=lambda tag: out.filled(out.n if tag is None else tag))
        except BaseException as e:
            out.fail(e)
            raise

    if defer is None:
        job()
    else:
        defer(job)
    return out


#: moves stepped together when MuJoCo runs beside the stream (``defer``): in record order, so the first
#: pieces of the record are ready after the first few batches
EPOCH_MOVES = 24


def _coarse_models(models, k: int) -> list:
    """The models with the time step k dt (the same objects for k = 1)."""
    if k == 1:
        return list(models)
    out = []
    for m in models:
        c = copy.copy(m)
        c.opt.timestep = m.opt.timestep * k
        out.append(c)
    return out


def _fill_interpolated(out, dst: slice, sd: np.ndarray, knots: np.ndarray, sl: dict,
                       earth_W: np.ndarray) -> None:
    """Record in ``out`` (:class:`TruthPieces`) the move of L samples at ``dst`` from MuJoCo rows ``sd`` at
    the sample offsets ``knots``: linear in time between them, the last interval ending at the
    closed-form sample ``dst.stop`` (module doc); rows at every offset are kept as they are."""
    L = dst.stop - dst.start
    w = sd[:, sl["w_C"]] + rotate_to_body(sd[:, sl["q_WC"]], earth_W)
    cols = {name: (w[:, j] if sensor == "w_C" else sd[:, sl[sensor]][:, j]) for name, (sensor, j) in SIGNALS.items()}
    if knots.size == L:
        out.move(dst.start, dst.stop, None, {k: v.copy() for k, v in cols.items()})
        return
    xk = np.append(knots, L).astype(float)
    out.move(dst.start, dst.stop, xk, {k: np.append(v, out.value_at(dst.stop, k)) for k, v in cols.items()})


def _plan(length: int, slew_end: int, k: int) -> list[tuple[int, int, int]]:
    """(start, stop, step) pieces covering a move of ``length`` samples: every sample (step 1) for
    FINE_HEAD samples from the move's start (the command's step) and around the slew's end
    (``slew_end``, where the commanded acceleration jumps), every k-th elsewhere; a coarse piece
    followed by a fine one ends on its own grid."""
    if k == 1:
        return [(0, length, 1)]
    fine = [(0, min(FINE_HEAD, length))]
    if slew_end > 0:
        lo, hi = max(0, slew_end - FINE_TAIL), min(length, slew_end + FINE_HEAD)
        if lo <= fine[-1][1]:
            fine[-1] = (0, max(fine[-1][1], hi))
        else:
            fine.append((lo, hi))
    plan, pos = [], 0
    for lo, hi in fine:
        if lo > pos:
            q = pos + k * ((lo - pos) // k)
            if q > pos:
                plan.append((pos, q, k))
            lo = q
        plan.append((lo, hi, 1))
        pos = hi
    if pos < length:
        plan.append((pos, length, k))
    return plan


def _step_batch(batch, coarse: dict, datas, length: int, slew_end: int, k: int):
    """MuJoCo over the moves ``batch`` (equal ``length`` and slew end): sensor rows (nbatch, m, nsd) and their
    sample offsets (m,), stepped piece by piece as :func:`_plan` says (``coarse``: id(model) -> the model with
    the time step k dt)."""
    state = np.stack([_rest_state(m, q0, c[0], datas[0]) for m, c, q0, _ in batch])
    nd = datas[:min(2, len(batch))]
    untimed()   # steps without MuJoCo's profiling clock (imurig.rigs.mujoco_clock)
    rows, knots = [], []
    for lo, hi, step in _plan(length, slew_end, k):
        ms = [m if step == 1 else coarse[id(m)] for m, _, _, _ in batch]
        c = np.stack([c[lo:hi:step] for _, c, _, _ in batch])
        st, sd = rollout.rollout(ms, nd, state, c)
        state = np.ascontiguousarray(st[:, -1])
        rows.append(sd)
        knots.append(lo + step * np.arange(c.shape[1]))
    return np.concatenate(rows, axis=1), np.concatenate(knots)


def _slew_end(c: np.ndarray) -> int:
    """The first sample of the constant tail of a move's command c (L, 2) (0 if it never changes)."""
    moving = np.flatnonzero(np.any(c[1:] != c[:-1], axis=1))
    return int(moving[-1]) + 1 if moving.size else 0


def rollout_moves(moves, sink, k: int = 1, desc: str = "MuJoCo moves", epoch: int | None = None,
                  reached=None) -> None:
    """MuJoCo over the moves, batched by length (one ``mujoco.rollout`` call per batch, memory bounded by
    :data:`MAX_BATCH_BYTES`); after the first FINE_HEAD samples, every k-th sample stepped (module doc).

    ``moves``: (model, ctrl (L, nu) rad, qpos0 (nq,) rad, tag): the servo starts at rest at ``qpos0`` and
    follows ``ctrl``; sensor row i is evaluated at the move's sample i under ctrl[i] (as in
    :func:`imurig.rigs.mujoco_rig.rollout_servo`). Each move's rows go to ``sink(tag, sd (m, nsensordata),
    knots (m,) sample offsets, L)`` (m = L for k = 1). Each move is stepped on its own (its row of a batch),
    so the batches do not change its rows. ``epoch``: the moves in order of their tags, that many at a
    time (batched within them), ``reached(tag)`` called after each with the next one's first tag (None
    after the last); else all batched together."""
    if not moves:
        if reached is not None:
            reached(None)
        return
    nsd = moves[0][0].nsensordata
    coarse = {}
    for m, _, _, _ in moves:
        if id(m) not in coarse:
            coarse[id(m)] = _coarse_models([m], k)[0]
    datas = [mujoco.MjData(moves[0][0]) for _ in range(2)]
    if epoch is None:
        epochs = [list(moves)]
    else:
        ordered = sorted(moves, key=lambda mv: mv[3])
        epochs = [ordered[i:i + epoch] for i in range(0, len(ordered), epoch)]
    # in epochs MuJoCo runs beside the stream, in the background: no bar of its own
    bar_cm = progress(total=sum(len(m[1]) for m in moves), desc=desc, unit="step") if epoch is None else \
        nullcontext(SimpleNamespace(update=lambda n: None))
    with bar_cm as bar:
        for e, group_moves in enumerate(epochs):
            by_len: dict[tuple, list] = {}
            for mv in group_moves:  # batched by length and slew end (the same pieces)
                c = mv[1]
                by_len.setdefault((len(c), _slew_end(c) if k > 1 else 0), []).append(mv)
            for (length, slew_end), group in by_len.items():
                per = max(1, MAX_BATCH_BYTES // (length * nsd * 8))
                for i in range(0, len(group), per):
                    batch = group[i:i + per]
                    sd, knots = _step_batch(batch, coarse, datas, length, slew_end, k)
                    for j, mv in enumerate(batch):
                        sink(mv[3], sd[j], knots, length)
                    bar.update(length * len(batch))
            if reached is not None:
                reached(epochs[e + 1][0][3] if e + 1 < len(epochs) else None)
