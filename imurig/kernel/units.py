"""Units at the boundary.

Inside the bench every number is SI. Datasheet and lab units appear only in
constructors and in the CSV lab format, where a column header carries its unit
as a suffix (``theta_deg``, ``acc_x_V``, ``temp_box_degC``). This module parses
those suffixes and converts to and from SI.

SI unit names used inside: ``V``, ``A``, ``rad``, ``rad/s``, ``m/s^2``, ``T``,
``K``, ``s``, ``m``, ``Hz``, ``ohm``, ``1`` (dimensionless or counts).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from imurig.kernel.errors import RecordingError

G_STANDARD = 9.80665  # m/s^2, used only to convert datasheet 'g' figures
ARCMIN = math.pi / (180 * 60)  # rad
ARCSEC = ARCMIN / 60  # rad
DEG = math.pi / 180  # rad
MICRO_G = 1e-6 * G_STANDARD  # m/s^2
#: K, the reference temperature of the sensor models and of the thermal fits (25 C, the Q-Flex
#: datasheet's: its temperature sensor gives 298.2 uA there); dT = T - T_REF_K everywhere
T_REF_K = 298.15


@dataclass(frozen=True)
class UnitSpec:
    """Conversion of a lab unit to SI: ``si = scale * value + offset``."""

    suffix: str
    si: str
    scale: float
    offset: float = 0.0


_UNITS = [
    UnitSpec("V", "V", 1.0),
    UnitSpec("mV", "V", 1e-3),
    UnitSpec("uV", "V", 1e-6),
    UnitSpec("A", "A", 1.0),
    UnitSpec("mA", "A", 1e-3),
    UnitSpec("uA", "A", 1e-6),
    UnitSpec("rad", "rad", 1.0),
    UnitSpec("deg", "rad", DEG),
    UnitSpec("arcmin", "rad", ARCMIN),
    UnitSpec("arcsec", "rad", ARCSEC),
    UnitSpec("rad_s", "rad/s", 1.0),
    UnitSpec("deg_s", "rad/s", DEG),
    UnitSpec("dps", "rad/s", DEG),
    UnitSpec("m_s2", "m/s^2", 1.0),
    UnitSpec("T", "T", 1.0),
    UnitSpec("uT", "T", 1e-6),
    UnitSpec("nT", "T", 1e-9),
    UnitSpec("K", "K", 1.0),
    UnitSpec("degC", "K", 1.0, 273.15),
    UnitSpec("s", "s", 1.0),
    UnitSpec("ms", "s", 1e-3),
    UnitSpec("us", "s", 1e-6),
    UnitSpec("m", "m", 1.0),
    UnitSpec("Hz", "Hz", 1.0),
    UnitSpec("ohm", "ohm", 1.0),
    UnitSpec("count", "1", 1.0),
    UnitSpec("1", "1", 1.0),
]
UNITS: dict[str, UnitSpec] = {u.suffix: u for u in _UNITS}
SI_UNITS = sorted({u.si for u in _UNITS})

# Preferred lab unit for writing each SI unit back to CSV.
LAB_SUFFIX = {"V": "V", "A": "uA", "rad": "deg", "rad/s": "dps", "m/s^2": "m_s2", "T": "nT",
              "K": "degC", "s": "s", "m": "m", "Hz": "Hz", "ohm": "ohm", "1": "count"}

_BY_LENGTH = sorted(UNITS, key=len, reverse=True)


def split_column(header: str) -> tuple[str, UnitSpec]:
    """Split a CSV header ``name_unit`` into ``(name, UnitSpec)``.

    The longest known unit suffix wins, so ``acc_m_s2`` is ``acc`` in m/s^2.
    Raises RecordingError naming the column and the known units otherwise.
    """
    h = header.strip()
    for suf in _BY_LENGTH:
        if h.endswith("_" + suf) and len(h) > len(suf) + 1:
            return h[: -len(suf) - 1], UNITS[suf]
    raise RecordingError(
        f"column '{h}' does not end in a known unit suffix. Name columns <name>_<unit>, "
        f"e.g. 'acc_x_V' or 'theta_deg'; known units: {', '.join(sorted(UNITS))}")


def to_si(values, spec: UnitSpec):
    """Convert lab values (array or float) to SI."""
    return values * spec.scale + spec.offset if (spec.scale != 1.0 or spec.offset) else values


def from_si(values, si_unit: str):
    """Convert SI values to the preferred lab unit; returns ``(values, suffix)``."""
    suf = LAB_SUFFIX.get(si_unit)
    if suf is None:
        raise RecordingError(f"no lab unit known for SI unit '{si_unit}'")
    spec = UNITS[suf]
    if spec.scale == 1.0 and spec.offset == 0.0:
        return values, suf
    return (values - spec.offset) / spec.scale, suf
