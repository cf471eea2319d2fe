"""The effect library: one module per physical effect, each an :class:`~imurig.sensors.effects.base.Effect`.

``LIBRARY`` lists every effect class once; the sensor chain, the diagnosis, the bounds and the
filter priors find effects here and nowhere else (README, "Adding an effect").
"""
from imurig.sensors.effects.adc_crosstalk import AdcCrosstalk
from imurig.sensors.effects.adc_quantisation import AdcQuantisation
from imurig.sensors.effects.base import STAGES, Candidate, ChainContext, Effect, Param, PositionView, ScanSlot
from imurig.sensors.effects.earth_rate import EarthRateLeftOut
from imurig.sensors.effects.g_sensitivity import GSensitivity
from imurig.sensors.effects.gyro_row_drift import GyroRowDrift
from imurig.sensors.effects.gyro_scale_nonlinearity import GyroScaleNonlinearity
from imurig.sensors.effects.hard_iron import HardIron
from imurig.sensors.effects.instrument_range_change import InstrumentRangeChange
from imurig.sensors.effects.local_field_anomaly import LocalFieldAnomaly
from imurig.sensors.effects.mag_misalignment import MagMisalignment
from imurig.sensors.effects.mag_scale_nonlinearity import MagScaleNonlinearity
from imurig.sensors.effects.mag_temperature_drift import MagTemperatureDrift
from imurig.sensors.effects.mag_time_delay import MagTimeDelay
from imurig.sensors.effects.mag_time_drift import MagTimeDrift
from imurig.sensors.effects.mains_rate_factor import MainsRateFactor
from imurig.sensors.effects.rate_proportional_error import RateProportionalError
from imurig.sensors.effects.slip_rings import SlipRingNoise
from imurig.sensors.effects.soft_iron import SoftIron
from imurig.sensors.effects.table_slip import TableSlip
from imurig.sensors.effects.temperature_hysteresis import TemperatureHysteresis
from imurig.sensors.effects.timer_quantisation import TimerQuantisation
from imurig.sensors.effects.views import (MagView, RateRowView, RateShortfallView, ThermalView, TurnSampleView,
                                          TurnView, VoltmeterRowView)

#: the turn-table, rate-row, thermal and magnetometer effects in the order each view offers their
#: candidates (turn windows: Earth rate, g-sensitivity; rate rows: range change, nonlinearity,
#: drift; magnetometer blocks: hard and soft iron, misalignment, field anomaly, temperature and
#: time drift, nonlinearity, delay)
TURN_RATE_MAG_EFFECTS: tuple[type[Effect], ...] = (
    EarthRateLeftOut, GSensitivity, SlipRingNoise, MainsRateFactor, TableSlip, RateProportionalError,
    TimerQuantisation, InstrumentRangeChange, GyroScaleNonlinearity, GyroRowDrift, TemperatureHysteresis,
    HardIron, SoftIron, MagMisalignment, LocalFieldAnomaly, MagTemperatureDrift, MagTimeDrift, MagScaleNonlinearity,
    MagTimeDelay)

LIBRARY: tuple[type[Effect], ...] = (AdcCrosstalk, AdcQuantisation) + TURN_RATE_MAG_EFFECTS


def by_name(name: str) -> type[Effect]:
    """The effect class called ``name``; raises KeyError naming the library's effects."""
    for cls in LIBRARY:
        if cls.name == name:
            return cls
    raise KeyError(f"no effect '{name}' in the library; known: {', '.join(c.name for c in LIBRARY)}")


def for_view(kind: str) -> list[type[Effect]]:
    """The effect classes that offer diagnosis candidates for views of ``kind`` ("positions", ...)."""
    return [cls for cls in LIBRARY if kind in cls.views]


__all__ = ["LIBRARY", "STAGES", "AdcCrosstalk", "AdcQuantisation", "Candidate", "ChainContext", "EarthRateLeftOut",
           "Effect", "GSensitivity", "GyroRowDrift", "GyroScaleNonlinearity", "HardIron", "InstrumentRangeChange",
           "LocalFieldAnomaly", "MagMisalignment", "MagScaleNonlinearity", "MagTemperatureDrift", "MagTimeDelay",
           "MagTimeDrift", "MagView", "MainsRateFactor", "Param", "PositionView", "RateProportionalError",
           "RateRowView", "RateShortfallView", "ScanSlot", "SlipRingNoise", "SoftIron", "TableSlip",
           "TemperatureHysteresis", "ThermalView", "TimerQuantisation", "TurnSampleView", "TurnView",
           "VoltmeterRowView", "by_name", "for_view"]
