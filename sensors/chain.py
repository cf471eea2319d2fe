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

from dataclasses import asdict, dataclass, field

import numpy as np

from imurig.kernel.recording import Recording
from imurig.sensors.accelerometer import AXES, CurrentTemperatureSensor, QFlexTriad
from imurig.sensors.adc import DAQ6036E
from imurig.sensors.disturbances import LooseCable, PeopleTransients, PumpVibration, SlipRingNoise
from imurig.sensors.gyro import AXES as GYRO_AXES
from imurig.sensors.gyro import FOGTriad
from imurig.sensors.magnetometer import FluxgateTriad
from imurig.sensors.timers import EventTimer, gps_mark_timer, hp6700_counter
from imurig.sensors.noise import child_rng
from imurig.kernel.site import parse_time

DEFAULT_SCAN = ("acc_x", "mag_x", "acc_y", "mag_y", "acc_z", "mag_z",
                "temp_acc_x", "temp_acc_y", "temp_acc_z", "temp_box")
TURN_TABLE_SCAN = ("gyro_p", "gyro_q", "gyro_r", "acc_x", "acc_y", "acc_z", "temp_box", "pulse")


@dataclass
class LabClimate:
    """Lab air temperature (C) with an optional linear drift; the IMU runs ``self_heating_K`` warmer."""

    temperature_C: float = 21.0
    drift_C_per_h: float = 0.0
    self_heating_K: float = 4.0

    def imu_temperature_K(self, time_s: np.ndarray) -> np.ndarray:
        return 273.15 + self.temperature_C + self.self_heating_K + self.drift_C_per_h * (time_s - time_s[0]) / 3600


@dataclass
class ThermalLags:
    """First-order thermal time constants (s) of the sensor groups inside the IMU box, used
    when the rig gives the air temperature (``T_air`` truth signal, e.g. a thermal chamber)."""

    accelerometers_s: float = 480.0
    gyros_s: float = 720.0
    box_sensor_s: float = 360.0


@dataclass
class ImuLab:
    """The MiniSAR IMU, its junction box and the acquisition set-up, as one switchable chain."""

    accelerometers: QFlexTriad = field(default_factory=QFlexTriad.from_datasheet)
    magnetometer: FluxgateTriad = field(default_factory=FluxgateTriad.from_datasheet)
    gyros: FOGTriad = field(default_factory=FOGTriad.from_datasheet)
    temp_sensors: dict = field(default_factory=lambda: {
        "temp_acc_x": CurrentTemperatureSensor(), "temp_acc_y": CurrentTemperatureSensor(),
        "temp_acc_z": CurrentTemperatureSensor(), "temp_box": CurrentTemperatureSensor()})
    adc: DAQ6036E = field(default_factory=lambda: DAQ6036E(scan_list=DEFAULT_SCAN))
    pump: PumpVibration = field(default_factory=PumpVibration)
    people: PeopleTransients = field(default_factory=PeopleTransients)
    cable: LooseCable = field(default_factory=LooseCable)
    climate: LabClimate = field(default_factory=LabClimate)
    slip_rings: SlipRingNoise = field(default_factory=SlipRingNoise)
    thermal_lags: ThermalLags = field(default_factory=ThermalLags)
    timers: tuple[EventTimer, ...] = field(default_factory=lambda: (gps_mark_timer(), hp6700_counter()))

    @classmethod
    def draw(cls, rng: np.random.Generator, **overrides) -> "ImuLab":
        """A lab whose sensors carry errors drawn from their datasheet limits."""
        kw = dict(accelerometers=QFlexTriad.from_datasheet(rng), magnetometer=FluxgateTriad.from_datasheet(rng),
                  gyros=FOGTriad.from_datasheet(rng))
        kw.update(overrides)
        return cls(**kw)

    def measure(self, rig: Recording, seed: np.random.SeedSequence) -> Recording:
        """Add measured channels to a rig recording; returns a new Recording."""
        t = rig.time_s
        fs = float(rig.meta["sample_rate_hz"])
        start = parse_time(rig.meta["start_time"])
        hour = (start.hour + start.minute / 60 + start.second / 3600 + (t - t[0]) / 3600.0) % 24.0
        scan = set(self.adc.scan_list)
        ts = rig.truth_signals

        def wanted(prefix, axes):
            return any(f"{prefix}_{a}" in scan for a in axes)

        f_dist = (self.pump.specific_force(t, hour, fs, child_rng(seed, "pump"))
                  + self.people.specific_force(t, hour, fs, child_rng(seed, "people")))
        if "T_air" in ts:  # a thermal chamber: each sensor group lags the air temperature
            from imurig.sensors.thermal import first_order_lag, hysteresis_state

            T_acc = first_order_lag(ts["T_air"], t, self.thermal_lags.accelerometers_s)
            T_gyro = first_order_lag(ts["T_air"], t, self.thermal_lags.gyros_s)
            T_box = first_order_lag(ts["T_air"], t, self.thermal_lags.box_sensor_s)
            h_acc = hysteresis_state(T_acc, self.accelerometers.hysteresis_width_K, fs)
        else:
            T_acc = T_gyro = T_box = self.climate.imu_temperature_K(t)
            h_acc = 0.0
        T_imu = T_acc
        analog, slope, used = {}, {}, []
        if wanted("acc", AXES):
            f_C = np.stack([ts[f"f_C_{a}"] for a in AXES], axis=1)
            acc = self.accelerometers
            if np.any(acc.position_C_m) and "w_C_x" in ts:  # the triad off the case reference point
                from imurig.sensors.accelerometer import lever_arm_specific_force

                f_C = f_C + lever_arm_specific_force(np.stack([ts[f"w_C_{a}"] for a in AXES], axis=1), t,
                                                     acc.position_C_m)
            v = acc.ideal_voltage(f_C + f_dist, T_acc, h_acc)
            d = np.gradient(v, t, axis=0)
            v += acc.noise_current(t.size, fs, child_rng(seed, "accelerometers"),
                                   averaged=bool(rig.meta.get("averaged_logging"))) * acc.load_resistor_ohm
            for j, a in enumerate(AXES):
                analog[f"acc_{a}"], slope[f"acc_{a}"] = v[:, j], d[:, j]
            used.append("accelerometers")
        if wanted("mag", AXES):
            B_C = np.stack([ts[f"B_C_{a}"] for a in AXES], axis=1)
            v = self.magnetometer.output_voltage(B_C, child_rng(seed, "magnetometer"), T_box)
            d = np.gradient(v, t, axis=0)  # fluxgate noise is small: no separate noise-free path
            for j, a in enumerate(AXES):
                analog[f"mag_{a}"], slope[f"mag_{a}"] = v[:, j], d[:, j]
            used.append("magnetometer")
        if wanted("gyro", GYRO_AXES):
            w_C = np.stack([ts[f"w_C_{a}"] for a in AXES], axis=1)
            g = self.gyros
            f_gyro = (np.stack([ts[f"f_C_{a}"] for a in AXES], axis=1) + f_dist
                      if np.any(g.g_sensitivity_rad_s_per_m_s2) else None)
            v = g.ideal_voltage(w_C, T_gyro, f_gyro)
            d = np.gradient(v, t, axis=0)
            grng = child_rng(seed, "gyros")
            for blk in rig.blocks():  # the bias instability decorrelates over a remount gap
                v[blk] += g.noise_rate(blk.stop - blk.start, fs, grng) * g.scale_V_per_rad_s
            for j, a in enumerate(GYRO_AXES):
                analog[f"gyro_{a}"], slope[f"gyro_{a}"] = v[:, j], d[:, j]
            used.append("gyros")
        for name, sensor in self.temp_sensors.items():
            if name in scan:
                analog[name] = sensor.voltage(T_box if name == "temp_box" else T_acc, child_rng(seed, name))
        if self.slip_rings.enabled and "spin_angle" in ts:
            # every IMU line crosses a slip ring; lines from the table itself do not
            for name in list(analog):
                analog[name] = analog[name] + self.slip_rings.voltage(ts["spin_angle"], child_rng(seed, "slip_" + name))
        for line in rig.meta.get("analog_lines", []):
            analog[line] = ts[line]
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
        if "T_air" in ts:
            for k, v in (("T_acc", T_acc), ("T_gyro", T_gyro), ("T_box", T_box), ("h_acc", h_acc)):
                truth_signals[k] = v
                truth_units[k] = "1" if k == "h_acc" else "K"
        else:
            truth_signals["T_imu"] = T_imu
            truth_units["T_imu"] = "K"
        if np.any(f_dist):
            for j, a in enumerate(AXES):
                truth_signals[f"f_dist_C_{a}"] = f_dist[:, j]
                truth_units[f"f_dist_C_{a}"] = "m/s^2"
        meta = dict(rig.meta)
        meta["adc"] = self.adc.settings() | {"saturated_samples": adc_report["saturated_samples"]}
        meta["acc_nominal_sensitivity_V_per_m_s2"] = self.accelerometers.nominal_sensitivity_V_per_m_s2().tolist()
        meta["gyro_nominal_sensitivity_V_per_rad_s"] = self.gyros.nominal_sensitivity().tolist()
        meta["gyro_noise_model"] = {"arw_rad_s_per_sqrt_hz": self.gyros.arw_rad_s_per_sqrt_hz,
                                    "bias_instability_rad_s": self.gyros.bias_instability_rad_s,
                                    "bias_instability_tau_s": self.gyros.bias_instability_tau_s,
                                    "source": "VG941-3AM datasheet (random walk, bias variation); tau assumed"}
        events = dict(rig.events)
        if "pulse_true" in rig.events:
            for timer in self.timers:
                events[f"pulse_{timer.name}"] = timer.measure(rig.events["pulse_true"], child_rng(seed, timer.name))
            meta["timers"] = {tm.name: tm.settings() for tm in self.timers}
        meta["temperature_sensor"] = {"uA_per_K": 1.0, "uA_at_298_15K": 298.2, "load_resistor_ohm": 10e3}
        truth = dict(rig.truth or {})
        sensors = {"accelerometers": self.accelerometers.truth(), "magnetometer": self.magnetometer.truth(),
                   "gyros": self.gyros.truth()}
        truth["sensors"] = {k: v for k, v in sensors.items() if k in used}
        truth["sensors"]["temperature_sensors"] = {k: s.truth() for k, s in self.temp_sensors.items() if k in scan}
        truth["chain"] = {"adc": self.adc.settings(), "pump": asdict(self.pump), "people": asdict(self.people),
                          "cable": asdict(self.cable), "climate": asdict(self.climate),
                          "thermal_lags": asdict(self.thermal_lags),
                          "slip_rings": asdict(self.slip_rings) if "spin_angle" in ts else None,
                          "timers": {tm.name: tm.settings() for tm in self.timers}}
        truth["seed"] = {"entropy": str(seed.entropy), "spawn_key": list(seed.spawn_key)}
        return Recording(time_s=t, channels=channels, units=units, segments=dict(rig.segments),
                         segment_units=dict(rig.segment_units), meta=meta, truth=truth,
                         truth_signals=truth_signals, truth_units=truth_units, channel_quantum=quantum,
                         events=events)
