"""A drift of the gyro output in the order the appendix-B rows were read.

    V_i' = V_i + d i                 [V],  i the row (in the order taken), d (V per row)

No sensor model injects it as such (a turn-on drift or warming of the gyro would); ``inject``
applies it to readings in row order (tests). Diagnosis (:class:`RateRowView`): the row index is
the column. Truth map: no chain injects it, so the truth is d = 0.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from imurig.sensors.effects.base import Candidate, Effect, Param
from imurig.sensors.effects.views import RateRowView


@dataclass
class GyroRowDrift(Effect):
    """A drift ``drift_V_per_row`` (V per row)."""

    drift_V_per_row: float = 0.0

    name: ClassVar[str] = "gyro_row_drift"
    order: ClassVar[int] = 209
    finding: ClassVar[str] = "drift"
    stage: ClassVar[str] = "digital"
    physics: ClassVar[str] = "a drift of the gyro output in the order the rows were taken"
    seed_section: ClassVar[str] = "4.4.2, appendix B"
    seed_says: ClassVar[str] = "– (not examined in the seed; the rows of Table B.1 were read one after the other)"
    params: ClassVar[tuple] = (Param("drift", "V/row"),)
    views: ClassVar[tuple] = (RateRowView.kind,)

    def inject(self, V: np.ndarray, ctx=None, rng=None) -> np.ndarray:
        V = np.asarray(V, float)
        return V + self.drift_V_per_row * np.arange(V.size)

    def candidates(self, view) -> list[Candidate]:
        if not isinstance(view, RateRowView):
            return []
        idx = view.row
        return [Candidate(self.finding_name(), self.physics, ("drift",), lambda _: idx.astype(float))]

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        """{drift: 0}: no chain injects a drift in row order (module doc)."""
        return {"drift": 0.0}
