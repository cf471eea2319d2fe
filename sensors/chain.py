"""The sensor chain: truth at the IMU -> sensor physics -> analog lines -> ADC -> Recording.

The chain composes effect objects (:mod:`imurig.sensors.effects`) stage by stage, as dm_control
composes corruptors:

    rig Recording (set-points + truth signals f_C, w_C, B_C)
      specific_force: pump, people (+ the triad's lever arm)  -> specific force at the IMU [m/s^2]
      sensor:         Q-Flex triad, fog triad, fluxgate, temperature sensors (their own
                      parameters: misalignment, nonlinearity, temperature drift ...) -> analog volts [V]
      analog:         slip rings (every IMU line), loose cable (one line)               [V]
      conversion:     DAQ-6036E (channel skew, ground loop, crosstalk, noise, 16 bit)   [V, quantised]
      events:         timers tag the rig's pulses                                      [s]
      = Recording with channels acc_*, mag_*, gyro_*, temp_* (and pulse_* events)

Every effect draws from its own generator (:func:`imurig.sensors.noise.child_rng`), keyed by the
effect's stream name ("pump", "people", "cable", "slip_<line>", "adc", each sensor's name ...),
so one seed reproduces a dataset bit for bit, and switching one effect on or off leaves every
other stage's realisation unchanged.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from imurig.kernel.errors import ConfigError
from imurig.kernel.recording import Recording
from imurig.kernel.site import parse_time
from imurig.sensors.accelerometer import AXES, CurrentTemperatureSensor, QFlexTriad
from imurig.sensors.adc import DAQ6036E
from imurig.sensors.disturbances import LooseCable, PeopleTransients, PumpVibration, SlipRingNoise
from imurig.sensors.effects.base import ChainContext
from imurig.sensors.gyro import AXES as GYRO_AXES
from imurig.sensors.gyro import FOGTriad
from imurig.sensors.magnetometer import FluxgateTriad
from imurig.sensors.noise import child_rng
from imurig.sensors.thermal import first_order_lag, hysteresis_state
from imurig.sensors.timers import EventTimer, gps_mark_timer, hp6700_counter

DEFAULT_SCAN = ("acc_x", "mag_x", "acc_y", "mag_y", "acc_z", "mag_z",
                "temp_acc_x", "temp_acc_y", "temp_acc_z", "temp_box")
TURN_TABLE_SCAN = ("gyro_p", "gyro_q", "gyro_r", "acc_x", "acc_y", "acc_z", "temp_box", "pulse")
#: the stages a lab's own disturbance effects may act at (conversion effects are the converter's
#: settings, sensor-stage effects the sensor models' parameters)
LAB_STAGES = ("specific_force", "analog")


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
class SensorTemperatures:
    """The sensors' temperatures (K, (n,)) and the accelerometers' hysteresis state during a record."""

    acc: np.ndarray
    gyro: np.ndarray
    box: np.ndarray
    h_acc: np.ndarray | float
    chamber: bool


@dataclass
class ImuLab:
    """The MiniSAR IMU, its junction box and the acquisition set-up, as one switchable chain.

    The lab's disturbances are effect objects: ``pump`` and ``people`` (specific force),
    ``slip_rings`` and ``cable`` (analog lines), and any further ones in ``effects`` (stage
    "specific_force" or "analog"); :meth:`stage_effects` lists them per stage in chain order.
    """

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
    effects: tuple = ()

    def __post_init__(self):
        for e in self.effects:
            if getattr(e, "stage", None) not in LAB_STAGES:
                raise ConfigError(f"effect '{getattr(e, 'name', e)}' acts at stage '{getattr(e, 'stage', None)}'; a "
                                  f"lab's own effects act at {LAB_STAGES} (conversion effects are the converter's "
                                  "settings, sensor-stage effects the sensor models' parameters)")

    @classmethod
    def draw(cls, rng: np.random.Generator, **overrides) -> "ImuLab":
        """A lab whose sensors carry errors drawn from their datasheet limits."""
        kw = dict(accelerometers=QFlexTriad.from_datasheet(rng), magnetometer=FluxgateTriad.from_datasheet(rng),
                  gyros=FOGTriad.from_datasheet(rng))
        kw.update(overrides)
        return cls(**kw)

    def stage_effects(self, stage: str) -> list:
        """The lab's effects acting at ``stage``, in chain order (the named ones first).

        "conversion": the converter's (crosstalk, channel skew); "sensor": the accelerometer
        triad's parameters (misalignment, nonlinearity, temperature drift)."""
        if stage == "conversion":
            return [self.adc.skew, self.adc.crosstalk]
        if stage == "sensor":
            return list(self.accelerometers.sensor_effects())
        named = {"specific_force": (self.pump, self.people), "analog": (self.slip_rings, self.cable)}.get(stage, ())
        return [*named, *(e for e in self.effects if e.stage == stage)]

    # ------------------------------------------------------------------ the chain
    def measure(self, rig: Recording, seed: np.random.SeedSequence) -> Recording:
        """Add measured channels to a rig recording; returns a new Recording."""
        ctx = self._context(rig)
        f_dist = self._specific_force(ctx, seed)
        temps = self._temperatures(rig)
        analog, slope, used = self._sensor_lines(rig, ctx, f_dist, temps, seed)
        ctx.imu_lines = tuple(analog)
        for line in rig.meta.get("analog_lines", []):
            analog[line] = rig.truth_signals[line]
        self._analog(analog, ctx, seed)
        volts, adc_report = self.adc.convert(analog, rig.time_s, child_rng(seed, "adc"), slope, consume=True)
        del analog, slope
        events = self._events(rig, seed)
        return self._recording(rig, seed, volts, adc_report, f_dist, temps, used, events)

    def _context(self, rig: Recording) -> ChainContext:
        t = rig.time_s
        start = parse_time(rig.meta["start_time"])
        hour = (start.hour + start.minute / 60 + start.second / 3600 + (t - t[0]) / 3600.0) % 24.0
        sens = dict(zip((f"acc_{a}" for a in AXES), self.accelerometers.nominal_sensitivity_V_per_m_s2()))
        return ChainContext(time_s=t, sample_rate_hz=float(rig.meta["sample_rate_hz"]), hour_of_day=hour,
                            truth_signals=rig.truth_signals, adc=self.adc, sensitivity_V_per_SI=sens)

    def _specific_force(self, ctx: ChainContext, seed) -> np.ndarray:
        """Specific-force stage: the disturbances' f (n, 3) m/s^2 at the IMU, shared by the sensors."""
        f = np.zeros((ctx.time_s.size, 3))
        for eff in self.stage_effects("specific_force"):  # a deterministic effect has no stream and draws nothing
            f = eff.inject(f, ctx, child_rng(seed, eff.stream) if eff.stream else None)
        return f

    def _temperatures(self, rig: Recording) -> SensorTemperatures:
        t, ts = rig.time_s, rig.truth_signals
        if "T_air" in ts:  # a thermal chamber: each sensor group lags the air temperature
            T_acc = first_order_lag(ts["T_air"], t, self.thermal_lags.accelerometers_s)
            return SensorTemperatures(acc=T_acc, gyro=first_order_lag(ts["T_air"], t, self.thermal_lags.gyros_s),
                                      box=first_order_lag(ts["T_air"], t, self.thermal_lags.box_sensor_s),
                                      h_acc=hysteresis_state(T_acc, self.accelerometers.hysteresis_width_K,
                                                             float(rig.meta["sample_rate_hz"])), chamber=True)
        T = self.climate.imu_temperature_K(t)
        return SensorTemperatures(acc=T, gyro=T, box=T, h_acc=0.0, chamber=False)

    def _sensor_lines(self, rig, ctx, f_dist, temps, seed) -> tuple[dict, dict, list]:
        """Sensor stage: the analog line of every scanned sensor (V), the noise-free slopes (V/s)
        for the converter's skew, and which sensor groups were used."""
        scan = set(self.adc.scan_list)
        analog, slope, used = {}, {}, []

        def wanted(prefix, axes):
            return any(f"{prefix}_{a}" in scan for a in axes)

        for prefix, axes, group, lines in (("acc", AXES, "accelerometers", self._accelerometer_volts),
                                           ("mag", AXES, "magnetometer", self._magnetometer_volts),
                                           ("gyro", GYRO_AXES, "gyros", self._gyro_volts)):
            if wanted(prefix, axes):
                v, d = lines(rig, ctx, f_dist, temps, seed)
                for j, a in enumerate(axes):
                    analog[f"{prefix}_{a}"], slope[f"{prefix}_{a}"] = v[j], d[j]
                used.append(group)
        for name, sensor in self.temp_sensors.items():
            if name in scan:
                T, rng = temps.box if name == "temp_box" else temps.acc, child_rng(seed, name)
                analog[name] = np.empty(np.shape(T))
                for a, b in _row_chunks(analog[name].shape[0]):  # the same draws, in order, in pieces
                    analog[name][a:b] = sensor.voltage(T[a:b], rng)
        return analog, slope, used

    # each group's lines are three separate (n,) arrays (not the columns of one (n, 3) array), so the
    # converter frees each line's memory as soon as it has converted it
    def _accelerometer_volts(self, rig, ctx, f_dist, temps, seed):
        ts, t = rig.truth_signals, rig.time_s
        acc = self.accelerometers
        lever = acc.lever_arm()
        f_C = None
        if lever.active and "w_C_x" in ts:  # the lever arm's terms need the whole record (dw/dt)
            f_C = lever.inject(np.stack([ts[f"f_C_{a}"] for a in AXES], axis=1), ctx)
            f_C += f_dist
        v = [np.empty(t.size) for _ in AXES]
        for a, b in _row_chunks(t.size):  # pointwise: in bounded pieces, no full-length temporaries
            if f_C is None:
                f = np.stack([ts[f"f_C_{ax}"][a:b] for ax in AXES], axis=1)
                f += f_dist[a:b]
            else:
                f = f_C[a:b]
            _put_columns(v, a, b, acc.ideal_voltage(f, _rows(temps.acc, a, b), _rows(temps.h_acc, a, b)))
        del f_C
        d = [_gradient_rows(x, t) for x in v]
        noise = acc.current_noise(averaged=bool(rig.meta.get("averaged_logging"))).current(
            t.size, ctx.sample_rate_hz, child_rng(seed, "accelerometers"))
        for a, b in _row_chunks(t.size):
            for j, x in enumerate(v):
                x[a:b] += noise[a:b, j] * acc.load_resistor_ohm[j]
        return v, d

    def _magnetometer_volts(self, rig, ctx, f_dist, temps, seed):
        ts, t = rig.truth_signals, rig.time_s
        rng = child_rng(seed, "magnetometer")
        v = [np.empty(t.size) for _ in AXES]
        for a, b in _row_chunks(t.size):  # the noise drawn row-chunk by row-chunk: the same draws in order
            B_C = np.stack([ts[f"B_C_{ax}"][a:b] for ax in AXES], axis=1)
            _put_columns(v, a, b, self.magnetometer.output_voltage(B_C, rng, _rows(temps.box, a, b)))
        return v, [_gradient_rows(x, t) for x in v]  # fluxgate noise is small: no separate noise-free path

    def _gyro_volts(self, rig, ctx, f_dist, temps, seed):
        ts, t, g = rig.truth_signals, rig.time_s, self.gyros
        g_sens = bool(np.any(g.g_sensitivity_rad_s_per_m_s2))
        v = [np.empty(t.size) for _ in GYRO_AXES]
        for a, b in _row_chunks(t.size):  # pointwise: in bounded pieces
            w_C = np.stack([ts[f"w_C_{ax}"][a:b] for ax in AXES], axis=1)
            f_gyro = np.stack([ts[f"f_C_{ax}"][a:b] for ax in AXES], axis=1) + f_dist[a:b] if g_sens else None
            _put_columns(v, a, b, g.ideal_voltage(w_C, _rows(temps.gyro, a, b), f_gyro))
        d = [_gradient_rows(x, t) for x in v]
        grng = child_rng(seed, "gyros")
        for blk in rig.blocks():  # the bias instability decorrelates over a remount gap
            nz = g.noise_rate(blk.stop - blk.start, ctx.sample_rate_hz, grng)
            nz *= g.scale_V_per_rad_s
            for j, x in enumerate(v):
                x[blk] += nz[:, j]
        return v, d

    def _analog(self, analog: dict, ctx: ChainContext, seed) -> None:
        """Analog stage: each effect on the lines it acts on, one random stream per line."""
        for eff in self.stage_effects("analog"):
            for line in eff.lines(list(analog), ctx):
                analog[line] = eff.inject(analog[line], ctx, child_rng(seed, eff.line_stream(line)))

    def _events(self, rig: Recording, seed) -> dict:
        """Events stage: every timer tags the rig's true pulses."""
        events = dict(rig.events)
        if "pulse_true" in rig.events:
            for timer in self.timers:
                events[f"pulse_{timer.name}"] = timer.measure(rig.events["pulse_true"], child_rng(seed, timer.name))
        return events

    # ------------------------------------------------------------------ the record
    def _recording(self, rig, seed, volts, adc_report, f_dist, temps, used, events) -> Recording:
        channels, units = dict(rig.channels), dict(rig.units)
        for k, v in volts.items():
            channels[k] = v
            units[k] = "V"
        truth_signals, truth_units = dict(rig.truth_signals), dict(rig.truth_units)
        if temps.chamber:
            for k, v in (("T_acc", temps.acc), ("T_gyro", temps.gyro), ("T_box", temps.box), ("h_acc", temps.h_acc)):
                truth_signals[k] = v
                truth_units[k] = "1" if k == "h_acc" else "K"
        else:
            truth_signals["T_imu"] = temps.acc
            truth_units["T_imu"] = "K"
        if np.any(f_dist):
            for j, a in enumerate(AXES):
                truth_signals[f"f_dist_C_{a}"] = f_dist[:, j]
                truth_units[f"f_dist_C_{a}"] = "m/s^2"
        return Recording(time_s=rig.time_s, channels=channels, units=units, segments=dict(rig.segments),
                         segment_units=dict(rig.segment_units), meta=self._meta(rig, adc_report),
                         truth=self._truth(rig, seed, used), truth_signals=truth_signals, truth_units=truth_units,
                         channel_quantum={k: self.adc.lsb_V for k in volts}, events=events)

    def _meta(self, rig: Recording, adc_report: dict) -> dict:
        meta = dict(rig.meta)
        meta["adc"] = self.adc.settings() | {"saturated_samples": adc_report["saturated_samples"]}
        meta["acc_nominal_sensitivity_V_per_m_s2"] = self.accelerometers.nominal_sensitivity_V_per_m_s2().tolist()
        meta["gyro_nominal_sensitivity_V_per_rad_s"] = self.gyros.nominal_sensitivity().tolist()
        meta["gyro_noise_model"] = {"arw_rad_s_per_sqrt_hz": self.gyros.arw_rad_s_per_sqrt_hz,
                                    "bias_instability_rad_s": self.gyros.bias_instability_rad_s,
                                    "bias_instability_tau_s": self.gyros.bias_instability_tau_s,
                                    "source": "VG941-3AM datasheet (random walk, bias variation); tau assumed"}
        for e in self.effects:   # a wandering scale factor (the Delft 2005 preset), so that a GLS fit weighs each step by it
            if e.name == "gyro_scale_instability" and e.enabled and e.sigma > 0:
                meta["gyro_noise_model"].update(scale_instability=e.sigma, scale_instability_tau_s=e.tau_s)
        if "pulse_true" in rig.events:
            meta["timers"] = {tm.name: tm.settings() for tm in self.timers}
        meta["temperature_sensor"] = {"uA_per_K": 1.0, "uA_at_298_15K": 298.2, "load_resistor_ohm": 10e3}
        return meta

    def _truth(self, rig: Recording, seed, used: list) -> dict:
        scan = set(self.adc.scan_list)
        truth = dict(rig.truth or {})
        sensors = {"accelerometers": self.accelerometers.truth(), "magnetometer": self.magnetometer.truth(),
                   "gyros": self.gyros.truth()}
        truth["sensors"] = {k: v for k, v in sensors.items() if k in used}
        truth["sensors"]["temperature_sensors"] = {k: s.truth() for k, s in self.temp_sensors.items() if k in scan}
        truth["chain"] = {"adc": self.adc.settings(), "pump": asdict(self.pump), "people": asdict(self.people),
                          "cable": asdict(self.cable), "climate": asdict(self.climate),
                          "thermal_lags": asdict(self.thermal_lags),
                          "slip_rings": asdict(self.slip_rings) if "spin_angle" in rig.truth_signals else None,
                          "timers": {tm.name: tm.settings() for tm in self.timers}}
        if self.effects:
            truth["chain"]["effects"] = {e.name: e.settings() for e in self.effects}
        truth["seed"] = {"entropy": str(seed.entropy), "spawn_key": list(seed.spawn_key)}
        return truth


#: rows per piece of the pointwise stages (bounded temporaries; results do not depend on it)
ROW_CHUNK = 1 << 18


def _row_chunks(n: int, chunk: int = ROW_CHUNK):
    """(start, stop) row ranges covering n rows."""
    return [(a, min(n, a + chunk)) for a in range(0, n, chunk)]


def _rows(x, a: int, b: int):
    """Rows a:b of a per-sample array; a scalar (or 0-d array) as it is."""
    return x[a:b] if np.ndim(x) >= 1 else x


def _put_columns(cols: list, a: int, b: int, x: np.ndarray) -> None:
    """Rows a:b of the (n,) arrays ``cols`` from the columns of ``x`` (b - a, len(cols))."""
    for j, c in enumerate(cols):
        c[a:b] = x[:, j]


def _gradient_rows(v: np.ndarray, t: np.ndarray, chunk: int = ROW_CHUNK) -> np.ndarray:
    """np.gradient(v, t, axis=0) computed in row pieces with one row of overlap: the same values
    (each interior row uses its two neighbours, the end rows one-sided differences)."""
    n = v.shape[0]
    if n <= chunk:
        return np.gradient(v, t, axis=0)
    out = np.empty_like(v)
    for a, b in _row_chunks(n, chunk):
        lo, hi = max(a - 1, 0), min(b + 1, n)
        out[a:b] = np.gradient(v[lo:hi], t[lo:hi], axis=0)[a - lo:a - lo + (b - a)]
    return out
