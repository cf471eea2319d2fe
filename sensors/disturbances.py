"""Lab disturbances of seed section 4.3.3, each a named, switchable, parameterised effect.

- :class:`PumpVibration`: the hydraulic pump in the basement shakes the building during
  working hours; specific force added at the IMU, varying in time and direction.
- :class:`PeopleTransients`: doors and chairs: damped building-mode oscillations at
  random times, more often during working hours.
- :class:`LooseCable`: a faulty connector spikes one analog channel (volts).
- :class:`SlipRingNoise`: the turn table's slip rings (seed Fig. 4.16), an effect of
  :mod:`imurig.sensors.effects` (``slip_ring_noise``), re-exported here for the lab's set-up.

Each takes local clock times (hours of day, (n,)) so working hours are respected.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from scipy import signal

from imurig.sensors.effects.slip_rings import SlipRingNoise
from imurig.sensors.noise import band_noise

__all__ = ["LooseCable", "PeopleTransients", "PumpVibration", "SlipRingNoise", "settings", "working_mask"]


def working_mask(hour_of_day: np.ndarray, start_h: float, stop_h: float) -> np.ndarray:
    return (hour_of_day >= start_h) & (hour_of_day < stop_h)


@dataclass
class PumpVibration:
    """Building vibration from the hydraulic pump (m/s^2 at the IMU), on in working hours.

    f_vib(t) = sum_h A_h(t) d_h(t) sin(2 pi h f0 t + phi_h) + broadband(5..40 Hz)
    with slowly varying amplitudes A_h and directions d_h (unit vectors), so the
    vibration "varies in time and directions" and differs between the three axes.
    """

    enabled: bool = True
    fundamental_hz: float = 24.7
    harmonics: tuple = (1.0, 0.5)
    rms_m_s2: float = 0.03
    broadband_rms_m_s2: float = 0.01
    modulation_hz: float = 0.05
    work_start_h: float = 7.5
    work_stop_h: float = 17.5

    def specific_force(self, time_s, hour_of_day, fs, rng) -> np.ndarray:
        n = time_s.size
        out = np.zeros((n, 3))
        on = working_mask(hour_of_day, self.work_start_h, self.work_stop_h)
        if not self.enabled or not on.any():
            return out
        weights = np.asarray(self.harmonics, float)
        amp_each = self.rms_m_s2 * np.sqrt(2) * weights / np.sqrt(np.sum(weights**2))
        for h, a in enumerate(amp_each, start=1):
            if h * self.fundamental_hz >= fs / 2:  # averaged out by a slow (averaging) logger
                continue
            env = 1 + 0.5 * band_noise(rng, (n,), fs, (0, self.modulation_hz), 1.0)
            direction = band_noise(rng, (n, 3), fs, (0, self.modulation_hz), 1.0) + rng.normal(size=3)
            direction /= np.linalg.norm(direction, axis=1, keepdims=True)
            phase = rng.uniform(0, 2 * np.pi)
            out += (a * env * np.sin(2 * np.pi * h * self.fundamental_hz * time_s + phase))[:, None] * direction
        if self.broadband_rms_m_s2 > 0 and fs / 2 > 40.0:
            out += band_noise(rng, (n, 3), fs, (5.0, 40.0), self.broadband_rms_m_s2)
        return out * on[:, None]


@dataclass
class PeopleTransients:
    """Doors closing, chairs moved: Poisson events of damped oscillation (m/s^2 at the IMU).

    Each event: a d exp(-t/tau) sin(2 pi f t), random unit direction d, amplitude a ~ |N(0, peak)|.
    """

    enabled: bool = True
    rate_per_hour_working: float = 20.0
    rate_per_hour_evening: float = 1.0
    peak_m_s2: float = 0.05
    frequency_hz: float = 12.0
    decay_s: float = 0.3
    work_start_h: float = 7.5
    work_stop_h: float = 17.5

    def specific_force(self, time_s, hour_of_day, fs, rng) -> np.ndarray:
        n = time_s.size
        out = np.zeros((n, 3))
        if not self.enabled or self.frequency_hz >= fs / 2:  # averaged out by a slow logger
            return out
        on = working_mask(hour_of_day, self.work_start_h, self.work_stop_h)
        rate = np.where(on, self.rate_per_hour_working, self.rate_per_hour_evening) / 3600.0 / fs
        events = np.flatnonzero(rng.random(n) < rate)
        if events.size == 0:
            return out
        impulses = np.zeros((n, 3))
        d = rng.normal(size=(events.size, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        impulses[events] = d * np.abs(rng.normal(0, self.peak_m_s2, size=(events.size, 1)))
        # damped resonator as an IIR filter: impulse response exp(-t/tau) sin(2 pi f t)
        r = np.exp(-1 / (self.decay_s * fs))
        w = 2 * np.pi * self.frequency_hz / fs
        b = [0.0, r * np.sin(w)]
        a = [1.0, -2 * r * np.cos(w), r * r]
        return signal.lfilter(b, a, impulses, axis=0)


@dataclass
class LooseCable:
    """A faulty connector: rectangular voltage spikes on one analog channel (V).

    Spikes start as a Poisson process of ``rate_hz``, last U(min, max) seconds, and have
    amplitude N(0, amplitude_V).
    """

    enabled: bool = False
    channel: str = "acc_y"
    rate_hz: float = 0.5
    amplitude_V: float = 0.3
    min_duration_s: float = 0.005
    max_duration_s: float = 0.05

    def voltage(self, n: int, fs: float, rng) -> np.ndarray:
        out = np.zeros(n)
        if not self.enabled:
            return out
        starts = np.flatnonzero(rng.random(n) < self.rate_hz / fs)
        if starts.size == 0:
            return out
        lengths = np.maximum(1, (rng.uniform(self.min_duration_s, self.max_duration_s, starts.size) * fs)
                             .astype(int))
        amps = rng.normal(0, self.amplitude_V, starts.size)
        delta = np.zeros(n + 1)
        np.add.at(delta, starts, amps)
        np.add.at(delta, np.minimum(starts + lengths, n), -amps)
        return np.cumsum(delta)[:n]


def settings(obj) -> dict:
    return asdict(obj)
