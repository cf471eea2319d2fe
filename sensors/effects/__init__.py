"""The effect library: one module per physical effect, each an :class:`~imurig.sensors.effects.base.Effect`.

``LIBRARY`` lists every effect class once; the sensor chain, the diagnosis, the bounds and the
filter priors find effects here and nowhere else (README, "Adding an effect").
"""
from imurig.sensors.effects.adc_crosstalk import AdcCrosstalk
from imurig.sensors.effects.adc_quantisation import AdcQuantisation
from imurig.sensors.effects.axis_misalignment import AxisMisalignment
from imurig.sensors.effects.base import (STAGES, Candidate, ChainContext, Effect, Param, PositionView, ScanSlot,
                                         ScatterView, recording_truth)
from imurig.sensors.effects.building_vibration import PumpVibration
from imurig.sensors.effects.cable_fault_spikes import LooseCable
from imurig.sensors.effects.channel_skew import ChannelSkew
from imurig.sensors.effects.cross_coupling import CrossCoupling
from imurig.sensors.effects.lever_arm import LeverArm
from imurig.sensors.effects.people_transients import PeopleTransients
from imurig.sensors.effects.scale_nonlinearity import ScaleNonlinearity
from imurig.sensors.effects.temperature_drift import TemperatureDrift

#: in the order the diagnosis offers their candidates (position means: crosstalk, drift, axes, square, product)
LIBRARY: tuple[type[Effect], ...] = (AdcCrosstalk, AdcQuantisation, TemperatureDrift, AxisMisalignment,
                                     ScaleNonlinearity, CrossCoupling, PumpVibration, PeopleTransients, LooseCable,
                                     ChannelSkew, LeverArm)


def by_name(name: str) -> type[Effect]:
    """The effect class called ``name``; raises KeyError naming the library's effects."""
    for cls in LIBRARY:
        if cls.name == name:
            return cls
    raise KeyError(f"no effect '{name}' in the library; known: {', '.join(c.name for c in LIBRARY)}")


def for_view(kind: str) -> list[type[Effect]]:
    """The effect classes that offer diagnosis candidates for views of ``kind`` ("positions", ...)."""
    return [cls for cls in LIBRARY if kind in cls.views]


__all__ = ["LIBRARY", "STAGES", "AdcCrosstalk", "AdcQuantisation", "AxisMisalignment", "Candidate", "ChainContext",
           "ChannelSkew", "CrossCoupling", "Effect", "LeverArm", "LooseCable", "Param", "PeopleTransients",
           "PositionView", "PumpVibration", "ScaleNonlinearity", "ScanSlot", "ScatterView", "TemperatureDrift",
           "by_name", "for_view", "recording_truth"]
