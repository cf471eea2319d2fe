"""Bias drift with the accelerometer's temperature (seed 4.5; datasheet A.1: <= 70 ug/C).

    a_j' = a_S,j + b_j + kb_j (T - T_ref)          [m/s^2],  kb (m/s^2/K), T_ref = 298.15 K

Injected by the sensor model (:class:`imurig.sensors.accelerometer.QFlexTriad`, its
``bias_tempco_m_s2_per_K`` with the curvature terms: stage "sensor"); ``inject`` applies a kb of
its own to a signal (tests), the temperature from the context's truth signals (T_acc or T_imu).

Diagnosis (static positions): the first recorded temperature channel's per-position level, less
its mean (V; the Q-Flex's sensor gives 1 uA/K over 10 kohm = 10 mV/K; or K, degC as read), is the
column, offered only where the temperature moved by more than 0.2 K. The level is the clipped mean
of the position's samples (:func:`imurig.diagnose.tilt_table.level_statistic`): the bias follows
kb T(t), so a position's level holds kb times its mean temperature, which a median of readings on
a thermometer's 0.01 degC grid misses by up to half a step. Truth map: the readings
u_j = D_j (a_j + b_j + kb_j dT) (D the relative scale, without a scale tempco) invert to
f_j = u_j / D_j - b_j - kb_j dT exactly, dT = dV / (10 mV/K): the coefficient per volt is
-kb_j / (0.01 V/K), whatever D.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from imurig.kernel.units import T_REF_K
from imurig.sensors.effects._qflex import accelerometers, axis_index
from imurig.sensors.effects.base import Candidate, ChainContext, Effect, Param, PositionView

G = 9.80665  # m/s^2 per g, for the datasheet's ug/C only


@dataclass
class TemperatureDrift(Effect):
    """kb (3,) m/s^2/K about ``reference_temperature_K``."""

    bias_tempco_m_s2_per_K: np.ndarray = field(default_factory=lambda: np.zeros(3))
    reference_temperature_K: float = T_REF_K

    name: ClassVar[str] = "temperature_drift"
    stage: ClassVar[str] = "sensor"
    physics: ClassVar[str] = "the bias drifts with the sensor's temperature over the campaign"
    seed_section: ClassVar[str] = "4.5; A.1"
    seed_says: ClassVar[str] = ("temperature changes bias and scale ('the correction of the temperature influences "
                                "was done prior to the least-squares correction'); bias temperature sensitivity "
                                "+70 ug/C maximum")
    params: ClassVar[tuple] = (Param("drift", "m/s^2/V", datasheet=70e-6 * G,
                                     note="inverse-model coefficient of the temperature reading (10 mV/K), "
                                          "-kb / 0.01; datasheet bound on kb in m/s^2/K"),)
    views: ClassVar[tuple] = ("positions",)
    order: ClassVar[int] = 20

    #: the temperature channels the diagnosis looks for, in this order (the first recorded is used)
    channels: ClassVar[tuple] = ("temp_acc_x", "temp_acc_y", "temp_acc_z", "temp_box")
    #: the temperature sensors' nominal slope: 1 uA/K over 10 kohm (V/K)
    volts_per_K: ClassVar[float] = 0.01
    #: a drift is named only where the temperature moved more than this (K)
    min_span_K: ClassVar[float] = 0.2

    def __post_init__(self):
        self.bias_tempco_m_s2_per_K = np.broadcast_to(np.asarray(self.bias_tempco_m_s2_per_K, float), (3,)).copy()

    def inject(self, a: np.ndarray, ctx: ChainContext, rng=None) -> np.ndarray:
        """a + kb (T - T_ref) for a (n, 3) m/s^2, T (n,) K from ctx.truth_signals (T_acc or T_imu)."""
        ts = ctx.truth_signals
        T = np.asarray(ts["T_acc"] if "T_acc" in ts else ts["T_imu"], float)
        return np.asarray(a, float) + self.bias_tempco_m_s2_per_K * (T - self.reference_temperature_K)[:, None]

    def candidates(self, view: PositionView) -> list[Candidate]:
        volts = next((v for v in map(view.channel_median, self.channels) if v is not None), None)
        # a drift with temperature can only be named where the temperature moved (volts -> K)
        if volts is None or not np.ptp(volts) * 1e3 * 0.1 > self.min_span_K:
            return []
        return [Candidate(self.name, self.physics, ("drift",), lambda _, t=volts - np.mean(volts): t)]

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        """{drift: -kb_j / 0.01} (m/s^2 per volt of the temperature reading) on ``channel``."""
        kb = accelerometers(truth)["bias_tempco_m_s2_per_K"][axis_index(channel)]
        return {"drift": float(-kb / self.volts_per_K)}
