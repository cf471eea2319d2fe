"""Hard iron (seed 4.6, eq. 4.45-4.47): a constant field of the magnetised vehicle or rack adds to
every axis of the magnetometer.

    B_S = ... + b_hard                         [T, (n, 3)]

Stage "sensor": the fluxgate model (:class:`imurig.sensors.magnetometer.FluxgateTriad`, its
``hard_iron_T``) adds it. Diagnosis (:class:`MagView`, the nominal twin of per-axis gains):
one constant column per axis, amplitudes b_j (nT) in the indicated field m = V / s_nominal.
Truth map: b_j = g_j b_hard,j (nT), g_j = s_true / s_nominal.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from imurig.sensors.effects._fluxgate import AXES, NT, fluxgate, gain
from imurig.sensors.effects.base import Candidate, Effect, Param
from imurig.sensors.effects.views import MagView


@dataclass
class HardIron(Effect):
    """b_hard (3,) T in the sensor frame."""

    hard_iron_T: np.ndarray = field(default_factory=lambda: np.zeros(3))

    name: ClassVar[str] = "hard_iron"
    order: ClassVar[int] = 211
    stage: ClassVar[str] = "sensor"
    physics: ClassVar[str] = "hard iron: a constant field of the magnetised vehicle or rack adds to every axis (nT)"
    seed_section: ClassVar[str] = "4.6, eq. 4.45-4.47"
    seed_says: ClassVar[str] = "a hard iron bias would change the origin of the circle"
    params: ClassVar[tuple] = tuple(Param(f"b_{a}_nT", "nT", datasheet=2000.0, note="g_j b_hard,j") for a in AXES)
    views: ClassVar[tuple] = (MagView.kind,)

    def __post_init__(self):
        self.hard_iron_T = np.broadcast_to(np.asarray(self.hard_iron_T, float), (3,)).copy()

    def inject(self, B_S: np.ndarray, ctx=None, rng=None) -> np.ndarray:
        """B_S + b_hard for B_S (n, 3) T."""
        return B_S + self.hard_iron_T

    def candidates(self, view) -> list[Candidate]:
        if not isinstance(view, MagView) or view.twin_model != "nominal":
            return []
        nb = view.n_blocks
        return [Candidate(self.name, self.physics, tuple(f"b_{a}_nT" for a in AXES),
                          lambda _: np.column_stack([view.on_axis(j, np.ones(nb)) for j in range(3)]))]

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        g, b = gain(truth), fluxgate(truth)["hard_iron_T"]
        return {f"b_{a}_nT": float(g[j] * b[j] * NT) for j, a in enumerate(AXES)}
