"""Channel skew of a multiplexed converter (seed 4.3.4): slot j of the scan is converted j / f_mux
after the scan starts, i.e. after the sample's time tag.

    u_j <- u_j + (j / f_mux) du_j/dt                    [V]   (first order in the skew)

du_j/dt: the noise-free signal's slope (wideband noise is not differentiated: its samples stay
i.i.d.). Stage "conversion": :class:`imurig.sensors.adc.DAQ6036E` applies it to each slot before
the crosstalk.

Diagnosis: the tilt table's slews (candidate ``time_delay`` on acc_j, parameter tau_s: the delay
of the channel against its time tag) find tau_j = j / f_mux when the twin leaves the skew out.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from imurig.sensors.effects.base import Effect, Param, ScanSlot


@dataclass
class ChannelSkew(Effect):
    """The multiplexer's sampling-time skew (switch with ``enabled``)."""

    enabled: bool = True

    name: ClassVar[str] = "channel_skew"
    stage: ClassVar[str] = "conversion"
    physics: ClassVar[str] = ("the multiplexer converts the channels one after the other: slot j is sampled "
                              "j / f_mux after the time tag")
    seed_section: ClassVar[str] = "4.3.4"
    seed_says: ClassVar[str] = ("at 20 kHz 'the time between the first channel to be sampled and the last is "
                                "16 / 20000 Hz = 0.0008 s'")
    params: ClassVar[tuple] = (Param("tau_s", "s", seed=16 / 20e3, note="slot / f_mux; the seed's figure is the "
                                                                         "whole 16-slot scan"),)

    def delay_s(self, slot: ScanSlot) -> float:
        """j / f_mux (0 when off)."""
        return slot.index / slot.mux_frequency_hz if self.enabled else 0.0

    def inject(self, u: np.ndarray, slot: ScanSlot, rng=None) -> np.ndarray:
        if not self.enabled or slot.slope_V_s is None:
            return u
        return u + slot.slope_V_s * (slot.index / slot.mux_frequency_hz)

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        """{tau_s: j / f_mux} of ``channel``'s slot j in the recorded scan (0 with the skew off)."""
        adc = truth["chain"]["adc"]
        if not adc.get("skew_enabled", True):
            return {"tau_s": 0.0}
        return {"tau_s": list(adc["scan_list"]).index(channel) / float(adc["mux_frequency_hz"])}
