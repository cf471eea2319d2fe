"""A simulated turn-table record whose samples are made on demand (:meth:`imurig.rigs.turn_table.TurnTable.run`).

The mountings follow one another with the remount time as a gap: sample i of mounting b is at
t = t0_b + i dt, t0_{b+1} = (t0_b + (n_b - 1) dt) + dt + remount_s. Channel ``rate_dial``: the dial's
setting (rad/s) from the start of each step's ramp to the next. Truth signals over any row range
(:meth:`TurnRun.truth_rows`): f_C_x/y/z, w_C_x/y/z and spin_angle from the truth's states
(:class:`imurig.rigs.turn_truth.TurnStates`, or whole arrays when MuJoCo stepped every sample), and the
index sensor's line pulse = pulse_high_V where theta mod 2 pi < pulse_width, else 0 V. Every row is a
pointwise function of the states, so any split of the rows gives the whole record's values, bit for bit.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from imurig.kernel.recording import Recording

TRUTH_NAMES = ("spin_angle", "pulse", "f_C_x", "f_C_y", "f_C_z", "w_C_x", "w_C_y", "w_C_z")


@dataclass
class TurnRun:
    """The rows of a turn-table record (module doc) and its small parts: segments, events, meta, truth."""

    off: np.ndarray                 # mounting b's rows: off[b]:off[b + 1]
    t0: list                        # each mounting's first sample time (s)
    dt: float
    dial: list                      # each mounting's [(first row, dial rad/s)], rows within the mounting
    source: object                  # TurnStates, or {name: whole array} (f_C_*, w_C_*, spin_angle)
    pulse_width_rad: float
    pulse_high_V: float
    segments: dict
    segment_units: dict
    meta: dict
    truth: dict
    events: dict
    units: dict = field(default_factory=lambda: {"rate_dial": "rad/s"})

    @property
    def n(self) -> int:
        return int(self.off[-1])

    @property
    def truth_units(self) -> dict:
        return {k: {"f": "m/s^2", "w": "rad/s", "p": "V"}.get(k[0], "rad") for k in TRUTH_NAMES}

    def _mounts(self, a: int, b: int):
        """(mounting, its first row, lo, hi) for the mountings that hold rows of [a, b)."""
        for m in range(len(self.t0)):
            lo, hi = max(a, int(self.off[m])), min(b, int(self.off[m + 1]))
            if lo < hi:
                yield m, int(self.off[m]), lo, hi

    def time_rows(self, a: int, b: int) -> np.ndarray:
        """time_s over samples [a, b)."""
        out = np.empty(b - a)
        for m, first, lo, hi in self._mounts(a, b):
            seg = out[lo - a:hi - a]   # t0 + k dt, in place
            np.multiply(np.arange(lo - first, hi - first), self.dt, out=seg)
            seg += self.t0[m]
        return out

    def channel_rows(self, a: int, b: int) -> dict:
        """The dial's setting over samples [a, b)."""
        out = np.zeros(b - a)
        for m, first, lo, hi in self._mounts(a, b):
            starts = [s for s, _ in self.dial[m]] + [int(self.off[m + 1] - first)]
            for (s, v), z in zip(self.dial[m], starts[1:]):
                s_, z_ = max(lo, first + s), min(hi, first + z)
                if s_ < z_:
                    out[s_ - a:z_ - a] = v
        return {"rate_dial": out}

    def truth_rows(self, a: int, b: int) -> dict:
        """The truth signals over samples [a, b), in the order of :data:`TRUTH_NAMES`."""
        src = self.source
        rows = src.rows(a, b) if hasattr(src, "rows") else {k: v[a:b] for k, v in src.items()}
        spin = rows["spin_angle"]
        pulse = np.where(np.mod(spin, 2 * np.pi) < self.pulse_width_rad, self.pulse_high_V, 0.0)
        return {"spin_angle": spin, "pulse": pulse, **{k: rows[k] for k in TRUTH_NAMES[2:]}}

    def recording(self) -> Recording:
        """The whole record as a Recording (set-point, truth, events; no sensors)."""
        return Recording(time_s=self.time_rows(0, self.n), channels=self.channel_rows(0, self.n),
                         units=dict(self.units), segments=self.segments, segment_units=self.segment_units,
                         meta=self.meta, truth=self.truth, truth_signals=self.truth_rows(0, self.n),
                         truth_units=self.truth_units, events=self.events)
