"""ADC multiplexer crosstalk (seed 4.3.4, Table 4.3): the amplifier has not settled from the
previously scanned channel when the next one is sampled.

    u_j <- u_j + c (u_{j-1} - u_j),   c = exp(-1 / (f_mux tau))          [V]

u_j: slot j's input, u_{j-1}: the previously converted slot's input, f_mux: the multiplexing
frequency, tau: the settling time constant of the converter's input amplifier.

Diagnosis (static positions): the leak is linear in the previous channel's voltage, so its
per-position median is the regression column. In the inverse model f = V / (s G) its coefficient
is -c / (s (1 - c)) m/s^2 per volt, s the channel's true sensitivity (V per m/s^2).

Where the scan order is unknown (a lab CSV without ``adc.scan_list``), the source is a scanned
parameter: each candidate source channel k's per-position median is tried as the column, and the
engine's max-statistic threshold takes the largest statistic over all sources, so choosing the
source costs its multiple comparison.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from imurig.sensors.effects.base import Candidate, Effect, Param, PositionView, ScanSlot


@dataclass
class AdcCrosstalk(Effect):
    """Settling crosstalk of a multiplexed converter (``settling_tau_s`` in s)."""

    settling_tau_s: float = 0.59e-6
    enabled: bool = True

    name: ClassVar[str] = "adc_crosstalk"
    stage: ClassVar[str] = "conversion"
    physics: ClassVar[str] = ("ADC multiplexer crosstalk: the previously scanned channel leaks into the next one "
                              "(the amplifier's settling is too short for the multiplexing frequency)")
    seed_section: ClassVar[str] = "4.3.4, Table 4.3"
    seed_says: ClassVar[str] = ("coupling of an ADC channel to the next one; a lower multiplexing frequency "
                                "cured it")
    params: ClassVar[tuple] = (Param("settling_tau_s", "s", note="c = exp(-1/(f_mux tau)); fitted as c"),
                               Param("c", "m/s^2/V", note="inverse-model coefficient on the previous channel, "
                                                          "-c/(s (1 - c)): negative for a positive leak c (V/V)"))
    views: ClassVar[tuple] = ("positions",)
    order: ClassVar[int] = 10

    def coefficient(self, mux_frequency_hz: float) -> float:
        """c = exp(-1 / (f_mux tau)): the fraction of the previous slot's difference left (0 when off)."""
        if not self.enabled or self.settling_tau_s <= 0:
            return 0.0
        return math.exp(-1.0 / (mux_frequency_hz * self.settling_tau_s))

    def inject(self, u: np.ndarray, slot: ScanSlot, rng: np.random.Generator | None = None) -> np.ndarray:
        c = self.coefficient(slot.mux_frequency_hz)
        if c == 0.0 or slot.previous_V is None:
            return u
        return u + c * (slot.previous_V - u)

    @staticmethod
    def previous_channel(scan_list, channel: str) -> str | None:
        """The channel converted just before ``channel`` (the scan wraps round), or None if not scanned."""
        scan = list(scan_list)
        if channel not in scan:
            return None
        return scan[scan.index(channel) - 1]

    def candidates(self, view: PositionView) -> list[Candidate]:
        if view.crosstalk_sources:
            return self._scanned_source(view)
        prev = self.previous_channel(view.scan_list, view.channel)
        pv = view.channel_median(prev) if prev is not None else None
        if pv is None:
            return []
        return [Candidate(self.name, f"ADC multiplexer crosstalk: the previously scanned channel '{prev}' leaks "
                                     f"into '{view.channel}' (settling too short for the mux frequency)",
                          ("c",), lambda _, pv=pv: pv)]

    def _scanned_source(self, view: PositionView) -> list[Candidate]:
        """One candidate whose scanned parameter is the source channel (scan order unknown)."""
        cols = {k: view.channel_median(k) for k in view.crosstalk_sources if k != view.channel}
        cols = {k: np.asarray(v, float) for k, v in cols.items() if v is not None}
        if not cols:
            return []
        return [Candidate(self.name, f"ADC multiplexer crosstalk: a logged channel leaks into '{view.channel}' (the "
                                     f"scan order is unknown: the source is chosen among {len(cols)} channels)",
                          ("c",), lambda k, cols=cols: cols[k], scan=tuple(cols), scan_name="source_channel")]

    def fitted(self, truth, channel: str | None = None) -> dict[str, float]:
        """-c / (s (1 - c)) on accelerometer ``channel`` ("acc_x" ...), c from the recorded converter (the
        channel's own where its line settles with its own tau)."""
        adc = truth["chain"]["adc"]
        c = float((adc.get("crosstalk_coefficients") or {}).get(channel, adc["crosstalk_coefficient"]))
        j = "xyz".index(channel[-1])
        s = float(truth["sensors"]["accelerometers"]["sensitivity_V_per_m_s2"][j])
        return {"c": -c / (s * (1.0 - c))}
