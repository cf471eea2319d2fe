"""Steady-state instability of the fibre-optic gyros' scale factor (datasheet A.2: "SF stability
(steady state) 0.03 %").

    V_i'(t) = V_i(t) (1 + s_i(t))                                                  [V]
    s_i     first-order Gauss-Markov: s[k+1] = phi s[k] + sigma sqrt(1 - phi^2) w[k],
            phi = exp(-1 / (tau f_s)), stationary start s[0] ~ N(0, sigma^2)

on each gyro line (``gyro_p``, ``gyro_q``, ``gyro_r``; one stream per line). Stage "analog": it
multiplies the line's voltage, bias included (the bias voltage is < 0.1 % of a turning line's).
The mean of s over a window of T seconds has the variance

    var(mean s) = sigma^2 (2 tau / T) (1 - (tau / T) (1 - exp(-T / tau)))          [-]

(:meth:`GyroScaleInstability.window_variance`), so a window of whole rounds at rate Omega carries
a rate error of variance Omega^2 var(mean s). The datasheet gives sigma (3e-4, 1 sigma) and no
correlation time; ``tau_s`` is an assumption (10 s, shorter than a turn-table step, so steps are
independent). Off by default (sigma = 0); the Delft 2005 preset's turn table fits sigma to the
residual envelopes of Figs. 4.20-4.21 (:mod:`imurig.montecarlo.delft_fit_turn`).
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from scipy import signal

from imurig.sensors.effects.base import ChainContext, Effect, Param

#: the datasheet's bound (A.2, "SF stability (steady state) 0.03%")
DATASHEET_SIGMA = 3e-4
GYRO_LINES = ("gyro_p", "gyro_q", "gyro_r")


@dataclass
class GyroScaleInstability(Effect):
    """Relative scale-factor wander of each gyro line: Gauss-Markov ``sigma`` (-), ``tau_s`` (s)."""

    enabled: bool = False
    sigma: float = 0.0
    tau_s: float = 10.0

    name: ClassVar[str] = "gyro_scale_instability"
    stage: ClassVar[str] = "analog"
    stream: ClassVar[str] = "gyro_scale"
    physics: ClassVar[str] = ("the gyros' scale factor wanders about its mean during a run, so a rate step's "
                              "mean output scatters in proportion to the rate")
    seed_section: ClassVar[str] = "A.2 (VG941-3AM datasheet); 4.4.3-4.4.4, Figs. 4.20-4.21"
    seed_says: ClassVar[str] = "Table A.1: 'SF stability (steady state) 0.03%', 'SF repeatability 0.10%'"
    params: ClassVar[tuple] = (
        Param("sigma", "1", datasheet=DATASHEET_SIGMA, note="relative, 1 sigma"),
        Param("tau_s", "s", note="not in the datasheet; assumed 10 s (steps independent)"))

    def lines(self, names, ctx: ChainContext | None = None) -> list[str]:
        if not self.enabled or self.sigma <= 0:
            return []
        return [n for n in names if n in GYRO_LINES]

    def line_stream(self, line: str) -> str:
        return f"{self.stream}_{line}"

    def wander(self, n: int, fs: float, rng: np.random.Generator) -> np.ndarray:
        """s (n,) of one line (module doc)."""
        phi = float(np.exp(-1.0 / (self.tau_s * fs)))
        drive = rng.standard_normal(n) * self.sigma * np.sqrt(1 - phi**2)
        drive[0] = rng.standard_normal() * self.sigma     # stationary start
        return signal.lfilter([1.0], [1.0, -phi], drive)

    def inject(self, v: np.ndarray, ctx: ChainContext, rng: np.random.Generator) -> np.ndarray:
        if not self.enabled or self.sigma <= 0:
            return v
        v = np.asarray(v, float)
        return v * (1.0 + self.wander(v.shape[0], ctx.sample_rate_hz, rng))

    def window_variance(self, window_s) -> np.ndarray:
        """var of the mean of s over windows of ``window_s`` seconds (module doc)."""
        T = np.asarray(window_s, float)
        r = self.tau_s / T
        return self.sigma**2 * 2 * r * (1 - r * (1 - np.exp(-1 / r)))

    def noise_variance(self, ctx: ChainContext) -> float:
        """Relative variance sigma^2 of one sample (the line's variance is this times V^2)."""
        return self.sigma**2 if self.enabled else 0.0

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        """{sigma}: the injected sigma on a gyro line (0 elsewhere or when off)."""
        e = truth.get("chain", {}).get("effects", {}).get(self.name)
        if not e or not e.get("enabled") or (channel is not None and channel not in GYRO_LINES):
            return {"sigma": 0.0}
        return {"sigma": float(e["sigma"])}
