"""An autoscaling voltmeter's range change (seed 4.4.2): from the row where the readings cross a
range limit on, they come with the upper range's gain and display resolution.

    V_read,i = (1 + gain_step [i >= k]) V_i + offset_step [i >= k]               [V]

k: the first row on the upper range. Stage "digital": the hand-read voltmeter
(:class:`imurig.sensors.voltmeter.AutoscaleVoltmeter`, its per-range ``gain`` and
``resolution_V``) applies it by range; ``inject`` applies a step from ``first_row`` (tests).

Diagnosis: per gyro (:class:`RateRowView`) the columns r [i >= k] and [i >= k] (gain step in V
per deg/s, offset step in V); jointly for all gyros read by the one voltmeter
(:class:`VoltmeterRowView`) the columns s_g r [i >= k] (one relative gain step for all, s_g each
gyro's fitted scale) and [i >= k] (one offset step); k scanned, or fixed where the readings'
display grid locates it. Truth map: the relative gain step g_upper - 1 of the recorded voltmeter.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from imurig.sensors.effects.base import Candidate, Effect, Param
from imurig.sensors.effects.views import RateRowView, VoltmeterRowView


@dataclass
class InstrumentRangeChange(Effect):
    """A relative gain step ``gain_step`` and an offset step ``offset_step_V`` (V) from row ``first_row`` on."""

    first_row: int = 0
    gain_step: float = -0.006
    offset_step_V: float = 0.0

    name: ClassVar[str] = "instrument_range_change"
    order: ClassVar[int] = 207
    stage: ClassVar[str] = "digital"
    physics: ClassVar[str] = ("the voltmeter changed range (autoscale): a gain and offset step and a coarser "
                              "display from that row on")
    seed_section: ClassVar[str] = "4.4.2"
    seed_says: ClassVar[str] = ("the voltage meter was set to autoscale; it changed the measurement range for the "
                                "last nine measurements")
    params: ClassVar[tuple] = (Param("relative_gain_step", "1", seed=-0.006,
                                     note="joint over the gyros; per gyro the gain step is in V/(deg/s)"),
                               Param("offset_step_V", "V"), Param("first_row", "1", note="scanned"))
    views: ClassVar[tuple] = (RateRowView.kind, VoltmeterRowView.kind)

    def inject(self, V: np.ndarray, ctx=None, rng=None) -> np.ndarray:
        """Readings (m,) V in row order with the step from ``first_row`` on."""
        V = np.asarray(V, float)
        on = np.arange(V.size) >= self.first_row
        return V * (1 + self.gain_step * on) + self.offset_step_V * on

    def candidates(self, view) -> list[Candidate]:
        if isinstance(view, RateRowView):
            r, idx = np.asarray(view.rate_dps, float), view.row
            return [Candidate(self.name, "the voltmeter changed range (autoscale) from this row on: a gain and "
                              "offset step", ("gain_step", "offset_step"),
                              lambda kk: np.column_stack([r * (idx >= kk), (idx >= kk).astype(float)]),
                              scan=tuple(view.first_rows), scan_name="first_row")]
        if isinstance(view, VoltmeterRowView):
            r, idx = np.asarray(view.rate_dps, float), view.row
            m = len(view.gyros)
            step = lambda kk: np.tile((idx >= kk).astype(float), m)  # noqa: E731
            gain_col = lambda kk: np.concatenate([view.scale_V_per_dps[j] * r * (idx >= kk)  # noqa: E731
                                                  for j in range(m)])
            return [Candidate(self.name, "the voltmeter that reads all gyros changed range (autoscale) from this "
                              "row on: one gain step and one offset step for all of them",
                              ("relative_gain_step", "offset_step_V"),
                              lambda kk: np.column_stack([gain_col(kk), step(kk)]), scan=tuple(view.first_rows),
                              scan_name="first_row")]
        return []

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        """{relative_gain_step: gain of the upper range - 1} of the recorded voltmeter (truth["voltmeter"])."""
        return {"relative_gain_step": float(truth["voltmeter"]["gain"][1]) - 1.0}
