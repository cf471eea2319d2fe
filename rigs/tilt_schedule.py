"""The tilt table's schedule in samples: the commanded angles of a run (slews on a cosine profile, then
settling and acquisition at rest) and the position each sample belongs to."""
from __future__ import annotations

import math

import numpy as np

from imurig.kernel.units import DEG


class CommandSchedule:
    """The commanded (theta, phi) of one run as its slews and holds, and its acquisition windows.

    Between positions the table slews on a cosine profile whose peak rate is ``slew_rate_deg_s``, then
    settles, then acquires for ``dwell_s``. :meth:`rows` gives any range of samples, the values the whole
    array (:func:`command_profile`) holds there, computed for that range only (a run's moves read a
    tenth of its samples)."""

    def __init__(self, protocol, set_theta, set_phi, dt: float):
        windows, pieces = [], []   # pieces: (start, length, p0, p1) of a slew from p0 to p1, p0 None for a hold
        n_settle = int(round(protocol.settle_s / dt))
        n_dwell = int(round(protocol.dwell_s / dt))
        rate = protocol.slew_rate_deg_s * DEG
        targets = np.stack([set_theta, set_phi], 1)
        prev = targets[0]
        n = 0
        for k, target in enumerate(targets):
            delta = float(np.max(np.abs(target - prev)))
            if k > 0 and delta > 0:
                n_slew = max(int(round(0.5 / dt)), int(math.ceil(delta / rate * math.pi / 2 / dt)))
                pieces.append((n, n_slew, prev, target))
                n += n_slew
            hold = n_settle + n_dwell + (n_settle if k == 0 else 0)
            pieces.append((n, hold, None, target))
            windows.append((n + hold - n_dwell, n + hold))
            n += hold
            prev = target
        self.n, self.windows, self._pieces = n, windows, pieces
        self._starts = np.array([p[0] for p in pieces], dtype=np.int64)

    def rows(self, lo: int, hi: int) -> np.ndarray:
        """The commands (hi - lo, 2) rad of samples [lo, hi): a slew of N samples from p0 to p1 at its
        sample j (1..N) is p0 + (1 - cos(pi j / N)) / 2 (p1 - p0), a hold its target."""
        out = np.empty((hi - lo, 2))
        first = max(int(np.searchsorted(self._starts, lo, side="right")) - 1, 0)
        for a, length, p0, p1 in self._pieces[first:]:
            if a >= hi:
                break
            s, e = max(a, lo), min(a + length, hi)
            if s >= e:
                continue
            if p0 is None:
                out[s - lo:e - lo] = p1
            else:
                f = (1 - np.cos(np.pi * np.arange(s - a + 1, e - a + 1) / length)) / 2
                seg = out[s - lo:e - lo]
                np.multiply(f[:, None], p1 - p0, out=seg)
                seg += p0
        return out


def command_profile(protocol, set_theta, set_phi, dt: float):
    """Commanded (theta, phi) per sample and acquisition windows for one run (:class:`CommandSchedule`).

    Returns cmd (nstep, 2) rad and the list of (start_idx, stop_idx).
    """
    schedule = CommandSchedule(protocol, set_theta, set_phi, dt)
    return schedule.rows(0, schedule.n), schedule.windows


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
