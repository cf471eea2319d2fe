"""Segments as set-point plateaus.

A sample belongs to a plateau when every set-point stays within ``tol_j`` of its previous sample
(``tol_j`` = 1e-5 of the set-point's range plus its float noise: 8 float32 epsilons of its largest
magnitude), so float noise in a logged set-point does not break a plateau while a ramp does. Runs of
such samples shorter than the minimum plateau length (``max(min_plateau_s, 10 samples)``) and runs
whose set-point spread exceeds 1e-3 of the range (a very slow ramp) are moves (no segment).
Neighbouring plateaus with the same set-points within tolerance and no time gap are merged.
"""
from __future__ import annotations

import numpy as np

from imurig.kernel.errors import RecordingError
from imurig.kernel.recording import Recording

MIN_PLATEAU_S = 1.0
MIN_PLATEAU_SAMPLES = 10


def plateau_segments(rec: Recording, setpoints: list[str], min_plateau_s: float = MIN_PLATEAU_S):
    """(segments, units, evidence): one segment per set-point plateau; see the module doc."""
    t = rec.time_s
    sp = np.stack([rec.channels[s] for s in setpoints], axis=1)
    rng = np.ptp(sp, axis=0)
    tol = 1e-5 * rng + 8 * np.finfo(np.float32).eps * np.max(np.abs(sp), axis=0) + 1e-15
    dt = np.diff(t)
    gap = dt > 1.5 * float(np.median(dt))
    steady = np.all(np.abs(np.diff(sp, axis=0)) <= tol, axis=1) & ~gap
    brk = np.flatnonzero(~steady) + 1
    starts = np.concatenate(([0], brk))
    stops = np.concatenate((brk, [t.size]))
    min_n = max(MIN_PLATEAU_SAMPLES, int(np.ceil(min_plateau_s * rec.sample_rate_hz)))
    long_ = (stops - starts) >= min_n
    starts, stops = starts[long_], stops[long_]
    starts, stops, n_slow = _hold_within(sp, starts, stops, 1e-3 * rng + tol, min_n)
    starts, stops = _merge(sp, t, starts, stops, tol, gap)
    if starts.size > max(1, t.size // min_n):
        raise RecordingError(f"{starts.size} plateaus in {t.size} samples: the set-points never hold still")
    step = float(np.median(dt))
    seg = {"start_s": t[starts], "stop_s": t[stops - 1] + step}
    units = {"start_s": "s", "stop_s": "s"}
    for j, s in enumerate(setpoints):
        seg[s] = np.array([np.median(sp[a:b, j]) for a, b in zip(starts, stops)])
        units[s] = rec.units[s]
    moving = t.size - int(np.sum(stops - starts))
    evidence = (f"{starts.size} plateau(s) of {setpoints} held within {np.array2string(tol, precision=3)} "
                f"(SI) per sample for at least {min_n} samples; {moving} samples in ramps or moves are no "
                f"segment" + (f"; {n_slow} slow drift(s) cut to their plateau or rejected" if n_slow else ""))
    return seg, units, evidence


def _hold_within(sp, starts, stops, band, min_n: int):
    """The runs whose set-points spread within ``band``. A run that drifts further (slow ramps whose
    per-sample step is within the tolerance, run into their plateaus) is cut: its longest stretch
    within ``band`` / 2 of its median is a plateau when >= ``min_n`` samples long, and the parts
    before and after it are cut the same way. Returns (starts, stops, how many runs drifted)."""
    keep, n_slow = [], 0
    work = [(a, b, True) for a, b in zip(starts, stops)]
    while work:
        a, b, top = work.pop()
        if b - a < min_n:
            continue
        if np.all(np.ptp(sp[a:b], axis=0) <= band):
            keep.append((a, b))
            continue
        n_slow += top
        near = np.all(np.abs(sp[a:b] - np.median(sp[a:b], axis=0)) <= 0.5 * band, axis=1)
        edges = np.flatnonzero(np.diff(np.concatenate(([0], near.astype(np.int8), [0]))))
        if edges.size == 0:
            continue
        lens = edges[1::2] - edges[::2]
        k = int(np.argmax(lens))
        i0, i1 = a + edges[2 * k], a + edges[2 * k + 1]
        if i1 - i0 >= min_n:
            keep.append((i0, i1))
        work += [(a, i0, False), (i1, b, False)]
    keep.sort()
    return (np.array([k[0] for k in keep], int), np.array([k[1] for k in keep], int), n_slow)


def _merge(sp, t, starts, stops, tol, gap):
    """Join neighbouring plateaus with the same set-points (a blip between them) unless a gap parts them."""
    if starts.size < 2:
        return starts, stops
    keep_s, keep_e = [starts[0]], [stops[0]]
    for a, b in zip(starts[1:], stops[1:]):
        same = np.all(np.abs(np.median(sp[a:b], 0) - np.median(sp[keep_s[-1]:keep_e[-1]], 0)) <= 10 * tol)
        short = (a - keep_e[-1]) <= 2 and not np.any(gap[keep_e[-1] - 1:a])
        if same and short:
            keep_e[-1] = b
        else:
            keep_s.append(a)
            keep_e.append(b)
    return np.array(keep_s), np.array(keep_e)
