"""A slow tail in one channel's settling in the multiplexed scan (seed 4.3.4, Table 4.3): a small part
``alpha`` of a step settles with a long time constant ``tau_s``, so the sample remembers the slots
before the previous one, through a grounded slot too.

A linear settling with the step remainder s(t) = (1 - alpha) e^(-t / tau_f) + alpha e^(-t / tau_s)
samples slot j (slot time T = 1 / f_mux) as u_j + sum_k (u_(j-k) - u_(j-k+1)) s(k T). The fast part is
:mod:`imurig.sensors.effects.adc_crosstalk` (one slot back); the tail's part, with y = e^(-T / tau_s), is

    u_j <- u_j + alpha y (r_j - u_j),   r_j = (1 - y) sum_(k=1..j) y^(k-1) u_(j-k) + y^j u_idle     [V]

r_j: the slots converted before j in this scan (a grounded slot's u = 0 V) weighted by the tail's
decay, and the idle input the multiplexer rests on between scans (the previous scan's last slot; the
idle time, ~1 ms, settles the tail fully). The leak of the slot just before j is alpha y (1 - y), of
the data slot before a grounded slot alpha y^2 (1 - y): the grounded slot cures the fast part, not the
tail. The -alpha y u_j term is a scale factor.

Where it comes from (a model, not named by the seed): the seed's y line (the one with the faulty
junction box) coupled to the previously converted channel, and a grounded slot between "did not lead
to a significant improvement" (Tab. 4.3: 0.00622 -> 0.00407 m/s^2), while 50 kHz cured it; a settling
that is a single exponential cannot do both (:func:`imurig.montecarlo.delft_fit.grounded_slot_bound`).
Fitted to Tab. 4.3 as the y line's (:mod:`imurig.montecarlo.delft_fit`). No diagnosis view.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from imurig.sensors.effects.base import Effect, Param, ScanSlot


@dataclass
class AdcSlowSettling(Effect):
    """The slow tail of one channel's settling (``alpha`` of a step, ``tau_s`` in s)."""

    alpha: float = 0.0
    tau_s: float = 0.0
    enabled: bool = True

    name: ClassVar[str] = "adc_slow_settling"
    stage: ClassVar[str] = "conversion"
    physics: ClassVar[str] = ("a slow tail of a channel's settling in the multiplexed scan: the sample remembers the "
                              "slots before the previous one, through a grounded slot too")
    seed_section: ClassVar[str] = "4.3.4, Table 4.3"
    seed_says: ClassVar[str] = ("the y channel's coupling to the previous ADC channel; 'the hopping to a ground "
                                "channel did not lead to a significant improvement' (0.00622 -> 0.00407 m/s^2) "
                                "while a lower multiplexing frequency 'gives the multiplexer enough time to recover'")
    params: ClassVar[tuple] = (Param("alpha", "-", note="the tail's share of a step"),
                               Param("tau_s", "s", note="the tail's time constant"))
    views: ClassVar[tuple] = ()

    def decay(self, mux_frequency_hz: float) -> float:
        """y = e^(-1 / (f_mux tau_s)): the tail left after one slot (0 when off)."""
        if not self.enabled or self.alpha <= 0 or self.tau_s <= 0:
            return 0.0
        return math.exp(-1.0 / (mux_frequency_hz * self.tau_s))

    def weights(self, n_before: int, mux_frequency_hz: float) -> tuple[np.ndarray, float]:
        """((1 - y) y^(k-1) for k = 1..n_before, y^n_before): the weights of the slots before j (nearest
        first) and of the idle input in r_j."""
        y = self.decay(mux_frequency_hz)
        k = np.arange(1, n_before + 1)
        return (1 - y) * y ** (k - 1), y ** n_before

    def reservoir(self, before: list[np.ndarray | None], idle: np.ndarray, mux_frequency_hz: float) -> np.ndarray:
        """r_j (n,) V from the inputs of the slots before j in this scan (nearest first; None for a grounded
        slot) and the idle input (module doc)."""
        w, w_idle = self.weights(len(before), mux_frequency_hz)
        r = w_idle * np.asarray(idle, float)
        for wk, u in zip(w, before):
            if u is not None:
                r = r + wk * u
        return r

    def inject(self, u: np.ndarray, slot: ScanSlot, rng: np.random.Generator | None = None) -> np.ndarray:
        """u + alpha y (r - u), with r in ``slot.previous_V`` (:meth:`reservoir`)."""
        y = self.decay(slot.mux_frequency_hz)
        if y == 0.0 or slot.previous_V is None:
            return u
        return u + self.alpha * y * (slot.previous_V - u)
