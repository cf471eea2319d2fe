"""A hand-read digital voltmeter with autoscale (the SIMONA experiment, seed section 4.4.2).

Reading of a voltage V (one reading per setting, averaged over the integration time):

    range  = the first range whose limit exceeds |V|          (autoscale)
    V_read = q_r * round(g_r * V_avg / q_r) + n,  n ~ N(0, noise_r^2)      [V]

q_r: display resolution of the range, g_r: the range's gain (calibration) factor. The
defaults were chosen to match appendix B: readings below 60 mV show 10 uV steps, above
that 100 uV steps, and the upper range reads about 0.6 % low -- the "change of the
measurement range for the last nine measurements" the seed reports.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np


@dataclass
class AutoscaleVoltmeter:
    limits_V: tuple = (0.06, 0.6, 6.0)
    resolution_V: tuple = (1e-5, 1e-4, 1e-3)
    gain: tuple = (1.0, 0.994, 0.994)
    noise_V: tuple = (3e-6, 3e-5, 3e-4)
    integration_s: float = 0.2

    def read(self, v_avg: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Readings (V) and the range index used, for averaged input voltages ``v_avg``."""
        v = np.asarray(v_avg, float)
        r = np.searchsorted(np.asarray(self.limits_V), np.abs(v), side="right")
        r = np.minimum(r, len(self.limits_V) - 1)
        q = np.asarray(self.resolution_V)[r]
        g = np.asarray(self.gain)[r]
        noisy = g * v + np.asarray(self.noise_V)[r] * rng.standard_normal(v.shape)
        return np.round(noisy / q) * q, r

    def settings(self) -> dict:
        return asdict(self)
