"""Common-mode noise and the ground loop of single-ended wiring (seed 4.3.4, Table 4.3).

    u_j(t) = v_j(t) + c(t)                                    [V], the same c on every slot j
    c(t)   = sigma_cm e(t)                                    (NRSE, GRSE; e white N(0, 1))
           + A_gl (sin(2 pi f_mains t + p) + 0.3 sin(6 pi f_mains t + p))   (GRSE only)

Differential wiring (DIFF) rejects both. Per logged sample the white part adds sigma_cm^2 to
every channel and to every pair's covariance; the mean of N samples, sigma_cm^2 / N. The mains
hum is deterministic within a record (a random phase p per record); it does not enter the
Gaussian budgets.

Injected by the converter (:meth:`imurig.sensors.adc.DAQ6036E.convert` draws through ``common``);
the bounds and the filter priors ask ``noise_variance``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from imurig.sensors.effects.base import ChainContext, Effect, Param


@dataclass
class CommonModeNoise(Effect):
    """White common-mode noise ``rms_V`` and a ground-loop hum ``ground_loop_V`` at ``mains_hz``,
    for the converter's ``grounding`` ("GRSE", "NRSE" or "DIFF")."""

    rms_V: float = 30e-6
    ground_loop_V: float = 2e-3
    mains_hz: float = 50.0
    grounding: str = "NRSE"

    name: ClassVar[str] = "common_mode_noise"
    stage: ClassVar[str] = "conversion"
    physics: ClassVar[str] = ("noise common to all single-ended inputs, and mains hum through a ground loop when the "
                              "inputs are referenced to the converter's ground")
    seed_section: ClassVar[str] = "4.3.4, Table 4.3"
    seed_says: ClassVar[str] = ("Table 4.3 compares GRSE, NRSE and DIFF wiring: the noise of the single-ended "
                                "modes is higher")
    params: ClassVar[tuple] = (Param("rms_V", "V", seed=30e-6), Param("ground_loop_V", "V", seed=2e-3))
    order: ClassVar[int] = 9

    def common(self, time_s: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """c(t) (n,) V (module doc); zeros for DIFF. Draws the white part, then the hum's phase."""
        n = np.asarray(time_s).size
        c = np.zeros(n)
        if self.grounding != "DIFF" and self.rms_V > 0:
            c += self.rms_V * rng.standard_normal(n)
        if self.grounding == "GRSE" and self.ground_loop_V > 0:
            p = rng.uniform(0, 2 * np.pi)
            t = np.asarray(time_s, float)
            c += self.ground_loop_V * (np.sin(2 * np.pi * self.mains_hz * t + p)
                                       + 0.3 * np.sin(2 * np.pi * 3 * self.mains_hz * t + p))
        return c

    def noise_variance(self, ctx: ChainContext) -> float:
        """sigma_cm^2 / N V^2 per channel (N = ``ctx.window_samples``; 0 for DIFF)."""
        if self.grounding == "DIFF":
            return 0.0
        return self.rms_V**2 / max(int(ctx.window_samples), 1)
