"""A delay of the magnetometer's output against the rig's attitude (e.g. its output filter),
beyond the converter's known channel skew.

    V(t) = V_ideal(t - tau)                          [V],  tau (s)

Stage "rig" in the concealed cases: the field the sensor puts out at t is the field at t - tau,
so the case delays the rig's field truth B_C within each contiguous block through
:meth:`MagTimeDelay.inject` before the chain (the fluxgate is linear: delaying its input delays
its output, noise aside).

Diagnosis (:class:`MagView`): the column -A dB_ref/dt (stacked, nT/s), amplitude tau (s), the
first-order term of B(t - tau). Truth map: the case's delay (truth["magnetometer_diagnosis"]).
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from imurig.sensors.effects._fluxgate import case_truth
from imurig.sensors.effects.base import Candidate, ChainContext, Effect, Param
from imurig.sensors.effects.views import MagView


@dataclass
class MagTimeDelay(Effect):
    """Output delay ``delay_s`` (s)."""

    delay_s: float = 0.0

    name: ClassVar[str] = "mag_time_delay"
    order: ClassVar[int] = 218
    finding: ClassVar[str] = "time_delay"
    stage: ClassVar[str] = "rig"
    physics: ClassVar[str] = ("the magnetometer samples lag the rig's attitude (a delay against the set-points "
                              "beyond the DAQ's known channel skew, s)")
    seed_section: ClassVar[str] = "4.3.4"
    seed_says: ClassVar[str] = ("– (the twin knows the multiplexer's skew, 'the time between the first channel to "
                                "be sampled and the last is 16 / 20000 Hz = 0.0008 s'; a delay beyond it is not "
                                "discussed)")
    params: ClassVar[tuple] = (Param("tau_s", "s"),)
    views: ClassVar[tuple] = (MagView.kind,)

    def inject(self, x: np.ndarray, ctx: ChainContext, rng=None) -> np.ndarray:
        """x(t - tau) (n,) or (n, 3) on one contiguous block sampled at ctx.time_s (linear interpolation,
        the first sample held before the block's start)."""
        t = np.asarray(ctx.time_s, float)
        x = np.asarray(x, float)
        if x.ndim == 1:
            return np.interp(t - self.delay_s, t, x)
        return np.column_stack([np.interp(t - self.delay_s, t, x[:, j]) for j in range(x.shape[1])])

    def candidates(self, view) -> list[Candidate]:
        if not isinstance(view, MagView):
            return []
        dP = view.predicted_rate_nT_s()
        return [Candidate(self.finding_name(), self.physics, ("tau_s",), lambda _: -view.stacked(dP))]

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        return {"tau_s": float(case_truth(truth).get("delay_s", 0.0))}
