"""The tilt table's schedule in samples: the commanded angles of a run (slews on a cosine profile, then
settling and acquisition at rest) and the position each sample belongs to."""
from __future__ import annotations

import math

import numpy as np

from imurig.kernel.units import DEG


def command_profile(protocol, set_theta, set_phi, dt: float):
    """Commanded (theta, phi) per sample and acquisition windows for one run.

    Between positions the table slews on a cosine profile whose peak rate is
    ``slew_rate_deg_s``, then settles, then acquires for ``dwell_s``.
    Returns cmd (nstep, 2) rad, list of (start_idx, stop_idx), total steps.
    """
    windows, slews = [], []   # slews: (start, n_slew, prev, target)
    n_settle = int(round(protocol.settle_s / dt))
    n_dwell = int(round(protocol.dwell_s / dt))
    rate = protocol.slew_rate_deg_s * DEG
    targets = np.stack([set_theta, set_phi], 1)
    prev = targets[0]
    n, holds = 0, []
    for k, target in enumerate(targets):
        delta = float(np.max(np.abs(target - prev)))
        if k > 0 and delta > 0:
            n_slew = max(int(round(0.5 / dt)), int(math.ceil(delta / rate * math.pi / 2 / dt)))
            slews.append((n, n_slew, prev, target))
            n += n_slew
        hold = n_settle + n_dwell + (n_settle if k == 0 else 0)
        holds.append((n, hold, target))
        windows.append((n + hold - n_dwell, n + hold))
        n += hold
        prev = target
    cmd = np.empty((n, 2))   # filled in place, piece by piece (no list of pieces to concatenate)
    for a, n_slew, p0, p1 in slews:
        s = (1 - np.cos(np.pi * np.arange(1, n_slew + 1) / n_slew)) / 2
        np.multiply(s[:, None], p1 - p0, out=cmd[a:a + n_slew])
        cmd[a:a + n_slew] += p0
    for a, hold, target in holds:
        cmd[a:a + hold] = target
    return cmd, windows


def position_index(nstep: int, windows, steps: np.ndarray | None = None) -> np.ndarray:
    """Index of the position each step (of ``steps``; default all ``nstep``) belongs to (a slew belongs to
    the position it goes to)."""
    if steps is None:   # all steps, in order: each position's index repeated over its steps (no search)
        return np.repeat(np.arange(len(windows)), position_counts(nstep, windows))
    ends = np.array([b for _, b in windows])
    return np.minimum(np.searchsorted(ends, steps, side="right"), len(windows) - 1)


def position_counts(nstep: int, windows) -> np.ndarray:
    """Steps per position over all ``nstep`` steps (:func:`position_index`: a position's steps run to its
    window's end; the last position also takes any steps after it)."""
    ends = np.minimum(np.array([b for _, b in windows]), nstep)
    counts = np.diff(ends, prepend=0)
    counts[-1] += nstep - ends[-1]
    return counts
