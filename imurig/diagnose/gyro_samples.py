"""The table-axis gyro's samples as the index-pulse timer test reads them
(:func:`imurig.diagnose.pulse_angle.chain_from`), in memory."""
from __future__ import annotations

import numpy as np


class GyroSamples:
    """What :func:`chain_from` reads of the gyro's samples u at times t (in memory; a streamed record's
    reader, :class:`imurig.diagnose.turn_record.StreamedTurn`, gives the same values from a file):
    ``dt`` = median(diff(t)); :meth:`window` u[i0:i1] with (i0, i1) = searchsorted(t, (a, b));
    :meth:`integrals` G1, G2 (module doc, trapezoids) at times ``tp`` by np.interp; :meth:`sums`
    cs[i + h] - cs[i - h], cs the running sum of u from 0, i = clip(searchsorted(t, tp), h, n - h)."""

    def __init__(self, t_s: np.ndarray, u_V: np.ndarray):
        self.t, self.u = np.asarray(t_s, float), np.asarray(u_V, float)
        self.dt = float(np.median(np.diff(self.t)))

    def window(self, a: float, b: float) -> np.ndarray:
        i0, i1 = np.searchsorted(self.t, [a, b])
        return self.u[i0:i1]

    def integrals(self, tp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t, u = self.t, self.u
        dtv = np.diff(t)
        G1 = np.concatenate([[0.0], np.cumsum(0.5 * (u[1:] + u[:-1]) * dtv)])
        G2 = np.concatenate([[0.0], np.cumsum(0.5 * (u[1:] ** 2 + u[:-1] ** 2) * dtv)])
        return np.interp(tp, t, G1), np.interp(tp, t, G2)

    def sums(self, tp: np.ndarray, h: int) -> np.ndarray:
        idx = np.clip(np.searchsorted(self.t, tp), h, self.t.size - h)
        cs = np.concatenate([[0.0], np.cumsum(self.u)])
        return cs[idx + h] - cs[idx - h]
