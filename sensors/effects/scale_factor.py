"""Scale-factor error of an inertial sensor (seed 4.3.5, Tables 4.4-4.6; datasheets A.1, A.2).

    V_i = S_nom,i (1 + s_i) x_i     [V],  s_i = S_i / S_nom,i - 1   (-)

Injected by the sensor models through their true sensitivities (the Q-Flex's K1 R_L, the gyro's
scale factor: stage "sensor"); ``inject`` applies an s of its own to a signal (tests). The filter
carries it as ``acc.scale_factor.s_x`` ... and ``gyro.scale_factor.s_x`` ...
(:mod:`imurig.sensors.error_states`), the calibrations as their sensitivities.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from imurig.sensors.effects.base import Effect, Param

AXES = ("x", "y", "z")


@dataclass
class ScaleFactor(Effect):
    """Relative scale-factor error s (3,) of a triad."""

    s: np.ndarray = field(default_factory=lambda: np.zeros(3))

    name: ClassVar[str] = "scale_factor"
    stage: ClassVar[str] = "sensor"
    physics: ClassVar[str] = "each sensor's sensitivity differs from its nominal value (scale-factor error)"
    seed_section: ClassVar[str] = "4.3.5; A.1, A.2"
    seed_says: ClassVar[str] = "the Q-Flex scale factor is 1.33 mA/g within 0.2 % (datasheet A.1)"
    params: ClassVar[tuple] = tuple(Param(f"s_{a}", "1", datasheet=2e-3) for a in AXES)
    order: ClassVar[int] = 2

    def __post_init__(self):
        self.s = np.broadcast_to(np.asarray(self.s, float), (3,)).copy()

    def inject(self, x: np.ndarray, ctx=None, rng=None) -> np.ndarray:
        """x (n, 3) (1 + s)."""
        return np.asarray(x, float) * (1 + self.s)
