"""The Earth's rotation left out of a turn-table twin (seed 4.4.2).

    w_ref,j = e_j (Omega_table + Omega_E sin(latitude))                     [rad/s]

e_j = +1 / -1 while gyro j lies up / down the table's (vertical) spin axis, 0 otherwise;
Omega_E = 7.292115e-5 rad/s (WGS-84). Stage "rig": the Earth's rotation is physics, not an
error; the turn table's rig adds Omega_E, expressed in the IMU case frame, to its rate truth
(:class:`imurig.rigs.turn_table.TurnTable`). The effect is the twin's omission of it.

Diagnosis (:class:`TurnView`, only for a twin without the Earth's rate): the column -e_j, its
amplitude the vertical Earth rate Omega_vertical = Omega_E sin(latitude) (rad/s). Truth map:
Omega_E sin(latitude) at the rig's site (the recording's meta "site", through ``recording_truth``).
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from imurig.kernel.site import EARTH_RATE_RAD_S
from imurig.sensors.effects.base import Candidate, Effect, Param
from imurig.sensors.effects.views import TurnView


@dataclass
class EarthRateLeftOut(Effect):
    """The site's latitude (rad) fixes the vertical Earth rate the twin leaves out."""

    latitude_rad: float = math.radians(52.0)

    name: ClassVar[str] = "earth_rate_left_out"
    order: ClassVar[int] = 200
    stage: ClassVar[str] = "rig"
    physics: ClassVar[str] = ("the Earth's rotation: the gyro on the table axis also senses the Earth's vertical "
                              "rate Omega_E sin(latitude), which the twin's reference leaves out (rad/s)")
    seed_section: ClassVar[str] = "4.4.2"
    seed_says: ClassVar[str] = "the Earth's rate (15 deg/h) adds to the table rate along the vertical axis"
    params: ClassVar[tuple] = (Param("Omega_vertical", "rad/s", seed=EARTH_RATE_RAD_S * math.sin(math.radians(52.0)),
                                     note="Omega_E sin(latitude); Delft 52 deg N"),)
    views: ClassVar[tuple] = (TurnView.kind,)

    def vertical_rate_rad_s(self) -> float:
        """Omega_E sin(latitude) (rad/s)."""
        return EARTH_RATE_RAD_S * math.sin(self.latitude_rad)

    def inject(self, w_ref: np.ndarray, ctx: TurnView, rng=None) -> np.ndarray:
        """The reference rate of a twin that includes the Earth: w_ref + e_j Omega_vertical (rad/s)."""
        return np.asarray(w_ref, float) + self.vertical_rate_rad_s() * np.asarray(ctx.on_axis, float)

    def candidates(self, view) -> list[Candidate]:
        if not isinstance(view, TurnView) or view.earth_rate_in_twin:
            return []
        return [Candidate(self.name, self.physics, ("Omega_vertical",), lambda _, c=-np.asarray(view.on_axis): c)]

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        """{Omega_vertical: Omega_E sin(latitude)} at the site of the recorded rig (the truth of
        :func:`recording_truth`: the site is the recording's, not a secret of the truth)."""
        lat = float(truth["conditions"]["site"]["latitude_deg"])
        return {"Omega_vertical": EARTH_RATE_RAD_S * math.sin(math.radians(lat))}
