"""Turn-on bias of an inertial sensor (Q-Flex datasheet A.1, fibre-optic gyro A.2; seed 4.3.5).

    y_i = x_i + b_i                 [the sensor's SI unit: m/s^2 or rad/s], b constant per run

Injected by the sensor models (``bias_m_s2`` of the Q-Flex triad, ``bias_rad_s`` of the gyro
triad: stage "sensor"); ``inject`` applies a b of its own to a signal (tests). The filter carries
it as the states ``acc.bias.b_x`` ... and ``gyro.bias.b_x`` ... (:mod:`imurig.sensors.error_states`),
the tilt calibration as its bias terms.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from imurig.sensors.effects.base import Effect, Param

AXES = ("x", "y", "z")


@dataclass
class Bias(Effect):
    """Constant bias (3,) of a triad, in the sensor's SI unit."""

    bias: np.ndarray = field(default_factory=lambda: np.zeros(3))

    name: ClassVar[str] = "bias"
    stage: ClassVar[str] = "sensor"
    physics: ClassVar[str] = "a constant offset of each sensor's output (turn-on bias)"
    seed_section: ClassVar[str] = "4.3.5; A.1, A.2"
    seed_says: ClassVar[str] = ("the Q-Flex bias is below 4 mg and the gyro's bias repeatability is 0.003 deg/s "
                                "(datasheets)")
    params: ClassVar[tuple] = tuple(Param(f"b_{a}", "m/s^2 or rad/s", note="the sensor's SI unit") for a in AXES)
    order: ClassVar[int] = 1

    def __post_init__(self):
        self.bias = np.broadcast_to(np.asarray(self.bias, float), (3,)).copy()

    def inject(self, x: np.ndarray, ctx=None, rng=None) -> np.ndarray:
        """x (n, 3) + b."""
        return np.asarray(x, float) + self.bias

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        """{b_<axis>: b} of ``channel`` ('acc_x', 'gyro_y' ...) from the sensor's truth."""
        sensor, axis = channel.split("_")
        key = "gyros" if sensor == "gyro" else "accelerometers"
        unit = "bias_rad_s" if sensor == "gyro" else "bias_m_s2"
        i = {"x": 0, "y": 1, "z": 2, "p": 0, "q": 1, "r": 2}[axis]
        return {f"b_{AXES[i]}": float(truth["sensors"][key][unit][i])}
