"""Doors closing, chairs moved: damped building-mode oscillations at random times (seed 4.3.3).

    f(t) = sum_events a_e d_e h(t - t_e),  h(t) = exp(-t / tau) sin(2 pi f t)      [m/s^2, (n, 3)]

Events: a Bernoulli draw per sample with probability rate / f_s (the working-hours rate by day,
the evening rate otherwise), unit directions d_e uniform on the sphere, a_e ~ |N(0, peak)|. The
resonator runs as an IIR filter with impulse response h[n] = r^n sin(w n), r = exp(-1 / (tau f_s)),
w = 2 pi f / f_s. Left out when f >= f_s/2 (a slow, averaging logger). Stage "specific_force"
(stream "people"). Impulsive: the position medians reject most events, and the Gaussian bounds
leave them out.

Variance per axis (shot noise, Campbell; p = the mean event probability per sample,
E[a^2 d_j^2] = peak^2 / 3):

    per sample:          p peak^2 / 3 * sum_n h[n]^2,
                         sum_n r^(2n) sin^2(w n) = (1 / (1 - r^2) - Re 1 / (1 - r^2 e^(2iw))) / 2
    mean of N samples:   p peak^2 / 3 * H(1)^2 / N,  H(1) = r sin w / (1 - 2 r cos w + r^2)
                         (long-window limit)
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from scipy import signal

from imurig.sensors.effects.base import ChainContext, Effect, Param
from imurig.sensors.effects.building_vibration import working_mask


@dataclass
class PeopleTransients(Effect):
    """Doors and chairs: Poisson events of damped oscillation (m/s^2 at the IMU)."""

    enabled: bool = True
    rate_per_hour_working: float = 20.0
    rate_per_hour_evening: float = 1.0
    peak_m_s2: float = 0.05
    frequency_hz: float = 12.0
    decay_s: float = 0.3
    work_start_h: float = 7.5
    work_stop_h: float = 17.5

    name: ClassVar[str] = "people_transients"
    stage: ClassVar[str] = "specific_force"
    stream: ClassVar[str] = "people"
    impulsive: ClassVar[bool] = True
    physics: ClassVar[str] = "doors and chairs excite damped building oscillations at random times"
    seed_section: ClassVar[str] = "4.3.3"
    seed_says: ClassVar[str] = ("'even the closing of doors or traces of people moving chairs in the laboratory "
                                "appear in the plots'; the final runs were made between 6 pm and 10 pm")
    params: ClassVar[tuple] = (Param("rate_per_hour_working", "1/h"), Param("peak_m_s2", "m/s^2"),
                               Param("frequency_hz", "Hz"), Param("decay_s", "s"))

    def resonator(self, fs: float) -> tuple[float, float]:
        """(r, w): pole radius exp(-1 / (tau f_s)) and angle 2 pi f / f_s."""
        return float(np.exp(-1 / (self.decay_s * fs))), 2 * np.pi * self.frequency_hz / fs

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
        r, w = self.resonator(fs)
        b = [0.0, r * np.sin(w)]
        a = [1.0, -2 * r * np.cos(w), r * r]
        return signal.lfilter(b, a, impulses, axis=0)

    def inject(self, f: np.ndarray, ctx: ChainContext, rng: np.random.Generator) -> np.ndarray:
        if not self.enabled:
            return f
        return f + self.specific_force(ctx.time_s, ctx.hour_of_day, ctx.sample_rate_hz, rng)

    def event_probability(self, ctx: ChainContext) -> float:
        """p: the mean event probability per sample over the context's clock."""
        on = ctx.working_fraction(self.work_start_h, self.work_stop_h)
        rate_h = on * self.rate_per_hour_working + (1 - on) * self.rate_per_hour_evening
        return rate_h / 3600.0 / ctx.sample_rate_hz

    def noise_variance(self, ctx: ChainContext) -> float:
        """Per-axis variance (m/s^2)^2 of one sample, or of a long window mean (module doc)."""
        fs = ctx.sample_rate_hz
        if not self.enabled or self.frequency_hz >= fs / 2:
            return 0.0
        r, w = self.resonator(fs)
        scale = self.event_probability(ctx) * self.peak_m_s2**2 / 3
        if ctx.window_samples > 1:
            dc = r * np.sin(w) / (1 - 2 * r * np.cos(w) + r * r)
            return float(scale * dc**2 / ctx.window_samples)
        energy = 0.5 * (1 / (1 - r * r) - (1 / (1 - r * r * np.exp(2j * w))).real)
        return float(scale * energy)
