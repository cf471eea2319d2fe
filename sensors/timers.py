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

with q the resolution, d a constant latency (irrelevant to round times), e the jitter: the
effect ``timer_quantisation`` of :mod:`imurig.sensors.effects`, which also states its variance
(q^2/12 + jitter^2 per tag) and its truth map.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from imurig.sensors.effects.timer_quantisation import TimerQuantisation


@dataclass
class EventTimer:
    name: str
    resolution_s: float
    jitter_s: float = 0.0
    latency_s: float = 0.0

    def effect(self) -> TimerQuantisation:
        """The timer's quantisation and jitter as an effect object."""
        return TimerQuantisation(resolution_s=self.resolution_s, jitter_s=self.jitter_s, latency_s=self.latency_s)

    def measure(self, true_times_s: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Measured time tags (s) of the true event times (s)."""
        return self.effect().inject(true_times_s, None, rng)

    def settings(self) -> dict:
        return asdict(self)


def gps_mark_timer() -> EventTimer:
    """NovAtel Euro4 mark input: 1 us time tags, ~0.1 ms latency jitter of the logging path."""
    return EventTimer("gps_mark", resolution_s=1e-6, jitter_s=1e-4, latency_s=2e-4)


def hp6700_counter() -> EventTimer:
    """Dedicated HP 6700 measurement system: 1 us resolution."""
    return EventTimer("hp6700", resolution_s=1e-6, jitter_s=0.0)
