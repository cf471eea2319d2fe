"""Lever arm: the triad senses off the case's reference point, where the rig gives f_C (seed 4.3.1).

    f_C(r) = f_C + dw/dt x r_C + w x (w x r_C)          [m/s^2, (n, 3)]

r_C (m, case frame C): where the triad senses relative to the reference point (the rig's 'imu'
site); w = w_C (rad/s), dw/dt by central differences. Stage "specific_force": the chain adds it
to the accelerometers' specific force (not to the gyros'), r_C being the triad's
``position_C_m`` (:class:`imurig.sensors.accelerometer.QFlexTriad`).

Diagnosis: the tilt table's slews (:func:`imurig.diagnose.tilt_table.diagnose_tilt_dynamics`,
candidate ``lever_arm``, parameters dr_x_m, dr_y_m, dr_z_m: the offset from where the twin puts
the triad, i.e. r_C itself for a twin at the reference point).
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from imurig.sensors.effects.base import ChainContext, Effect, Param


def lever_arm_specific_force(w_C: np.ndarray, time_s: np.ndarray, r_C) -> np.ndarray:
    """Specific force added at r_C (m, (3,) or (n,3), case frame C) by the case's rotation:
    dw/dt x r_C + w_C x (w_C x r_C) [m/s^2, (n,3)]; w_C (n,3) rad/s, dw/dt by central
    differences on ``time_s`` (n,) s."""
    w = np.asarray(w_C, float)
    r = np.broadcast_to(np.asarray(r_C, float), w.shape)
    a = np.gradient(w, np.asarray(time_s, float), axis=0)
    return np.cross(a, r) + np.cross(w, np.cross(w, r))


@dataclass
class LeverArm(Effect):
    """The triad's offset r_C (3,) m from the case reference point."""

    position_C_m: np.ndarray = field(default_factory=lambda: np.zeros(3))

    name: ClassVar[str] = "lever_arm"
    stage: ClassVar[str] = "specific_force"
    physics: ClassVar[str] = ("the accelerometers sense off the point the rig's specific force is given for: the "
                              "rotation adds tangential and centripetal accelerations")
    seed_section: ClassVar[str] = "4.3.1"
    seed_says: ClassVar[str] = ("the table is used at rest ('only the gravity vector ... is effective on the IMU'); "
                                "its slews between positions add the lever arm's accelerations, not examined there")
    params: ClassVar[tuple] = tuple(Param(f"dr_{a}_m", "m", note="offset of the triad from the reference point, "
                                                                 "case frame") for a in "xyz")

    def __post_init__(self):
        self.position_C_m = np.broadcast_to(np.asarray(self.position_C_m, float), (3,)).copy()

    @property
    def active(self) -> bool:
        return bool(np.any(self.position_C_m))

    def inject(self, f_C: np.ndarray, ctx: ChainContext, rng=None) -> np.ndarray:
        """f_C (n, 3) plus the kinematic terms, w_C from ctx.truth_signals (w_C_x ...); unchanged
        at r = 0 or where the rig gives no rate."""
        ts = ctx.truth_signals
        if not self.active or "w_C_x" not in ts:
            return f_C
        w_C = np.stack([ts[f"w_C_{a}"] for a in "xyz"], axis=1)
        return f_C + lever_arm_specific_force(w_C, ctx.time_s, self.position_C_m)

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        """{dr_x_m, dr_y_m, dr_z_m}: the triad's recorded ``position_C_m``."""
        r = truth["sensors"]["accelerometers"]["position_C_m"]
        return {f"dr_{a}_m": float(r[j]) for j, a in enumerate("xyz")}
