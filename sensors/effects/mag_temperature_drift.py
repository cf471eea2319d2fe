"""The fluxgate's offset drift with its temperature (seed 4.5: temperature changes bias and scale).

    B_S = ... + c (T - T_ref)                        [T, (n, 3)],  c (3,) T/K, T_ref = 298.15 K

T: the temperature inside the IMU box (the chain's T_box: the lab's IMU temperature, or the box
sensor's lag of the chamber air). Stage "sensor": the fluxgate model
(:class:`imurig.sensors.magnetometer.FluxgateTriad`, its ``tempco_T_per_K``) adds
:meth:`MagTemperatureDrift.offset_T` given the temperature the chain passes it.

Diagnosis (:class:`MagView`, offered only where the block temperature moved by more than 0.2 K):
per axis the column T_b - mean T (K), amplitude c_j (nT/K) in the indicated field. Truth map:
c_j = g_j tempco_j (nT/K), g_j = s_true / s_nominal.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from imurig.kernel.units import T_REF_K
from imurig.sensors.effects._fluxgate import AXES, NT, fluxgate, gain
from imurig.sensors.effects.base import Candidate, ChainContext, Effect, Param
from imurig.sensors.effects.views import MagView


@dataclass
class MagTemperatureDrift(Effect):
    """Offset tempco c (3,) T/K about ``reference_temperature_K``."""

    tempco_T_per_K: np.ndarray = field(default_factory=lambda: np.zeros(3))
    reference_temperature_K: float = T_REF_K

    name: ClassVar[str] = "mag_temperature_drift"
    order: ClassVar[int] = 215
    finding: ClassVar[str] = "temperature_drift"
    stage: ClassVar[str] = "sensor"
    physics: ClassVar[str] = "the fluxgate's offsets drift with its temperature (nT/K per axis)"
    seed_section: ClassVar[str] = "4.5"
    seed_says: ClassVar[str] = "temperature changes bias and scale; the correction of the temperature influences was " \
                               "done prior to the least-squares correction"
    params: ClassVar[tuple] = tuple(Param(f"c_{a}_nT_per_K", "nT/K", note="g_j tempco_j") for a in AXES)
    views: ClassVar[tuple] = (MagView.kind,)
    #: a drift with temperature is offered only where the temperature moved more than this (K)
    min_span_K: ClassVar[float] = 0.2

    def __post_init__(self):
        self.tempco_T_per_K = np.broadcast_to(np.asarray(self.tempco_T_per_K, float), (3,)).copy()

    def offset_T(self, temperature_K: np.ndarray) -> np.ndarray:
        """c (T - T_ref) (n, 3) T for temperatures (n,) K."""
        return (np.asarray(temperature_K, float) - self.reference_temperature_K)[:, None] * self.tempco_T_per_K[None, :]

    def inject(self, B_S: np.ndarray, ctx: ChainContext, rng=None) -> np.ndarray:
        """B_S + c (T - T_ref), T from ctx.truth_signals (T_box, else T_imu)."""
        ts = ctx.truth_signals
        return B_S + self.offset_T(ts["T_box"] if "T_box" in ts else ts["T_imu"])

    def candidates(self, view) -> list[Candidate]:
        if not isinstance(view, MagView) or view.temperature_K is None:
            return []
        Tb = np.asarray(view.temperature_K, float)
        if not np.ptp(Tb) > self.min_span_K:  # a drift with temperature needs the temperature to move
            return []
        dT = Tb - Tb.mean()
        return [Candidate(self.finding_name(), self.physics, tuple(f"c_{a}_nT_per_K" for a in AXES),
                          lambda _: np.column_stack([view.on_axis(j, dT) for j in range(3)]))]

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        g, c = gain(truth), fluxgate(truth)["tempco_T_per_K"]
        return {f"c_{a}_nT_per_K": float(g[j] * c[j] * NT) for j, a in enumerate(AXES)}
