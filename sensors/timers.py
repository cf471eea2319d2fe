"""Round timers of the turn table (seed section 4.4.3).

The table's optical sensor gives a pulse once per round. Its rising-edge times are
measured three ways:
- by the ADC: the pulse line is one scanned channel, so an edge is seen at the first
  1 kHz sample after it (resolution 1 ms) -- see :func:`imurig.calibration.gyro.pulse_edges`;
- by the GPS receiver's mark input: :class:`EventTimer` with the receiver's time-tag
  resolution and its interrupt/logging jitter;
- by a dedicated counter (HP 6700): :class:`EventTimer` with 1 us resolution.

Measurement equation of an event timer, per event k:

    t_k,meas = q * round((t_k + d + e_k) / q),   e_k ~ N(0, jitter^2)      [s]

with q the resolution, d a constant latency (irrelevant to round times), e the jitter.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np


@dataclass
class EventTimer:
    name: str
    resolution_s: float
    jitter_s: float = 0.0
    latency_s: float = 0.0

    def measure(self, true_times_s: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        t = np.asarray(true_times_s, float) + self.latency_s
        if self.jitter_s > 0:
            t = t + self.jitter_s * rng.standard_normal(t.shape)
        return np.round(t / self.resolution_s) * self.resolution_s

    def settings(self) -> dict:
        return asdict(self)


def gps_mark_timer() -> EventTimer:
    """NovAtel Euro4 mark input: 1 us time tags, ~0.1 ms latency jitter of the logging path."""
    return EventTimer("gps_mark", resolution_s=1e-6, jitter_s=1e-4, latency_s=2e-4)


def hp6700_counter() -> EventTimer:
    """Dedicated HP 6700 measurement system: 1 us resolution."""
    return EventTimer("hp6700", resolution_s=1e-6, jitter_s=0.0)
