"""Second-order scale-factor nonlinearity of a Q-Flex (datasheet A.1: <= 48 ug/g^2; seed 4.3.5).

    a_j' = a_S,j + k2_j a_S,j^2        [m/s^2],  k2 (1/(m/s^2))

Injected by the sensor model (:class:`imurig.sensors.accelerometer.QFlexTriad`, its
``k2_per_m_s2``: stage "sensor"); ``inject`` applies a k2 of its own to a signal (tests).

Diagnosis (static positions, a twin without the square): the axis' own reading squared, u_j^2,
is the column. Truth map: u_j = D_j (a + k2 a^2) inverts to a = u_j / D_j - k2_j (u_j / D_j)^2
+ O(k2^2 u^3), so the inverse model's coefficient of u_j^2 is -k2_j / D_j^2 (first order in k2).
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from imurig.sensors.effects._qflex import accelerometers, axis_index, relative_scale
from imurig.sensors.effects.base import Candidate, Effect, Param, PositionView

G = 9.80665  # m/s^2 per g, for the datasheet's ug/g^2 only


@dataclass
class ScaleNonlinearity(Effect):
    """k2 (3,) 1/(m/s^2) of each axis."""

    k2_per_m_s2: np.ndarray = field(default_factory=lambda: np.zeros(3))

    name: ClassVar[str] = "scale_nonlinearity"
    stage: ClassVar[str] = "sensor"
    physics: ClassVar[str] = "the scale factor changes with the input: a second-order term k2 a^2"
    seed_section: ClassVar[str] = "4.3.5; A.1"
    seed_says: ClassVar[str] = ("'no improvement ... with polynomials higher than quadratic terms except for the "
                                "z-axis'; the datasheet's nonlinearity is at most 48 ug/g^2")
    params: ClassVar[tuple] = (Param("k2", "1/(m/s^2)", datasheet=48e-6 / G,
                                     note="inverse-model coefficient of the own reading squared, -k2 / D^2"),)
    views: ClassVar[tuple] = ("positions",)
    order: ClassVar[int] = 40

    def __post_init__(self):
        self.k2_per_m_s2 = np.broadcast_to(np.asarray(self.k2_per_m_s2, float), (3,)).copy()

    def inject(self, a: np.ndarray, ctx=None, rng=None) -> np.ndarray:
        """a + k2 a^2 for a (n, 3) m/s^2."""
        a = np.asarray(a, float)
        return a + self.k2_per_m_s2 * a**2

    def candidates(self, view: PositionView) -> list[Candidate]:
        own = f"a{view.axis}"
        if f"{own}^2" in view.model_terms:
            return []
        return [Candidate(self.name, f"second-order scale-factor nonlinearity of acc_{view.axis} (the inverse "
                                     "model's coefficient of its own reading squared, 1/(m/s^2))", ("k2",),
                          lambda _, u=view.readings[own]: u ** 2)]

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        """{k2: -k2_j / D_j^2} on ``channel``; ``truth`` from ``recording_truth``."""
        j = axis_index(channel)
        return {"k2": float(-accelerometers(truth)["k2_per_m_s2"][j] / relative_scale(truth)[j] ** 2)}
