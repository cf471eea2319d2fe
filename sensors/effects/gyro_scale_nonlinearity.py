"""Second-order scale-factor nonlinearity of a fibre-optic gyro (seed eq. 4.39-4.41, beta_2).

    w_i' = w_S,i + k2_i w_S,i^2                          [rad/s],  k2 (1/(rad/s))

Stage "sensor": the gyro model (:class:`imurig.sensors.gyro.FOGTriad`, its ``k2_per_rad_s``)
applies it; ``inject`` applies a k2 of its own to rates (tests).

Diagnosis (appendix-B rows, a twin linear in the rate): the column r^2 of the stopwatch rate r
(deg/s) for one gyro (:class:`RateRowView`), or one such column per gyro in the voltmeter's joint
analysis (:class:`VoltmeterRowView`). Truth map, first order in k2 and with the reference rate
the true one: V = SF (w + k2 w^2), so the coefficient of r^2 is SF k2 (pi/180)^2 V/(deg/s)^2.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from imurig.sensors.effects._rate_rows import gyro_index, gyros
from imurig.sensors.effects.base import Candidate, Effect, Param
from imurig.sensors.effects.views import RateRowView, VoltmeterRowView


@dataclass
class GyroScaleNonlinearity(Effect):
    """k2 (3,) 1/(rad/s) of each gyro."""

    k2_per_rad_s: np.ndarray = field(default_factory=lambda: np.zeros(3))

    name: ClassVar[str] = "gyro_scale_nonlinearity"
    order: ClassVar[int] = 208
    finding: ClassVar[str] = "scale_nonlinearity"
    stage: ClassVar[str] = "sensor"
    physics: ClassVar[str] = "second-order scale-factor nonlinearity of the gyro: a term k2 w^2"
    seed_section: ClassVar[str] = "4.4.4, eq. 4.39-4.41"
    seed_says: ClassVar[str] = "the second-order coefficients are beta_2 for each model"
    params: ClassVar[tuple] = (Param("k2", "V/(deg/s)^2", note="coefficient of the rate squared; SF k2 (pi/180)^2"),
                               Param("k2_per_rad_s", "1/(rad/s)", datasheet=2e-6 / math.radians(1.0),
                                     note="the model's bound: 2e-6 per deg/s"))
    views: ClassVar[tuple] = (RateRowView.kind, VoltmeterRowView.kind)

    def __post_init__(self):
        self.k2_per_rad_s = np.broadcast_to(np.asarray(self.k2_per_rad_s, float), (3,)).copy()

    def inject(self, w: np.ndarray, ctx=None, rng=None) -> np.ndarray:
        """w + k2 w^2 for rates w (n, 3) rad/s."""
        w = np.asarray(w, float)
        return w + self.k2_per_rad_s * w**2

    def candidates(self, view) -> list[Candidate]:
        if isinstance(view, RateRowView):
            r = np.asarray(view.rate_dps, float)
            return [Candidate(self.finding_name(), "second-order scale-factor nonlinearity of the gyro", ("k2",),
                              lambda _: r**2)]
        if isinstance(view, VoltmeterRowView):
            r = np.asarray(view.rate_dps, float)
            return [Candidate(self.finding_name(), "second-order scale-factor nonlinearity of each gyro",
                              tuple(f"k2_{g}" for g in view.gyros), lambda _: view.per_gyro(r**2))]
        return []

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        """{k2: SF_j k2_j (pi/180)^2} (V/(deg/s)^2) of gyro ``channel``, first order."""
        g, j = gyros(truth), gyro_index(channel)
        return {"k2": float(g["scale_V_per_rad_s"][j]) * float(g["k2_per_rad_s"][j]) * math.radians(1.0) ** 2}
