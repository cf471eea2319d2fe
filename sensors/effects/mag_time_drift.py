"""A drift of the magnetometer's offsets in time, independently of the temperature.

    B_S = ... + d (t - t_0)                          [T, (n, 3)],  d (3,) T/s

No sensor model injects it (the fluxgate drifts with its temperature only); ``inject`` applies
it to a field record (tests). Diagnosis (:class:`MagView`): per axis the column (t_b - mean t) / 3600
(h), amplitude d_j (nT/h). Truth map: nothing injects it, so the truth is d = 0.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from imurig.sensors.effects._fluxgate import AXES
from imurig.sensors.effects.base import Candidate, ChainContext, Effect, Param
from imurig.sensors.effects.views import MagView


@dataclass
class MagTimeDrift(Effect):
    """Offset drift d (3,) T/s."""

    drift_T_per_s: np.ndarray = field(default_factory=lambda: np.zeros(3))

    name: ClassVar[str] = "mag_time_drift"
    order: ClassVar[int] = 216
    finding: ClassVar[str] = "time_drift"
    stage: ClassVar[str] = "sensor"
    physics: ClassVar[str] = "the offsets drift in time, independently of the temperature (nT/h per axis)"
    seed_section: ClassVar[str] = "4.6"
    seed_says: ClassVar[str] = "– (the seed treats the hard-iron biases as constant)"
    params: ClassVar[tuple] = tuple(Param(f"d_{a}_nT_per_h", "nT/h") for a in AXES)
    views: ClassVar[tuple] = (MagView.kind,)

    def __post_init__(self):
        self.drift_T_per_s = np.broadcast_to(np.asarray(self.drift_T_per_s, float), (3,)).copy()

    def inject(self, B_S: np.ndarray, ctx: ChainContext, rng=None) -> np.ndarray:
        """B_S + d (t - t_0), t = ctx.time_s."""
        t = np.asarray(ctx.time_s, float)
        return B_S + (t - t[0])[:, None] * self.drift_T_per_s[None, :]

    def candidates(self, view) -> list[Candidate]:
        if not isinstance(view, MagView):
            return []
        tb = np.asarray(view.time_s, float)
        th = (tb - tb.mean()) / 3600.0
        return [Candidate(self.finding_name(), self.physics, tuple(f"d_{a}_nT_per_h" for a in AXES),
                          lambda _: np.column_stack([view.on_axis(j, th) for j in range(3)]))]

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        """Zero on every axis: no chain injects a drift in time (module doc)."""
        return {f"d_{a}_nT_per_h": 0.0 for a in AXES}
