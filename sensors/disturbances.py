"""Lab disturbances of seed section 4.3.3 and the turn table's slip rings (seed Fig. 4.16).

Each is an effect object of :mod:`imurig.sensors.effects` (``building_vibration``,
``people_transients``, ``cable_fault_spikes``, ``slip_rings``); they are re-exported here under their
class names for the campaigns that configure a lab.
"""
from __future__ import annotations

from dataclasses import asdict

from imurig.sensors.effects.building_vibration import PumpVibration, working_mask
from imurig.sensors.effects.cable_fault_spikes import LooseCable
from imurig.sensors.effects.people_transients import PeopleTransients
from imurig.sensors.effects.slip_rings import SlipRingNoise

__all__ = ["LooseCable", "PeopleTransients", "PumpVibration", "SlipRingNoise", "settings", "working_mask"]


def settings(obj) -> dict:
    return asdict(obj)
