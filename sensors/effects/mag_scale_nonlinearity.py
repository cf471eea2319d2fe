"""Second-order scale nonlinearity of each magnetometer axis.

    B_S,j' = B_S,j + k2_j B_S,j^2                    [T],  k2 (3,) 1/T

No sensor model injects it (the fluxgate model is linear); ``inject`` applies it (tests).
Diagnosis (:class:`MagView`): per axis the column (A B_ref)_j^2 of the twin's fitted field (nT^2),
amplitude k2_j (1/nT). Truth map: nothing injects it, so the truth is k2 = 0.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from imurig.sensors.effects._fluxgate import AXES
from imurig.sensors.effects.base import Candidate, Effect, Param
from imurig.sensors.effects.views import MagView


@dataclass
class MagScaleNonlinearity(Effect):
    """k2 (3,) 1/T of each axis."""

    k2_per_T: np.ndarray = field(default_factory=lambda: np.zeros(3))

    name: ClassVar[str] = "mag_scale_nonlinearity"
    order: ClassVar[int] = 217
    finding: ClassVar[str] = "scale_nonlinearity"
    stage: ClassVar[str] = "sensor"
    physics: ClassVar[str] = "second-order scale nonlinearity of each axis (1/nT)"
    seed_section: ClassVar[str] = "4.6"
    seed_says: ClassVar[str] = "– (the seed's magnetometer model is linear: hard iron, scale factors, soft iron)"
    params: ClassVar[tuple] = tuple(Param(f"k2_{a}_per_nT", "1/nT") for a in AXES)
    views: ClassVar[tuple] = (MagView.kind,)

    def __post_init__(self):
        self.k2_per_T = np.broadcast_to(np.asarray(self.k2_per_T, float), (3,)).copy()

    def inject(self, B_S: np.ndarray, ctx=None, rng=None) -> np.ndarray:
        return B_S + self.k2_per_T * B_S**2

    def candidates(self, view) -> list[Candidate]:
        if not isinstance(view, MagView):
            return []
        P = view.predicted_nT()
        return [Candidate(self.finding_name(), self.physics, tuple(f"k2_{a}_per_nT" for a in AXES),
                          lambda _: np.column_stack([view.on_axis(j, P[:, j] ** 2) for j in range(3)]))]

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        """Zero on every axis: the fluxgate model is linear (module doc)."""
        return {f"k2_{a}_per_nT": 0.0 for a in AXES}
