"""The sensor chain: truth at the IMU -> sensor physics -> analog lines -> ADC -> Recording.

    rig Recording (set-points + truth signals f_C, w_C, B_C)
      + disturbances (pump, people)       -> specific force at the IMU      [m/s^2]
      -> Q-Flex triad, fluxgate, temperature sensors -> analog volts       [V]
      + loose cable spikes                 -> analog volts                 [V]
      -> DAQ-6036E (skew, ground loop, crosstalk, noise, 16-bit)           [V, quantised]
      = Recording with channels acc_*, mag_*, temp_*

Every stage draws from its own generator (:func:`imurig.sensors.noise.child_rng`), keyed
by the stage name, so one seed reproduces a dataset bit for bit, and switching one effect
on or off leaves every other stage's realisation unchanged.
"""
from __future__ import annotations

import datetime as _dt
from dataclasses import asdict, dataclass, field

import numpy as np

from imurig.recording import Recording
from imurig.sensors.accelerometer import AXES, CurrentTemperatureSensor, QFlexTriad
from imurig.sensors.adc import DAQ6036E
from imurig.sensors.disturbances import LooseCable, PeopleTransients, PumpVibration
from imurig.sensors.magnetometer import FluxgateTriad
from imurig.sensors.noise import child_rng
from imurig.site import parse_time

DEFAULT_SCAN = ("acc_x", "mag_x", "acc_y", "mag_y", "acc_z", "mag_z",
                "temp_acc_x", "temp_acc_y", "temp_acc_z", "temp_box")


@dataclass
class LabClimate:
    """Lab air temperature (C) with an optional linear drift; the IMU runs ``self_heating_K`` warmer."""

    temperature_C: float = 21.0
    drift_C_per_h: float = 0.0
    self_heating_K: float = 4.0

    def imu_temperature_K(self, time_s: np.ndarray) -> np.ndarray:
        return 273.15 + self.temperature_C + self.self_heating_K + self.drift_C_per_h * (time_s - time_s[0]) / 3600


@dataclass
class ImuLab:
    """The MiniSAR IMU, its junction box and the acquisition set-up, as one switchable chain."""

    accelerometers: QFlexTriad = field(default_factory=QFlexTriad.from_datasheet)
    magnetometer: FluxgateTriad = field(default_factory=FluxgateTriad.from_datasheet)
    temp_sensors: dict = field(default_factory=lambda: {
        "temp_acc_x": CurrentTemperatureSensor(), "temp_acc_y": CurrentTemperatureSensor(),
        "temp_acc_z": CurrentTemperatureSensor(), "temp_box": CurrentTemperatureSensor()})
    adc: DAQ6036E = field(default_factory=lambda: DAQ6036E(scan_list=DEFAULT_SCAN))
    pump: PumpVibration = field(default_factory=PumpVibration)
    people: PeopleTransients = field(default_factory=PeopleTransients)
    cable: LooseCable = field(default_factory=LooseCable)
    climate: LabClimate = field(default_factory=LabClimate)

    @classmethod
    def draw(cls, rng: np.random.Generator, **overrides) -> "ImuLab":
        """A lab whose sensors carry errors drawn from their datasheet limits."""
        kw = dict(accelerometers=QFlexTriad.from_datasheet(rng), magnetometer=FluxgateTriad.from_datasheet(rng))
        kw.update(overrides)
        return cls(**kw)

    def measure(self, rig: Recording, seed: np.random.SeedSequence) -> Recording:
        """Add measured channels to a rig recording; returns a new Recording."""
        t = rig.time_s
        fs = float(rig.meta["sample_rate_hz"])
        start = parse_time(rig.meta["start_time"])
        hour = (start.hour + start.minute / 60 + start.second / 3600 + (t - t[0]) / 3600.0) % 24.0
        f_C = np.stack([rig.truth_signals[f"f_C_{a}"] for a in AXES], axis=1)
        B_C = np.stack([rig.truth_signals[f"B_C_{a}"] for a in AXES], axis=1)

        f_dist = (self.pump.specific_force(t, hour, fs, child_rng(seed, "pump"))
                  + self.people.specific_force(t, hour, fs, child_rng(seed, "people")))
        T_imu = self.climate.imu_temperature_K(t)

        analog = {}
        slope = {}
        acc = self.accelerometers
        v_acc = acc.ideal_voltage(f_C + f_dist, T_imu)
        d_acc = np.gradient(v_acc, t, axis=0)
        v_acc += acc.noise_current(t.size, fs, child_rng(seed, "accelerometers")) * acc.load_resistor_ohm
        v_mag = self.magnetometer.output_voltage(B_C, child_rng(seed, "magnetometer"))
        d_mag = np.gradient(v_mag, t, axis=0)  # fluxgate noise is small: no separate noise-free path
        for j, a in enumerate(AXES):
            analog[f"acc_{a}"], slope[f"acc_{a}"] = v_acc[:, j], d_acc[:, j]
            analog[f"mag_{a}"], slope[f"mag_{a}"] = v_mag[:, j], d_mag[:, j]
        for name, sensor in self.temp_sensors.items():
            analog[name] = sensor.voltage(T_imu, child_rng(seed, name))
        if self.cable.enabled:
            if self.cable.channel not in analog:
                raise ValueError(f"loose cable on '{self.cable.channel}', which is not an analog line; "
                                 f"choose one of {sorted(analog)}")
            analog[self.cable.channel] = analog[self.cable.channel] + self.cable.voltage(
                t.size, fs, child_rng(seed, "cable"))

        volts, adc_report = self.adc.convert(analog, t, child_rng(seed, "adc"), slope)

        channels = dict(rig.channels)
        units = dict(rig.units)
        for k, v in volts.items():
            channels[k] = v
            units[k] = "V"
        quantum = {k: self.adc.lsb_V for k in volts}
        truth_signals = dict(rig.truth_signals)
        truth_units = dict(rig.truth_units)
        truth_signals["T_imu"] = T_imu
        truth_units["T_imu"] = "K"
        if np.any(f_dist):
            for j, a in enumerate(AXES):
                truth_signals[f"f_dist_C_{a}"] = f_dist[:, j]
                truth_units[f"f_dist_C_{a}"] = "m/s^2"
        meta = dict(rig.meta)
        meta["adc"] = self.adc.settings() | {"saturated_samples": adc_report["saturated_samples"]}
        meta["acc_nominal_sensitivity_V_per_m_s2"] = self.accelerometers.nominal_sensitivity_V_per_m_s2().tolist()
        meta["temperature_sensor"] = {"uA_per_K": 1.0, "uA_at_298_15K": 298.2, "load_resistor_ohm": 10e3}
        truth = dict(rig.truth or {})
        truth["sensors"] = {"accelerometers": self.accelerometers.truth(),
                            "magnetometer": self.magnetometer.truth(),
                            "temperature_sensors": {k: s.truth() for k, s in self.temp_sensors.items()}}
        truth["chain"] = {"adc": self.adc.settings(), "pump": asdict(self.pump), "people": asdict(self.people),
                          "cable": asdict(self.cable), "climate": asdict(self.climate)}
        truth["seed"] = {"entropy": str(seed.entropy), "spawn_key": list(seed.spawn_key)}
        return Recording(time_s=t, channels=channels, units=units, segments=dict(rig.segments),
                         segment_units=dict(rig.segment_units), meta=meta, truth=truth,
                         truth_signals=truth_signals, truth_units=truth_units, channel_quantum=quantum)
