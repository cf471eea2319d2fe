"""Rate noise of the fibre-optic gyros: angle random walk and bias instability (datasheet A.2).

    w_i'(t) = w_i(t) + n_i(t) + b_gm,i(t)                          [rad/s]
    n_i     white, per-sample sigma = N sqrt(f_s)  (Allan deviation N / sqrt(tau))
    b_gm,i  first-order Gauss-Markov: b[k+1] = phi b[k] + sigma sqrt(1 - phi^2) w[k],
            phi = exp(-1 / (tau f_s)), stationary start b[0] ~ N(0, sigma^2)

Injected by the triad (:meth:`imurig.sensors.gyro.FOGTriad.noise_rate` draws through ``rate``);
the filter priors (ARW, bias-instability sigma and tau) and the bounds ask this object.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from scipy import signal

from imurig.kernel.units import DEG
from imurig.sensors.effects.base import ChainContext, Effect, Param


@dataclass
class GyroNoise(Effect):
    """Angle random walk ``arw_rad_s_per_sqrt_hz`` and Gauss-Markov bias instability
    (``bias_instability_rad_s``, ``bias_instability_tau_s``) of each gyro."""

    arw_rad_s_per_sqrt_hz: float = 0.0015 * DEG
    bias_instability_rad_s: float = 0.001 * DEG
    bias_instability_tau_s: float = 100.0
    enabled: bool = True

    name: ClassVar[str] = "gyro_noise"
    stage: ClassVar[str] = "sensor"
    physics: ClassVar[str] = "the gyros' white rate noise (angle random walk) and slowly wandering bias"
    seed_section: ClassVar[str] = "A.2; 4.4"
    seed_says: ClassVar[str] = ("the VG941-3AM datasheet gives a random walk of 0.0015 deg/s/sqrt(Hz) and a bias "
                                "variation of 0.001 deg/s")
    params: ClassVar[tuple] = (Param("arw_rad_s_per_sqrt_hz", "rad/s/sqrt(Hz)", datasheet=0.0015 * DEG),
                               Param("bias_instability_rad_s", "rad/s", datasheet=0.001 * DEG),
                               Param("bias_instability_tau_s", "s", datasheet=100.0))
    order: ClassVar[int] = 6

    def rate(self, n: int, fs: float, rng: np.random.Generator) -> np.ndarray:
        """Rate noise (n, 3) rad/s: white plus Gauss-Markov bias instability (module doc)."""
        if not self.enabled:
            return np.zeros((n, 3))
        out = rng.standard_normal((n, 3))
        out *= self.arw_rad_s_per_sqrt_hz * np.sqrt(fs)  # in place: the same values, no second copy
        if self.bias_instability_rad_s > 0:
            phi = np.exp(-1.0 / (self.bias_instability_tau_s * fs))
            drive = rng.standard_normal((n, 3))
            drive *= self.bias_instability_rad_s
            drive *= np.sqrt(1 - phi**2)
            drive[0] = rng.standard_normal(3) * self.bias_instability_rad_s  # stationary start
            for j in range(3):  # one axis at a time: the same recursion, one (n,) temporary
                out[:, j] += signal.lfilter([1.0], [1.0, -phi], drive[:, j])
        return out

    def inject(self, w: np.ndarray, ctx: ChainContext, rng: np.random.Generator) -> np.ndarray:
        """w (n, 3) rad/s + n(t) + b_gm(t)."""
        w = np.asarray(w, float)
        if not self.enabled:
            return w
        return w + self.rate(w.shape[0], ctx.sample_rate_hz, rng)

    def noise_variance(self, ctx: ChainContext) -> float:
        """Per-axis variance (rad/s)^2 of one sample (N^2 f_s + sigma_b^2) or of the mean of
        ``ctx.window_samples`` = m samples: N^2 f_s / m + sigma_b^2 (the Gauss-Markov part, tau
        much longer than the window, does not average out)."""
        if not self.enabled:
            return 0.0
        m = max(int(ctx.window_samples), 1)
        return self.arw_rad_s_per_sqrt_hz**2 * ctx.sample_rate_hz / m + self.bias_instability_rad_s**2
