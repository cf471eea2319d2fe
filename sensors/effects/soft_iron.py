"""Soft iron (seed 4.6, eq. 4.48-4.51): induced magnetisation of the vehicle couples the axes
symmetrically and stretches the heading circle into an ellipse.

    B_S = S (I + M) B_C + ...,   S = S^T                   [T, (n, 3)]

Stage "sensor": the fluxgate model (:class:`imurig.sensors.magnetometer.FluxgateTriad`, its
``soft_iron``) applies S after the axis misalignment M. Diagnosis (:class:`MagView`, the nominal
twin): per axis pair (j, k) the column m_j += g_j s_jk B_k, m_k += g_k s_jk B_j (a symmetric
non-orthogonality of the sensor axes looks the same). Truth map: s_jk = S_jk.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from imurig.sensors.effects._fluxgate import AXES, PAIRS, fluxgate
from imurig.sensors.effects.base import Candidate, Effect, Param
from imurig.sensors.effects.views import MagView


@dataclass
class SoftIron(Effect):
    """The symmetric soft-iron matrix S (3, 3) (identity: none)."""

    soft_iron: np.ndarray = field(default_factory=lambda: np.eye(3))

    name: ClassVar[str] = "soft_iron"
    order: ClassVar[int] = 212
    stage: ClassVar[str] = "sensor"
    physics: ClassVar[str] = ("soft iron: induced magnetisation couples the axes symmetrically (s_jk = s_kj; a "
                              "symmetric non-orthogonality of the sensor axes looks the same)")
    seed_section: ClassVar[str] = "4.6, eq. 4.48-4.51"
    seed_says: ClassVar[str] = ("scale factor and soft iron effects give an ellipse with different minor and major "
                                "axes")
    params: ClassVar[tuple] = tuple(Param(f"s_{AXES[j]}{AXES[k]}", "1", datasheet=0.05) for j, k in PAIRS)
    views: ClassVar[tuple] = (MagView.kind,)

    def __post_init__(self):
        self.soft_iron = np.asarray(self.soft_iron, float).reshape(3, 3).copy()

    def matrix(self) -> np.ndarray:
        return self.soft_iron

    def inject(self, B: np.ndarray, ctx=None, rng=None) -> np.ndarray:
        """S B for B (n, 3)."""
        return B @ self.soft_iron.T

    def candidates(self, view) -> list[Candidate]:
        if not isinstance(view, MagView) or view.twin_model != "nominal":
            return []
        g, Bb = view.gains(), view.field_nT
        return [Candidate(self.name, self.physics, tuple(f"s_{AXES[j]}{AXES[k]}" for j, k in PAIRS),
                          lambda _: np.column_stack([view.on_axis(j, g[j] * Bb[:, k]) + view.on_axis(k, g[k] * Bb[:, j])
                                                     for j, k in PAIRS]))]

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        S = fluxgate(truth)["soft_iron"]
        return {f"s_{AXES[j]}{AXES[k]}": float(S[j][k]) for j, k in PAIRS}
