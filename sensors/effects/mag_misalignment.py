"""Misalignment of the magnetometer's axes against the rig's (IMU) frame (seed 4.6, Fig. 4.24):
a small rotation of the ellipse's axes.

    B_S = S (I + M) B_C + ...,   M = -M^T (a small rotation; zero diagonal)     [T, (n, 3)]

Stage "sensor": the fluxgate model (:class:`imurig.sensors.magnetometer.FluxgateTriad`, its
``misalignment_rad``) applies (I + M) before the soft iron. Diagnosis (:class:`MagView`, the
nominal twin): per axis pair (j, k) the column m_j += g_j w_jk B_k, m_k -= g_k w_jk B_j (rad).
Truth map: w_jk = M_jk (the concealed case injects an antisymmetric M).
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
class MagMisalignment(Effect):
    """M (3, 3) rad, zero diagonal."""

    misalignment_rad: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))

    name: ClassVar[str] = "mag_misalignment"
    order: ClassVar[int] = 213
    finding: ClassVar[str] = "misalignment"
    stage: ClassVar[str] = "sensor"
    physics: ClassVar[str] = ("misalignment: the sensor axes are rotated against the rig's (IMU) frame "
                              "(antisymmetric cross-coupling w_jk = -w_kj, rad)")
    seed_section: ClassVar[str] = "4.6, Fig. 4.24"
    seed_says: ClassVar[str] = ("misalignments ... can be described as a rotation of the minor and major axes; "
                                "considered very low if care is taken during the installation")
    params: ClassVar[tuple] = tuple(Param(f"w_{AXES[j]}{AXES[k]}_rad", "rad", datasheet=5e-3) for j, k in PAIRS)
    views: ClassVar[tuple] = (MagView.kind,)

    def __post_init__(self):
        self.misalignment_rad = np.asarray(self.misalignment_rad, float).reshape(3, 3).copy()
        np.fill_diagonal(self.misalignment_rad, 0.0)

    def matrix(self) -> np.ndarray:
        """I + M."""
        return np.eye(3) + self.misalignment_rad

    def inject(self, B: np.ndarray, ctx=None, rng=None) -> np.ndarray:
        """(I + M) B for B (n, 3)."""
        return B @ self.matrix().T

    def candidates(self, view) -> list[Candidate]:
        if not isinstance(view, MagView) or view.twin_model != "nominal":
            return []
        g, Bb = view.gains(), view.field_nT
        return [Candidate(self.finding_name(), self.physics, tuple(f"w_{AXES[j]}{AXES[k]}_rad" for j, k in PAIRS),
                          lambda _: np.column_stack([view.on_axis(j, g[j] * Bb[:, k]) - view.on_axis(k, g[k] * Bb[:, j])
                                                     for j, k in PAIRS]))]

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        M = fluxgate(truth)["misalignment_rad"]
        return {f"w_{AXES[j]}{AXES[k]}_rad": float(M[j][k]) for j, k in PAIRS}
