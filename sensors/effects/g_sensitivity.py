"""Gyro g-sensitivity: the rate output responds to the specific force (seed: not examined).

    w_i' = w_S,i + sum_j G_ij f_C,j                          [rad/s],  G ((rad/s)/(m/s^2))

f_C: the specific force at the IMU in the case frame (m/s^2). Stage "sensor": the gyro model
(:class:`imurig.sensors.gyro.FOGTriad`, its ``g_sensitivity_rad_s_per_m_s2``) applies it
through :meth:`GSensitivity.rate_error`.

Diagnosis (:class:`TurnView`): the column -f_j, the window's mean specific force along gyro j's
axis, amplitude G_jj. On a level table with the IMU at the centre, f_j = g e_j: the column is
the Earth-rate column times g, and the two cannot be told apart (the diagnosis names them as
aliases). Truth map: G_jj of the recorded gyros.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from imurig.sensors.effects.base import Candidate, ChainContext, Effect, Param
from imurig.sensors.effects.views import TurnView

DEG_PER_H_PER_G = np.radians(1.0) / 3600.0 / 9.80665   # 1 deg/h per g in (rad/s)/(m/s^2)


@dataclass
class GSensitivity(Effect):
    """G (3, 3) (rad/s)/(m/s^2): row i, the rate error of gyro i per unit specific force along each case axis."""

    g_sensitivity_rad_s_per_m_s2: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))

    name: ClassVar[str] = "g_sensitivity"
    order: ClassVar[int] = 201
    stage: ClassVar[str] = "sensor"
    physics: ClassVar[str] = "the gyro responds to the specific force along its axis (g-sensitivity)"
    seed_section: ClassVar[str] = "4.4 (not examined in the seed)"
    seed_says: ClassVar[str] = "– (the seed calibrates the gyros on the turn table without a g-dependent term)"
    params: ClassVar[tuple] = (Param("G", "(rad/s)/(m/s^2)", note="diagonal G_jj; 10 deg/h/g is a FOG's order"),)
    views: ClassVar[tuple] = (TurnView.kind,)

    def __post_init__(self):
        self.g_sensitivity_rad_s_per_m_s2 = np.asarray(self.g_sensitivity_rad_s_per_m_s2, float).reshape(3, 3).copy()

    def rate_error(self, f_C: np.ndarray) -> np.ndarray:
        """G f_C (n, 3) rad/s for the specific force f_C (n, 3) m/s^2."""
        return np.asarray(f_C, float) @ self.g_sensitivity_rad_s_per_m_s2.T

    def inject(self, w: np.ndarray, ctx: ChainContext, rng=None) -> np.ndarray:
        """w + G f_C for rates w (n, 3) rad/s, f_C (n, 3) from ctx.truth_signals (f_C_x, f_C_y, f_C_z)."""
        f_C = np.stack([ctx.truth_signals[f"f_C_{a}"] for a in "xyz"], axis=1)
        return w + self.rate_error(f_C)

    def candidates(self, view) -> list[Candidate]:
        if not isinstance(view, TurnView):
            return []
        return [Candidate(self.name, f"gyro {view.axis} responds to the specific force along its axis "
                                     "(g-sensitivity, (rad/s)/(m/s^2))", ("G",),
                          lambda _, c=-np.asarray(view.specific_force_m_s2): c)]

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        """{G: G_jj} of gyro ``channel`` ("gyro_p", "p" ...)."""
        j = "pqr".index(channel[-1])
        return {"G": float(truth["sensors"]["gyros"]["g_sensitivity_rad_s_per_m_s2"][j][j])}
