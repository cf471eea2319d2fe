"""Rate-dependent slip of the turn table's ball-and-disc integrator (seed appendix B).

    Omega = dial_eff (1 - s(dial_eff)),  s = s0 + s1 (dial_eff / 1 deg/s)^-alpha          [deg/s]

dial_eff = |dial| f_mains / f_motor (deg/s). The measured round times of appendix B exceed
360 / (5/6 dial) by 1-8 %, most at low rates. Stage "rig": the table model
(:class:`imurig.rigs.turn_table.TurnTableErrors`, ``slip_const``, ``slip_coeff``, ``slip_exp``)
applies :meth:`TableSlip.shortfall`.

Diagnosis (:class:`RateShortfallView`): the relative shortfall d = measured rate / (factor x
dial) - 1 with a constant as the nominal model; the column r^-alpha of the measured rate r
(deg/s), alpha scanned 0.2 ... 2.0. Truth map, first order in s: d = -s0 - s1 r^-alpha (1 +
O(alpha s)), so the fitted s1 is -s1 at alpha = slip_exp.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from imurig.sensors.effects._turn_table import table_errors
from imurig.sensors.effects.base import Candidate, Effect, Param
from imurig.sensors.effects.views import RateShortfallView


@dataclass
class TableSlip(Effect):
    """Slip s0 + s1 dial_eff^-alpha (dial_eff in deg/s)."""

    slip_const: float = 0.012
    slip_coeff: float = 0.03
    slip_exp: float = 0.7

    name: ClassVar[str] = "table_slip"
    order: ClassVar[int] = 204
    stage: ClassVar[str] = "rig"
    physics: ClassVar[str] = ("rate-dependent slip of the ball-and-disc integrator: the table turns slower than "
                              "set, most at low rates")
    seed_section: ClassVar[str] = "appendix B"
    seed_says: ClassVar[str] = "measured round times exceed 360/(5/6 dial) by 1-8 % (not explained in the text)"
    params: ClassVar[tuple] = (Param("s1", "1", seed=0.03, note="fitted: coefficient of r^-alpha in d (-s1)"),
                               Param("alpha", "1", seed=0.7, note="scanned 0.2 ... 2.0"),
                               Param("s0", "1", seed=0.012, note="constant slip: absorbed by the nominal constant"))
    views: ClassVar[tuple] = (RateShortfallView.kind,)
    #: the scan of the exponent alpha
    alphas: ClassVar[tuple] = tuple(np.round(np.arange(0.2, 2.01, 0.1), 2))

    def shortfall(self, dial_eff_dps) -> np.ndarray:
        """s(dial_eff) = s0 + s1 |dial_eff|^-alpha (dial_eff in deg/s)."""
        return self.slip_const + self.slip_coeff * np.abs(np.asarray(dial_eff_dps, float)) ** (-self.slip_exp)

    def inject(self, rate_dps: np.ndarray, ctx=None, rng=None) -> np.ndarray:
        """The table rate (deg/s) for the mains-corrected dial rate ``rate_dps``: rate (1 - s(rate))."""
        r = np.asarray(rate_dps, float)
        return r * (1 - self.shortfall(r))

    def candidates(self, view) -> list[Candidate]:
        if not isinstance(view, RateShortfallView):
            return []
        r = np.asarray(view.rate_dps, float)
        return [Candidate(self.name, self.physics, ("s1",), lambda a: r ** (-a), scan=self.alphas, scan_name="alpha")]

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        """{s1: -slip_coeff, alpha: slip_exp} of the recorded table (first order in the slip)."""
        e = table_errors(truth)
        return {"s1": -float(e["slip_coeff"]), "alpha": float(e["slip_exp"])}
