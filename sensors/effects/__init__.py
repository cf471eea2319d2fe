"""The effect library: one module per physical effect, each an :class:`~imurig.sensors.effects.base.Effect`.

``LIBRARY`` lists every effect class once; the sensor chain, the diagnosis, the bounds and the
filter priors find effects here and nowhere else (README, "Adding an effect").
"""
from imurig.sensors.effects.adc_crosstalk import AdcCrosstalk
from imurig.sensors.effects.adc_quantisation import AdcQuantisation
from imurig.sensors.effects.base import STAGES, Candidate, ChainContext, Effect, Param, PositionView, ScanSlot

LIBRARY: tuple[type[Effect], ...] = (AdcCrosstalk, AdcQuantisation)


def by_name(name: str) -> type[Effect]:
    """The effect class called ``name``; raises KeyError naming the library's effects."""
    for cls in LIBRARY:
        if cls.name == name:
            return cls
    raise KeyError(f"no effect '{name}' in the library; known: {', '.join(c.name for c in LIBRARY)}")


def for_view(kind: str) -> list[type[Effect]]:
    """The effect classes that offer diagnosis candidates for views of ``kind`` ("positions", ...)."""
    return [cls for cls in LIBRARY if kind in cls.views]


__all__ = ["LIBRARY", "STAGES", "AdcCrosstalk", "AdcQuantisation", "Candidate", "ChainContext", "Effect", "Param",
           "PositionView", "ScanSlot", "by_name", "for_view"]
