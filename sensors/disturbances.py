"""Lab disturbances of seed section 4.3.3 and the turn table's slip rings.

The pump, the people and the loose cable are effect objects of :mod:`imurig.sensors.effects`
(``building_vibration``, ``people_transients``, ``cable_fault_spikes``); they are re-exported
here under their class names for the campaigns that configure a lab.

:class:`SlipRingNoise` (seed Fig. 4.16) acts in the chain's analog stage on every line that
leaves the IMU while the table turns.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import ClassVar

import numpy as np

from imurig.sensors.effects.building_vibration import PumpVibration, working_mask
from imurig.sensors.effects.cable_fault_spikes import LooseCable
from imurig.sensors.effects.people_transients import PeopleTransients

__all__ = ["LooseCable", "PeopleTransients", "PumpVibration", "SlipRingNoise", "settings", "working_mask"]


def settings(obj) -> dict:
    return asdict(obj)


@dataclass
class SlipRingNoise:
    """Slip-ring contact noise on lines that cross the turn table's 16 rings (seed Fig. 4.16).

    v_noise(t) = rms * (1 + depth * p(theta(t))) * n(t),  n ~ N(0, 1) white   [V]
    p(theta) = sum over rough spots of exp(kappa (cos(theta - theta_s) - 1)): the noise
    rises whenever a brush passes a rough spot of its ring, so it is periodic in the
    table angle theta. The spots are drawn once per table (``rng`` of the rig).
    """

    enabled: bool = True
    rms_V: float = 20e-6
    depth: float = 8.0
    n_spots: int = 3
    kappa: float = 40.0
    spots_rad: tuple = (0.7, 2.9, 4.4)

    #: the chain's analog stage: every IMU line, one random stream per line ("slip_<line>")
    stage: ClassVar[str] = "analog"

    def profile(self, angle_rad: np.ndarray) -> np.ndarray:
        a = np.asarray(angle_rad)[:, None] - np.asarray(self.spots_rad)[None, :]
        return 1 + self.depth * np.exp(self.kappa * (np.cos(a) - 1)).sum(axis=1)

    def voltage(self, angle_rad: np.ndarray, rng) -> np.ndarray:
        if not self.enabled:
            return np.zeros_like(angle_rad)
        return self.rms_V * self.profile(angle_rad) * rng.standard_normal(angle_rad.shape)

    def lines(self, names, ctx) -> list[str]:
        """The IMU's lines (ctx.imu_lines) while the rig turns (a ``spin_angle`` truth signal);
        lines from the table itself do not cross a ring."""
        if not self.enabled or "spin_angle" not in ctx.truth_signals:
            return []
        return [n for n in names if n in ctx.imu_lines]

    def line_stream(self, line: str) -> str:
        return "slip_" + line

    def inject(self, v: np.ndarray, ctx, rng) -> np.ndarray:
        return v + self.voltage(ctx.truth_signals["spin_angle"], rng)
