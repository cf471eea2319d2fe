"""Quantisation and input noise of the 16-bit converter (seed 2 and 4.3.4).

    code = round((u + e_adc) / q),  e_adc ~ N(0, (k_e q)^2),  q = 2 range / 2^bits     [V]

Per logged sample the error is white with variance

    var = (q^2 / 12 + (k_e q)^2) / n_avg                                           [V^2]

where n_avg conversions are averaged into one logged sample (1 without averaging). This is the
one place the project writes that variance: the Cramér-Rao bounds, the Monte-Carlo budgets and the
diagnosis' noise floor (never below q / sqrt(12)) ask :func:`variance_V2` or the effect.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from imurig.kernel.infer import adc_step
from imurig.sensors.effects.base import ChainContext, Effect, Param


def variance_V2(lsb_V: float, input_noise_lsb_rms: float = 0.0, averaging: int = 1) -> float:
    """Per-logged-sample variance (V^2) of a converter's rounding and input noise: (q^2/12 + (k_e q)^2) / n_avg."""
    q = float(lsb_V)
    return (q * q / 12.0 + (float(input_noise_lsb_rms) * q) ** 2) / max(int(averaging), 1)


def floor_V(lsb_V: float) -> float:
    """The smallest noise level a quantised channel can show: q / sqrt(12) (V)."""
    return float(lsb_V) / 12.0 ** 0.5


def estimate_step(values) -> float:
    """The ADC step q of a record (V), the greatest common step of its values
    (:func:`imurig.kernel.infer.adc_step`, the import's own estimate: one statistic for both), or
    0.0 when the values are not on a grid (already filtered or scaled, a float logger)."""
    x = np.asarray(values, float).ravel()
    q = adc_step(x[np.isfinite(x)])
    return float(q) if q else 0.0


def step_of(meta, channel: str | None, values=None, quantum=None) -> float:
    """The ADC step q (V) of ``channel``: the recording's ``channel_quantum`` (``quantum``), the
    import's ``meta["inferred"]["adc_step_V"]`` (a number or a {channel: q} mapping), the
    converter's ``meta["adc"]["lsb_V"]`` (or 2 range_V / 2^bits; over sqrt(averaging)), else estimated from ``values``
    (:func:`estimate_step`); 0.0 when none says."""
    meta = meta or {}
    if quantum and channel in quantum:
        return float(quantum[channel])
    inf = (meta.get("inferred") or {}).get("adc_step_V")
    if isinstance(inf, dict) and "value" in inf:   # the import's {value, evidence} record
        inf = inf["value"]
    if isinstance(inf, dict) and channel in inf:
        return float(inf[channel])
    if isinstance(inf, (int, float)) and inf > 0:
        return float(inf)
    adc = meta.get("adc") or {}
    # n_avg conversions averaged into one logged sample: the rounding error's spread is that of a
    # step q / sqrt(n_avg) (module doc); the values are then no longer on the grid
    n_avg = max(int(adc.get("averaging", 1) or 1), 1)
    if adc.get("lsb_V"):
        return float(adc["lsb_V"]) / n_avg ** 0.5
    if adc.get("range_V") and adc.get("bits"):
        return 2.0 * float(adc["range_V"]) / 2 ** int(adc["bits"]) / n_avg ** 0.5
    return estimate_step(values) if values is not None else 0.0


@dataclass
class AdcQuantisation(Effect):
    """The converter's rounding and input noise; the size is the converter's (``ctx.adc``)."""

    name: ClassVar[str] = "adc_quantisation"
    stage: ClassVar[str] = "conversion"
    physics: ClassVar[str] = "rounding to the converter's step q and the converter's own input noise"
    seed_section: ClassVar[str] = "2, 4.3.4"
    seed_says: ClassVar[str] = "a 16-bit converter (DAQ-6036E) digitises every analog line"
    params: ClassVar[tuple] = (Param("input_noise_lsb_rms", "LSB", datasheet=0.6),)

    def noise_variance(self, ctx: ChainContext) -> float:
        adc = ctx.adc
        return variance_V2(adc.lsb_V, adc.input_noise_lsb_rms, adc.averaging)
