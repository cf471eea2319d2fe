"""Runs (mountings) from what the sensors see, and the check of the channel labels.

Tilt table: at rest a position (theta, phi) gives, for a perfect table, the specific force
f_P = g (-cos(phi) sin(theta), sin(phi) sin(theta), cos(theta)) on the platform, and in the IMU
case f_C = f_P R_MC with R_MC = I (``z_up``) or diag(1, -1, -1) (``z_down``), the bench's mountings
(:mod:`imurig.rigs.tilt_kinematics`, which the kernel may not import). Each plateau takes the
mounting whose f_C lies nearer the indicated u = V / s_nom; a run is a stretch of plateaus with one
mounting and no time gap.

Turn table: the gyro that answers the dial is on the table axis; its sign gives up or down
(``p_up`` ... ``r_down``, :mod:`imurig.rigs.turn_table`).

Label check (tilt table): across the plateaus the correlation of each accelerometer channel with
each component of f_C must peak on its own axis with a positive sign. |r_jj| < 0.5 with another
|r_jk| > 0.9 is a swap, r_jj < -0.9 a sign error (both refused); 0.5 <= r_jj < 0.9 is marginal
(a warning). The slope V_j / f_j is compared with the nominal sensitivity (a warning beyond x2).
"""
from __future__ import annotations

import numpy as np

from imurig.kernel.errors import RecordingError
from imurig.kernel.infer import ACC, ACC_KEY, GYRO, GYRO_KEY, note, warn
from imurig.kernel.recording import Recording
from imurig.kernel.site import Site
from imurig.kernel.units import G_STANDARD

TILT_MOUNTS = {"z_up": np.eye(3), "z_down": np.diag([1.0, -1.0, -1.0])}


def specific_force(theta, phi, mount: str, g: float) -> np.ndarray:
    """f_C (n, 3) m/s^2 at rest on a perfect tilt table (module doc)."""
    st, ct, sp, cp = np.sin(theta), np.cos(theta), np.sin(phi), np.cos(phi)
    f_P = g * np.stack([-cp * st, sp * st, ct], axis=1)
    return f_P @ TILT_MOUNTS[mount]


def _segment_means(rec: Recording, names) -> np.ndarray:
    sl = rec.segment_slices()
    return np.array([[np.median(rec.channels[c][s]) for c in names] for s in sl])


def _runs_from(labels: list[str], rec: Recording) -> tuple[np.ndarray, list[str]]:
    """Run index per segment: a new run when the mounting changes or a time gap parts two segments."""
    t = rec.time_s
    gaps = t[np.flatnonzero(np.diff(t) > 1.5 * float(np.median(np.diff(t)))) + 1]
    run, names = np.zeros(len(labels), int), [labels[0]]
    for i in range(1, len(labels)):
        parted = np.any((gaps > rec.segments["stop_s"][i - 1] - 1e-12) & (gaps <= rec.segments["start_s"][i]))
        if labels[i] != labels[i - 1] or parted:
            names.append(labels[i])
        run[i] = len(names) - 1
    return run, names


def _fill(labels: list) -> list:
    """Undecided labels (None) take the previous decided one (the next one at the start)."""
    known = [lb for lb in labels if lb]
    if not known:
        return labels
    out, last = [], known[0]
    for lb in labels:
        last = lb or last
        out.append(last)
    return out


def tilt_runs(rec: Recording, where: str) -> None:
    """Mounting of each plateau from the sign of gravity, then the label check."""
    if not all(c in rec.channels for c in ACC) or rec.n_segments == 0 or "theta" not in rec.segments:
        return
    g = Site.from_dict(rec.meta.get("site", {})).gravity_m_s2
    s = np.broadcast_to(np.asarray(rec.meta[ACC_KEY], float), (3,))
    u = _segment_means(rec, ACC) / s
    th, ph = rec.segments["theta"], rec.segments.get("phi", np.zeros(rec.n_segments))
    fit = {m: specific_force(th, ph, m, g) for m in TILT_MOUNTS}
    err = {m: np.linalg.norm(u - f, axis=1) for m, f in fit.items()}
    # where the mountings predict nearly the same force (y, z near 0) a plateau takes its neighbour's
    distinct = np.linalg.norm(fit["z_up"] - fit["z_down"], axis=1) > 0.2 * g
    labels = _fill([min(err, key=lambda m: err[m][i]) if distinct[i] else None for i in range(rec.n_segments)])
    if "run" not in rec.segments:
        run, names = _runs_from(labels, rec)
        rec.segments["run"] = run
        rec.segment_units["run"] = "1"
        rec.meta["runs"] = names
        rms = {m: float(np.sqrt(np.mean(err[m][[lb == m for lb in labels]] ** 2))) if m in labels else None
               for m in TILT_MOUNTS}
        note(rec, "runs", names, f"sign of gravity on the accelerometers at each plateau: {labels.count('z_up')} "
                                 f"z_up, {labels.count('z_down')} z_down; rms |u - f_C| per mounting {rms} m/s^2")
    f = np.stack([fit[lb][i] for i, lb in enumerate(labels)])
    check_labels(rec, _segment_means(rec, ACC), f, s, where)


def check_labels(rec: Recording, v: np.ndarray, f: np.ndarray, s: np.ndarray, where: str) -> None:
    """Swapped or sign-flipped accelerometer channels from the correlation of V_j with f_k (module doc)."""
    if v.shape[0] < 3:
        warn(rec, "MARGINAL: fewer than 3 plateaus; the accelerometer labels were not checked")
        return
    usable = np.std(f, axis=0) > 1e-3 * np.max(np.abs(f))
    r = np.full((3, 3), np.nan)
    for j in range(3):
        for k in np.flatnonzero(usable):
            if np.std(v[:, j]) > 0:
                r[j, k] = np.corrcoef(v[:, j], f[:, k])[0, 1]
    problems, marginal = [], []
    for j, c in enumerate(ACC):
        if not usable[j] or np.isnan(r[j, j]):
            continue
        others = [k for k in range(3) if k != j and abs(np.nan_to_num(r[j, k])) > 0.9]
        if r[j, j] < -0.9:
            problems.append(f"'{c}' falls where gravity on its axis rises (r = {r[j, j]:.2f}): a sign error; "
                            f"check the wiring/polarity of {c} or the mounting")
        elif abs(r[j, j]) < 0.5 and others:
            k = others[0]
            problems.append(f"'{c}' follows gravity on {'xyz'[k]} (r = {r[j, k]:.2f}), not on {'xyz'[j]} "
                            f"(r = {r[j, j]:.2f}): the headers '{c}' and '{ACC[k]}' look swapped")
        elif r[j, j] < 0.9:
            marginal.append(f"'{c}' correlates only {r[j, j]:.2f} with gravity on its axis")
        else:
            slope = np.polyfit(f[:, j], v[:, j], 1)[0]
            unit = _unit_factor(slope / s[j], G_STANDARD, "g", "m/s^2")
            if unit:
                problems.append(f"'{c}' reads {slope / s[j]:.4g} x the specific force its set-points give: {unit}")
            elif not 0.5 < slope / s[j] < 2.0:
                marginal.append(f"'{c}' gives {slope:.4g} V per m/s^2, nominal {s[j]:.4g}: check the sensitivity")
    note(rec, "label_check", {"correlation_V_vs_f": np.round(r, 4).tolist()},
         "correlation across plateaus of each accelerometer channel (rows x, y, z) with gravity's "
         "component on each axis (columns); expected near +1 on the diagonal")
    if problems:
        raise RecordingError(f"{where}: the accelerometer channels contradict the set-points and gravity: "
                             + "; ".join(problems))
    for m in marginal:
        warn(rec, "MARGINAL: " + m)


def _unit_factor(ratio: float, factor: float, big: str, small: str) -> str:
    """A hint when ``ratio`` (indicated / expected) is a unit conversion factor (within 3 %), else ""."""
    if abs(ratio * factor - 1) < 0.03:
        return (f"the values look like {big} in a channel read as {small} (or the nominal sensitivity is per "
                f"{small} where it should be per {big}): name the column's unit _{big.replace('/', '_')} or fix the "
                "sensitivity")
    if abs(ratio / factor - 1) < 0.03:
        return (f"the values look like {small} in a channel read as {big} (or the nominal sensitivity is per "
                f"{big} where it should be per {small}): fix the column's unit or the sensitivity")
    return ""


def turn_runs(rec: Recording, where: str = "recording") -> None:
    """Turn-table mounting per step: the gyro that answers the dial, and its sign."""
    if not all(c in rec.channels for c in GYRO) or "rate_dial" not in rec.segments or "run" in rec.segments:
        return
    s = np.broadcast_to(np.asarray(rec.meta[GYRO_KEY], float), (3,))
    u = _segment_means(rec, GYRO) / s
    rate = rec.segments["rate_dial"]
    moving = np.abs(rate) > 1e-3 * max(float(np.max(np.abs(rate))), 1e-12)
    if not np.any(moving):
        return
    labels, last = [], None
    for i in range(rec.n_segments):
        if moving[i]:
            j = int(np.argmax(np.abs(u[i])))
            last = f"{'pqr'[j]}_{'up' if u[i, j] * rate[i] > 0 else 'down'}"
        labels.append(last)
    labels = _fill(labels)
    run, names = _runs_from(labels, rec)
    rec.segments["run"] = run
    rec.segment_units["run"] = "1"
    rec.meta["runs"] = names
    ratio = [float(u[i, "pqr".index(labels[i][0])] * rate[i] / rate[i] ** 2) for i in np.flatnonzero(moving)]
    note(rec, "runs", names, f"the gyro answering the dial at each turning step (indicated/dial: median "
                             f"{np.median(np.abs(ratio)):.3f}, sign per mounting)")
    unit = _unit_factor(float(np.median(np.abs(ratio))), 180 / np.pi, "rad/s", "deg/s")
    if unit:
        raise RecordingError(f"{where}: the gyros read {np.median(np.abs(ratio)):.4g} x the dial rate: {unit}")
    if not 0.5 < np.median(np.abs(ratio)) < 2.0:
        warn(rec, f"MARGINAL: the gyros read {np.median(np.abs(ratio)):.3f} x the dial with the nominal sensitivity; "
                  "check the gyro sensitivity or the dial's unit")
