"""Thermal hysteresis of a sensor's bias (seed 4.5; Q-Flex datasheet A.1: <= 1000 ug over the
operating temperature): the heating and cooling branches of a thermal cycle differ.

    a_j' = a_S,j + ... + Hb_j h                       [m/s^2],  h in [-1/2, +1/2]

h: the play-operator state of :func:`imurig.sensors.thermal.hysteresis_state` of width w (K),
+1/2 after heating, -1/2 after cooling, held while the temperature stands still; Hb: the gap
between the branches. Stage "sensor": the accelerometer model
(:class:`imurig.sensors.accelerometer.QFlexTriad`, ``bias_hysteresis_m_s2``,
``hysteresis_width_K``) applies it with the state the chain computes (truth signal ``h_acc``);
``inject`` applies a gap of its own with that state (tests).

Diagnosis (:class:`ThermalView`, the step table of a thermal-chamber record against a
temperature polynomial without hysteresis): the column s = +1/2 on steps reached by heating,
-1/2 by cooling; its amplitude H is the gap in the six-position bias. Truth map, first order in
the small terms: the six-position mean of the readings u_j = D_j (1 + ks_j dT) a_j' (D_j the
relative scale K1_j / K1_nominal, ks_j the scale tempco) gives H = D_j (1 + ks_j dT) Hb_j, dT
the record's mean temperature less T_ref (truth["conditions"]["mean_temperature_K"], or dT = 0
where it is not given); the gyros have no hysteresis (H = 0). On the short thermal campaign it lies
within 1.5 % of the gap the noise-free twin of the same recording gives (the scale hysteresis, the
thermal curvature and the lags, left out here), which the concealed case uses as its truth.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from imurig.kernel.units import G_STANDARD, T_REF_K
from imurig.sensors.effects.base import Candidate, ChainContext, Effect, Param
from imurig.sensors.effects.views import ThermalView

#: the Q-Flex's nominal current scale factor, 1.33 mA/g (A per m/s^2)
K1_NOMINAL_A_PER_M_S2 = 1.33e-3 / G_STANDARD


@dataclass
class TemperatureHysteresis(Effect):
    """Bias gaps Hb (3,) m/s^2 between the branches, play width ``width_K`` (K)."""

    bias_hysteresis_m_s2: np.ndarray = field(default_factory=lambda: np.zeros(3))
    width_K: float = 4.0

    name: ClassVar[str] = "temperature_hysteresis"
    order: ClassVar[int] = 210
    stage: ClassVar[str] = "sensor"
    physics: ClassVar[str] = ("the bias depends on whether the temperature was reached by heating or by cooling "
                              "(hysteresis gap between the branches)")
    seed_section: ClassVar[str] = "4.5; A.1; paper (temperature cycles)"
    seed_says: ClassVar[str] = ("the cycle repetitions were done to detect the temperature dependent hysteresis of "
                                "the components; temperature hysteresis over the operating temperature +1000 ug "
                                "(maximum)")
    params: ClassVar[tuple] = (Param("H", "m/s^2", datasheet=1000e-6 * G_STANDARD,
                                     note="gap between the branches in the six-position bias (rad/s for gyros)"),
                               Param("width_K", "K", seed=4.0, note="play-operator width"))
    views: ClassVar[tuple] = (ThermalView.kind,)

    def __post_init__(self):
        self.bias_hysteresis_m_s2 = np.broadcast_to(np.asarray(self.bias_hysteresis_m_s2, float), (3,)).copy()

    def inject(self, a: np.ndarray, ctx: ChainContext, rng=None) -> np.ndarray:
        """a + Hb h for a (n, 3) m/s^2, h (n,) the play state from ctx.truth_signals["h_acc"]."""
        h = np.asarray(ctx.truth_signals["h_acc"], float)
        return np.asarray(a, float) + self.bias_hysteresis_m_s2 * h[:, None]

    def candidates(self, view) -> list[Candidate]:
        if not isinstance(view, ThermalView):
            return []
        return [Candidate(self.name, f"{view.channel}'s bias depends on whether the temperature was reached by "
                                     f"heating or by cooling (hysteresis gap between the branches, {view.unit})",
                          ("H",), lambda _, c=np.asarray(view.branch, float): c)]

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        """{H: D_j (1 + ks_j dT) Hb_j} on accelerometer ``channel`` ("acc_x" ...), 0 on a gyro (module doc)."""
        if not channel.startswith("acc"):
            return {"H": 0.0}
        acc = truth["sensors"]["accelerometers"]
        j = "xyz".index(channel[-1])
        T = (truth.get("conditions") or {}).get("mean_temperature_K")
        dT = 0.0 if T is None else float(T) - float(acc.get("reference_temperature_K", T_REF_K))
        D = float(acc["k1_A_per_m_s2"][j]) / K1_NOMINAL_A_PER_M_S2
        return {"H": D * (1.0 + float(acc["scale_tempco_per_K"][j]) * dT) * float(acc["bias_hysteresis_m_s2"][j])}
