"""The sensor-error states, named once for the simulation, the filter and the truth.

Each block of the navigation filter's error state (:mod:`imurig.flights.filter_config`) is one
parameter of one effect of the library, carried per axis. Its state names are

    <sensor>.<effect>.<parameter>_<axis>          e.g. acc.bias.b_x, gyro.axis_misalignment.M_yz,
                                                  acc.scale_nonlinearity.k2_z, mag.hard_iron.b_y

with <effect> the library effect's ``name`` (:mod:`imurig.sensors.effects`), and the block's
``truth`` reads the same parameter from the sensor model's ``truth()`` dict (SI), so an estimate
and its truth are compared by name. Blocks with no effect object (the temperature sensor's
error, the receiver's correlated position error, the compass's lumped heading error) name their
source instead.
"""
from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from imurig.sensors.effects import (AxisMisalignment, Bias, GyroNoise, HardIron, ScaleFactor, ScaleNonlinearity,
                                    SoftIron, TemperatureDrift, TemperatureHysteresis)
from imurig.sensors.effects.temperature_hysteresis import K1_NOMINAL_A_PER_M_S2

XYZ = ("x", "y", "z")
#: (i, j): input j sensed by axis i, the six off-diagonal misalignments in the filter's order
MIS_PAIRS = ((0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1))


@dataclass(frozen=True)
class StateBlock:
    """One block of sensor-error states: ``sensor`` ("acc", "gyro", "mag", "gps"), ``source`` (the
    library effect's name, or the source's), ``param`` and its per-state suffixes, the SI unit,
    and ``truth(sensor_truth) -> (k,)`` the true values from the sensor model's ``truth()``."""

    sensor: str
    source: str
    param: str
    suffixes: tuple[str, ...]
    unit: str
    truth: Callable[[Mapping], np.ndarray] | None = None

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(f"{self.sensor}.{self.source}.{self.param}_{s}" for s in self.suffixes)


def _key(key: str) -> Callable[[Mapping], np.ndarray]:
    return lambda t: np.asarray(t[key], float).reshape(-1)


def _pairs(key: str) -> Callable[[Mapping], np.ndarray]:
    return lambda t: np.array([np.asarray(t[key], float)[i, j] for i, j in MIS_PAIRS])


def _scale(key: str, nominal: Callable[[Mapping], np.ndarray]) -> Callable[[Mapping], np.ndarray]:
    return lambda t: np.asarray(t[key], float) / nominal(t) - 1.0


_PAIR_SUFFIX = tuple(f"{XYZ[i]}{XYZ[j]}" for i, j in MIS_PAIRS)
_ACC_NOMINAL = lambda t: K1_NOMINAL_A_PER_M_S2 * np.asarray(t["load_resistor_ohm"], float)  # noqa: E731
_GYRO_NOMINAL = lambda t: np.full(3, float(t["nominal_scale_V_per_rad_s"]))  # noqa: E731

ACC_BIAS = StateBlock("acc", Bias.name, "b", XYZ, "m/s^2", _key("bias_m_s2"))
GYRO_BIAS = StateBlock("gyro", Bias.name, "b", XYZ, "rad/s", _key("bias_rad_s"))
ACC_TEMPERATURE = StateBlock("acc", "temperature_sensor", "dT", XYZ, "K")
ACC_SCALE = StateBlock("acc", ScaleFactor.name, "s", XYZ, "1", _scale("sensitivity_V_per_m_s2", _ACC_NOMINAL))
GYRO_SCALE = StateBlock("gyro", ScaleFactor.name, "s", XYZ, "1", _scale("scale_V_per_rad_s", _GYRO_NOMINAL))
ACC_MISALIGNMENT = StateBlock("acc", AxisMisalignment.name, "M", _PAIR_SUFFIX, "rad", _pairs("misalignment_rad"))
GYRO_MISALIGNMENT = StateBlock("gyro", AxisMisalignment.name, "M", _PAIR_SUFFIX, "rad", _pairs("misalignment_rad"))
ACC_NONLINEARITY = StateBlock("acc", ScaleNonlinearity.name, "k2", XYZ, "s^2/m", _key("k2_per_m_s2"))
ACC_THERMAL = (StateBlock("acc", TemperatureDrift.name, "kT", XYZ, "m/s^2/K", _key("bias_tempco_m_s2_per_K")),
               StateBlock("acc", TemperatureDrift.name, "sT", XYZ, "1/K", _key("scale_tempco_per_K")),
               StateBlock("acc", TemperatureHysteresis.name, "Hb", XYZ, "m/s^2", _key("bias_hysteresis_m_s2")),
               StateBlock("acc", TemperatureHysteresis.name, "Hs", XYZ, "1", _key("scale_hysteresis")))
GPS_POSITION = StateBlock("gps", "position_error", "r", ("n", "e", "d"), "m")
GYRO_BIAS_INSTABILITY = StateBlock("gyro", GyroNoise.name, "b_gm", XYZ, "rad/s")
MAG_HEADING = StateBlock("mag", "compass", "heading_error", ("rad",), "rad")
MAG_HARD_IRON = StateBlock("mag", HardIron.name, "b", XYZ, "T")
MAG_MATRIX = StateBlock("mag", SoftIron.name, "A", tuple(f"{a}{b}" for a in XYZ for b in XYZ), "1")


def names(*blocks: StateBlock) -> tuple[str, ...]:
    """The state names of ``blocks`` in order."""
    return tuple(n for b in blocks for n in b.names)
