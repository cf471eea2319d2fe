"""A table-rate error proportional to the rate (a scale error of the dial).

    Omega = dial (1 + c dial)                  [deg/s],  c (1/(deg/s))

No rig injects it (the virtual C181's dial has a per-step setting error and the slip only);
``inject`` applies it to a rate (tests). Diagnosis (:class:`RateShortfallView`): the measured
rate r (deg/s) is the column of the relative shortfall d, amplitude c. Truth map: no rig injects
it, so every recording's truth is c = 0 (a finding on a virtual record is a false one).
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from imurig.sensors.effects.base import Candidate, Effect, Param
from imurig.sensors.effects.views import RateShortfallView


@dataclass
class RateProportionalError(Effect):
    """Relative rate error c per deg/s of rate."""

    c_per_dps: float = 0.0

    name: ClassVar[str] = "rate_proportional_error"
    order: ClassVar[int] = 205
    stage: ClassVar[str] = "rig"
    physics: ClassVar[str] = "a rate error proportional to the rate (scale of the dial)"
    seed_section: ClassVar[str] = "4.4.2, appendix B"
    seed_says: ClassVar[str] = "– (the seed reads the rate off the dial x 5/6; a dial scale error is not discussed)"
    params: ClassVar[tuple] = (Param("c", "1/(deg/s)", note="coefficient of the rate in d"),)
    views: ClassVar[tuple] = (RateShortfallView.kind,)

    def inject(self, rate_dps: np.ndarray, ctx=None, rng=None) -> np.ndarray:
        r = np.asarray(rate_dps, float)
        return r * (1 + self.c_per_dps * r)

    def candidates(self, view) -> list[Candidate]:
        if not isinstance(view, RateShortfallView):
            return []
        r = np.asarray(view.rate_dps, float)
        return [Candidate(self.name, self.physics, ("c",), lambda _: r)]

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        """{c: 0}: no rig injects a dial scale error (module doc)."""
        return {"c": 0.0}
