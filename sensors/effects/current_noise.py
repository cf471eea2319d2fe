"""Output current noise of the Q-Flex accelerometers (datasheet A.1; seed 4.3.3).

    V_i(t) = R_L,i (i_S,i(t) + n_i(t))                 [V]
    n_i    = sum over bands (lo, hi, rms) of Gaussian noise band-limited to [lo, hi]   [A]

The datasheet gives the noise as bands of rms current (0-10 Hz, 10-500 Hz, 500 Hz-10 kHz).
How a band appears in the sampled record (aliased to white when sampled directly, averaged out
above f_s/2 with averaged logging) is :func:`imurig.sensors.noise.sampled_bands`, the one place
that rule is written. Per logged sample the variance is sum rms_k^2 over the sampled bands; the
mean of a window of N samples keeps the bands reaching DC (:func:`window_mean_variance`); the
filter's velocity random walk is the two-sided PSD at DC of the bands reaching DC,
N_a^2 = sum rms_k^2 / (2 hi_k)  [A^2/Hz], divided by the scale factor K1 (A per m/s^2).

Injected by the triad (:meth:`imurig.sensors.accelerometer.QFlexTriad.noise_current` draws through
``current``); the bounds (:mod:`imurig.montecarlo.tilt_crlb`) and the filter priors
(:meth:`imurig.flights.filter_config.ImuNoise.from_sensors`) ask this object.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from imurig.sensors.effects.base import ChainContext, Effect, Param
from imurig.sensors.noise import add_band_noise, sampled_bands, window_mean_variance

QFLEX_BANDS = ((0.0, 10.0, 10e-9), (10.0, 500.0, 100e-9), (500.0, 10e3, 2e-6))


@dataclass
class CurrentNoise(Effect):
    """Gaussian current noise in bands (lo_Hz, hi_Hz, rms_A) on each accelerometer's output."""

    bands: tuple = QFLEX_BANDS
    load_resistor_ohm: np.ndarray = field(default_factory=lambda: np.full(3, 1.0))
    averaged: bool = False
    enabled: bool = True

    name: ClassVar[str] = "current_noise"
    stage: ClassVar[str] = "sensor"
    physics: ClassVar[str] = "the accelerometers' output current noise, in the datasheet's frequency bands"
    seed_section: ClassVar[str] = "A.1; 4.3.3"
    seed_says: ClassVar[str] = ("the Q-Flex datasheet gives the output noise as 10 nA rms in 0-10 Hz, 100 nA in "
                                "10-500 Hz and 2 uA in 500 Hz-10 kHz")
    params: ClassVar[tuple] = (Param("rms_0_10Hz_A", "A", datasheet=10e-9),
                               Param("rms_10_500Hz_A", "A", datasheet=100e-9),
                               Param("rms_500Hz_10kHz_A", "A", datasheet=2e-6))
    order: ClassVar[int] = 5

    def current(self, n: int, fs: float, rng: np.random.Generator) -> np.ndarray:
        """Current noise (n, 3) A as sampled at ``fs`` (bands folded by :func:`sampled_bands`)."""
        out = np.zeros((n, 3))
        if not self.enabled:
            return out
        for lo, hi, rms in sampled_bands(self.bands, fs, self.averaged):
            add_band_noise(out, rng, fs, (lo, hi), rms)  # in row pieces: the same values as band_noise
        return out

    def inject(self, v: np.ndarray, ctx: ChainContext, rng: np.random.Generator) -> np.ndarray:
        """V (n, 3) + R_L n(t)."""
        v = np.asarray(v, float)
        if not self.enabled:
            return v
        return v + self.current(v.shape[0], ctx.sample_rate_hz, rng) * np.asarray(self.load_resistor_ohm, float)

    def sample_variance_A2(self, fs: float) -> float:
        """Variance (A^2) of one logged sample of one axis: the sum of rms^2 over the sampled bands."""
        if not self.enabled:
            return 0.0
        return float(sum(rms**2 for _, _, rms in sampled_bands(self.bands, fs, self.averaged)))

    def window_variance_A2(self, fs: float, n_window: int) -> float:
        """Variance (A^2) of one axis' mean of ``n_window`` logged samples, long-window limit
        (:func:`imurig.sensors.noise.window_mean_variance`)."""
        return window_mean_variance(self.bands, fs, n_window, self.averaged) if self.enabled else 0.0

    def noise_variance(self, ctx: ChainContext) -> np.ndarray:
        """Per-axis variance (3,) V^2 of one logged sample (``ctx.window_samples`` 1) or of the
        mean of a window of ``ctx.window_samples`` samples (long-window limit)."""
        r = np.asarray(self.load_resistor_ohm, float)
        fs, m = ctx.sample_rate_hz, int(ctx.window_samples)
        var = self.sample_variance_A2(fs) if m <= 1 else self.window_variance_A2(fs, m)
        return var * r**2

    def random_walk_density_A(self, fs: float) -> float:
        """sqrt(two-sided PSD at DC) A/sqrt(Hz) of the sampled current noise: sum over the bands
        reaching DC of rms^2 / (2 hi)."""
        if not self.enabled:
            return 0.0
        return float(np.sqrt(sum(rms**2 / (2 * hi) for lo, hi, rms in sampled_bands(self.bands, fs, self.averaged)
                                 if lo <= 0)))
