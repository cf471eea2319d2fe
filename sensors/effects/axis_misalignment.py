"""Input-axis misalignment of the Q-Flex triad (seed 4.3.5, Tables 4.4-4.6; datasheet A.1: <= 2 mrad).

    a_S = (I + M) f_C          [m/s^2, (n, 3)],  M: zero diagonal, m_jk (rad) = how far axis j
                                                  leans towards axis k

Injected by the sensor model (:class:`imurig.sensors.accelerometer.QFlexTriad`, its
``misalignment_rad``: stage "sensor"); ``inject`` applies an M of its own to a signal (tests).

Diagnosis (static positions, a twin without misalignment): the other two axes' indicated specific
forces u_k, u_l are the columns. Truth map: in the inverse model f = (I + M)^-1 D^-1 u (exact
without nonlinearity; D the relative scale, :mod:`imurig.sensors.effects._qflex`) axis j's
coefficients of u_k are m_jk = [(I + M)^-1 D^-1]_jk.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from imurig.sensors.effects._qflex import AXES, axis_index, inverse_linear
from imurig.sensors.effects.base import Candidate, Effect, Param, PositionView


@dataclass
class AxisMisalignment(Effect):
    """Misalignment M (3, 3) rad of a triad's input axes (zero diagonal)."""

    misalignment_rad: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))

    name: ClassVar[str] = "axis_misalignment"
    stage: ClassVar[str] = "sensor"
    physics: ClassVar[str] = ("an accelerometer's sensitive axis leans towards the other two axes (input-axis "
                              "misalignment)")
    seed_section: ClassVar[str] = "4.3.5, Table 4.4; A.1"
    seed_says: ClassVar[str] = ("'beta2 = 0.00553735 of Ax is the contingent of the y-accelerometer that influences "
                                "the output in direction of the sensitive axis of the x-accelerometer'; the datasheet "
                                "bounds the input-axis misalignment by 2 mrad")
    params: ClassVar[tuple] = (Param("m_jk", "1", datasheet=2e-3,
                                     note="inverse-model coefficient of axis k's reading in axis j's model "
                                          "(~ -M_jk / D_k); datasheet bound on M in rad"),)
    views: ClassVar[tuple] = ("positions",)
    order: ClassVar[int] = 30

    def __post_init__(self):
        self.misalignment_rad = np.asarray(self.misalignment_rad, float).reshape(3, 3).copy()
        np.fill_diagonal(self.misalignment_rad, 0.0)

    def inject(self, f_C: np.ndarray, ctx=None, rng=None) -> np.ndarray:
        """a_S = (I + M) f_C for f_C (n, 3) m/s^2."""
        f_C = np.asarray(f_C, float)
        return f_C + f_C @ self.misalignment_rad.T

    @staticmethod
    def others(axis: str) -> list[str]:
        """The other two axes' reading names ('ax', 'ay', 'az' without axis' own)."""
        return [f"a{a}" for a in AXES if a != axis]

    def candidates(self, view: PositionView) -> list[Candidate]:
        others = self.others(view.axis)
        if set(others) & set(view.model_terms):  # the twin already has the other axes' terms
            return []
        r = view.readings
        return [Candidate(self.name, f"the sensitive axis of acc_{view.axis} leans towards the other two axes "
                                     "(misalignment; the inverse model's coefficients of the other axes' readings)",
                          tuple(f"m_{view.axis}{o[1]}" for o in others),
                          lambda _, o=others: np.column_stack([r[o[0]], r[o[1]]]))]

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        """{m_jk: [(I + M)^-1 D^-1]_jk} for the other axes k of ``channel`` ('acc_x' ...);
        ``truth`` from :func:`imurig.sensors.effects.base.recording_truth`."""
        j = axis_index(channel)
        inv = inverse_linear(truth)
        return {f"m_{AXES[j]}{AXES[k]}": float(inv[j, k]) for k in range(3) if k != j}
