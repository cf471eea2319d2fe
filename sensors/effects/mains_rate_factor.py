"""Mains-frequency rate factor of the turn table's synchronous motor (seed 4.4.1).

    Omega = dial (f_mains / f_motor)                                    [rad/s]

The Genisco C181's motor is built for 60 Hz; on Europe's 50 Hz mains the table turns at 5/6 of
the dial. Stage "rig": the table model (:class:`imurig.rigs.turn_table.TurnTableErrors`, its
``mains_hz`` and ``motor_design_hz``) applies :meth:`MainsRateFactor.factor`.

Diagnosis (appendix-B rows): the mean ratio of the stopwatch rate to the dial, named by the
motor/mains pair it matches when it lies more than 5 standard errors from 1 (a test of the rate
rows, not a regression column). Truth map: f_mains / f_motor of the recorded table.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from imurig.sensors.effects._turn_table import table_errors
from imurig.sensors.effects.base import Effect, Param

#: motor/mains pairs and the factor each gives (the diagnosis names the nearest)
MOTOR_MAINS = {"60 Hz motor on 50 Hz mains": 50 / 60, "50 Hz motor on 60 Hz mains": 60 / 50,
               "motor on its design mains": 1.0}


@dataclass
class MainsRateFactor(Effect):
    """A synchronous motor built for ``motor_design_hz`` on ``mains_hz`` mains."""

    mains_hz: float = 50.0
    motor_design_hz: float = 60.0

    name: ClassVar[str] = "mains_rate_factor"
    order: ClassVar[int] = 203
    stage: ClassVar[str] = "rig"
    physics: ClassVar[str] = "synchronous table motor: the table turns at f_mains / f_motor of the dial"
    seed_section: ClassVar[str] = "4.4.1"
    seed_says: ClassVar[str] = "the 60 Hz synchronous motor runs on 50 Hz mains: multiply the readings by 5/6"
    params: ClassVar[tuple] = (Param("factor", "1", seed=5 / 6, note="f_mains / f_motor"),)

    @property
    def factor(self) -> float:
        return self.mains_hz / self.motor_design_hz

    def inject(self, rate: np.ndarray, ctx=None, rng=None) -> np.ndarray:
        """The table rate for the dial rate ``rate`` (any unit): rate x f_mains / f_motor."""
        return np.asarray(rate, float) * self.factor

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        e = table_errors(truth)
        return {"factor": float(e["mains_hz"]) / float(e["motor_design_hz"])}
