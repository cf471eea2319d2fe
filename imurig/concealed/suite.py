"""Concealed-effect suite: recordings where one library effect is present at a chosen size
but absent from the nominal model, and null recordings with none. Shared by the tests and
``benchmarks/bench_diagnose.py`` (detection rate, false discoveries, parameter error, power).

Each case maps an effect size (in units of the noise where that is natural) to a recording,
and says which (channel, effect) pairs a correct diagnosis must report.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from imurig.calibration.thermal import ThermalCalibration, step_table
from imurig.campaigns.thermal import ThermalCampaign, twin_channels
from imurig.campaigns.turn_table import SimonaSetup, TurnTableCampaign, simona_virtual
from imurig.concealed import magnetometer as mag_cases
from imurig.concealed import tilt_table as tilt_cases
from imurig.concealed.tilt_table import (WIDE_TILT, accelerometers_recording, cable_recording, crosstalk_recording,
                                         pump_recording, small_tilt)
from imurig.diagnose.magnetometer import diagnose_magnetometer
from imurig.diagnose.rate_table import diagnose_rate_rows
from imurig.diagnose.thermal import diagnose_thermal
from imurig.diagnose.tilt_table import diagnose_tilt_table
from imurig.diagnose.turn_table import diagnose_turn_table
from imurig.kernel.errors import ConfigError
from imurig.kernel.site import Site
from imurig.rigs.thermal_chamber import ThermalProfile
from imurig.rigs.turn_table import TurnTableErrors, TurnTableProtocol
from imurig.sensors.effects import (AdcCrosstalk, AxisMisalignment, EarthRateLeftOut, GSensitivity, InstrumentRangeChange,
                                   ScaleNonlinearity, SlipRingNoise, TimerQuantisation, recording_truth)
from imurig.sensors.gyro import FOGTriad
from imurig.sensors.voltmeter import AutoscaleVoltmeter
from imurig.kernel import random_streams

DEG_PER_H_PER_G = math.radians(1.0) / 3600.0 / 9.80665   # 1 deg/h per g in (rad/s)/(m/s^2)


@dataclass
class Case:
    effect: str
    rig: str
    expected: set
    make: Callable[[int, float], object]            # (seed, size) -> Recording
    realistic_size: float
    sizes: tuple = ()                               # for the power curve
    size_unit: str = ""
    truth_param: Callable | None = None              # (rec) -> injected parameter value
    found_param: Callable | None = None              # (diagnosis) -> (estimate, std_error)
    notes: str = ""
    twin: dict = field(default_factory=dict)        # keyword arguments of the diagnosis (the twin)
    null: Callable | None = None                     # seed -> a recording with nothing omitted from this twin
    null_twin: dict | None = None                    # the twin for the null data, if not ``twin``
    extra: dict = field(default_factory=dict)
    # (diagnosis) -> (estimate, std_error) whether or not the effect was accepted: a z computed only
    # over detected records is biased away from zero when the power is below 1 (winner's curse)
    estimate_param: Callable | None = None


# the Earth's rate and the g-sensitivity show as a bias present only while the gyro is on the
# table axis, against the gyro's bias instability, which is independent from one mounting to
# the next: many short mountings separate them best. (Upside-down mountings would flip the sign
# but also the table wobble's effective misalignment, which one model per axis cannot follow.)
TURN_REMOUNTS = {"dial_rates_dps": (20, 100), "mounts": ("p_up", "q_up", "r_up") * 4, "min_window_s": 8.0}


def earth_fraction_site(fraction: float):
    """The default lab moved to the latitude where the Earth's vertical rate Omega sin(lat) is
    ``fraction`` of Delft's (52 deg N); 0 <= fraction <= 1 / sin(52 deg) = 1.27."""
    s = fraction * math.sin(math.radians(Site().latitude_deg))
    if not 0.0 <= s <= 1.0:
        raise ConfigError(f"Earth-rate fraction {fraction} needs sin(latitude) = {s:.3f}, outside [0, 1]; "
                          "use 0 ... 1.27")
    return Site(latitude_deg=math.degrees(math.asin(s)))


def _turn(seed, g_sensitivity=0.0, slip_rings=False, slip_rms_V=None, earth_fraction=1.0):
    """A turn-table campaign (each axis up four times) whose gyros have a diagonal g-sensitivity
    ``g_sensitivity`` ((rad/s)/(m/s^2)) times (1, -1, 1). ``slip_rms_V`` (V) resizes the slip rings'
    contact noise (switched on); ``earth_fraction`` moves the lab to the latitude where the Earth's
    vertical rate Omega sin(lat) is that fraction of Delft's (1: Delft, 52 deg N; at most 1.27)."""
    kw = {} if earth_fraction == 1.0 else {"site": earth_fraction_site(earth_fraction)}
    camp = TurnTableCampaign(protocol=TurnTableProtocol(**TURN_REMOUNTS), seed=seed,
                             slip_rings=slip_rings or slip_rms_V is not None, **kw)
    camp.check_identifiable()
    table, lab, ss = camp.build()
    gyros = replace(lab.gyros, g_sensitivity_rad_s_per_m_s2=np.diag([1.0, -1.0, 1.0]) * g_sensitivity)
    if slip_rms_V is not None:
        lab = replace(lab, slip_rings=replace(lab.slip_rings, rms_V=float(slip_rms_V)))
    rig = table.simulate(camp.protocol, camp.start_time, random_streams.generator("campaign/turn-table/rig", seed))
    rec = replace(lab, gyros=gyros).measure(rig, ss)
    rec.meta["campaign"] = {"name": "turn-table", **camp.to_dict()}
    return rec


def _gyro_param(d, gyro, effect):
    for f in d["gyros"][gyro]["findings"]:
        if f["effect"] == effect:
            return f["parameters"][0]["estimate"], f["parameters"][0]["std_error"]
    return None


def _slip_ring_param(d, gyro):
    """(estimate, std_error) of the slip-ring refit (the noisiest angle bin's excess noise) on ``gyro``."""
    f = d["gyros"][gyro].get("scatter", {}).get("finding")
    return None if f is None else (f["parameters"][0]["estimate"], f["parameters"][0]["std_error"])


SHORT_THERMAL = {"low_C": -40, "high_C": 40, "step_C": 20, "soak_s": 2400, "attitude_dwell_s": 40}


def _thermal(seed, bias_hysteresis=None):
    """A short thermal campaign; ``bias_hysteresis`` (m/s^2, all three accelerometers) replaces the
    drawn bias hysteresis (0 removes the hysteresis, scale hysteresis included)."""
    camp = ThermalCampaign(profile=ThermalProfile(**SHORT_THERMAL), seed=seed)
    chamber, lab, ss = camp.build()
    if bias_hysteresis is not None:
        acc = replace(lab.accelerometers, bias_hysteresis_m_s2=np.full(3, float(bias_hysteresis)),
                      scale_hysteresis=lab.accelerometers.scale_hysteresis * (bias_hysteresis != 0))
        lab = replace(lab, accelerometers=acc)
    rig = chamber.simulate(camp.profile, camp.start_time)
    rec = lab.measure(rig, ss)
    rec.meta["campaign"] = {"name": "thermal", **camp.to_dict()}
    return rec


def _thermal_gap_truth(rec, axis="x"):
    """The branch gap H the noise-free twin of the same recording gives (the injected hysteresis
    as the six-position bias sees it through the play operator's state)."""
    twin = ThermalCalibration().fit(step_table(rec, channels=twin_channels(rec)))
    return twin.results_[f"acc_bias_{axis}"].coef("hysteresis")


def _channel_param(d, channel, effect):
    for f in d["channels"][channel]["findings"]:
        if f["effect"] == effect:
            return f["parameters"][0]["estimate"], f["parameters"][0]["std_error"]
    return None


def _simona(seed, **setup_kw):
    gain = setup_kw.pop("gain", 1.0)
    table = setup_kw.pop("table", TurnTableErrors(mains_hz=60.0, slip_const=0.0, slip_coeff=0.0))
    setup = SimonaSetup(voltmeter=AutoscaleVoltmeter(gain=(1.0, gain, gain)), table=table, **setup_kw)
    orig = FOGTriad.from_datasheet

    def no_k2(rng=None, **kw):  # gyros without nonlinearity or bias instability: the nominal model's gyros
        g = orig(rng, **kw)
        g.k2_per_rad_s[:] = 0.0
        g.bias_instability_rad_s = 0.0
        return g

    FOGTriad.from_datasheet = no_k2
    try:
        return simona_virtual(seed, setup)
    finally:
        FOGTriad.from_datasheet = orig


def _voltmeter_param(d, effect, name):
    """(estimate, std_error) of parameter ``name`` of the joint voltmeter finding ``effect``."""
    for f in d.get("voltmeter", {}).get("findings", []):
        if f["effect"] == effect:
            for p in f["parameters"]:
                if p["name"].endswith(name):
                    return p["estimate"], p["std_error"]
    return None


def _range_change(seed, step):
    return _simona(seed, gain=1.0 - step)


def _mains(seed, _size):
    return _simona(seed, table=TurnTableErrors(mains_hz=50.0, slip_const=0.0, slip_coeff=0.0))


def _slip(seed, s1):
    return _simona(seed, table=TurnTableErrors(mains_hz=60.0, slip_const=0.0, slip_coeff=s1))


def _param(d, axis, effect, k=0):
    for f in d["axes"][axis]["findings"]:
        if f["effect"] == effect:
            return f["parameters"][k]["estimate"], f["parameters"][k]["std_error"]
    return None


CASES = [
    Case("adc_crosstalk", "tilt_table", {("y", "adc_crosstalk"), ("z", "adc_crosstalk")}, crosstalk_recording, 2e-4,
         sizes=(1e-5, 2e-5, 5e-5, 1e-4, 2e-4),
         size_unit="settling residual c (V/V); the diagnosis reports the inverse-model coefficient -c/(s (1 - c)) "
                   "in m/s^2 per V, negative for a positive leak",
         truth_param=lambda rec: AdcCrosstalk().fitted(rec.truth, "acc_y")["c"],
         found_param=lambda d: _param(d, "y", "adc_crosstalk")),
    Case("building_vibration", "tilt_table", {(a, "building_vibration") for a in "xyz"}, pump_recording, 0.03,
         sizes=(0.001, 0.002, 0.005, 0.01, 0.03), size_unit="pump rms (m/s^2)"),
    Case("cable_fault_spikes", "tilt_table", {("y", "cable_fault_spikes")}, cable_recording, 0.5,
         sizes=(0.005, 0.02, 0.05, 0.2, 0.5), size_unit="spike rate (1/s)"),
    Case("axis_misalignment", "tilt_table", {(a, "axis_misalignment") for a in "xyz"},
         lambda seed, m: accelerometers_recording(seed, misalignment=m), 1e-3,
         sizes=(2e-6, 5e-6, 1e-5, 2e-5, 5e-5), size_unit="misalignment angle (rad)",
         truth_param=lambda rec: AxisMisalignment().fitted(recording_truth(rec), "acc_x")["m_xy"],
         found_param=lambda d: _param(d, "x", "axis_misalignment"),
         twin={"twin_model": "own_axis"}, null=lambda seed: accelerometers_recording(seed, misalignment=0.0)),
    Case("scale_nonlinearity", "tilt_table", {(a, "scale_nonlinearity") for a in "xyz"},
         lambda seed, k2: accelerometers_recording(seed, k2=k2, protocol=WIDE_TILT), 48e-6 / 9.80665,
         sizes=tuple(x * 1e-6 / 9.80665 for x in (5, 10, 20, 30, 48)), size_unit="k2 (1/(m/s^2))",
         truth_param=lambda rec: ScaleNonlinearity().fitted(recording_truth(rec), "acc_x")["k2"],
         found_param=lambda d: _param(d, "x", "scale_nonlinearity"),
         twin={"twin_model": "linear"}, null=lambda seed: accelerometers_recording(seed, k2=0.0, protocol=WIDE_TILT)),
    Case("earth_rate_left_out", "turn_table", {(a, "earth_rate_left_out") for a in "pqr"},
         lambda seed, f: _turn(seed, earth_fraction=f), 1.0, sizes=(0.25, 0.5, 0.75, 1.0, 1.25),
         size_unit="fraction of Delft's vertical Earth rate (latitude moved)",
         truth_param=lambda rec: EarthRateLeftOut().fitted(recording_truth(rec))["Omega_vertical"],
         found_param=lambda d: _gyro_param(d, "p", "earth_rate_left_out"),
         twin={"earth_rate": False}, null=lambda seed: _turn(seed), null_twin={"earth_rate": True},
         notes="g_sensitivity is named as indistinguishable"),
    Case("g_sensitivity", "turn_table", {(a, "g_sensitivity") for a in "pqr"},
         lambda seed, gs: _turn(seed, gs), 10 * DEG_PER_H_PER_G,
         sizes=tuple(x * DEG_PER_H_PER_G for x in (1, 2, 5, 10, 20)), size_unit="G (rad/s per m/s^2)",
         truth_param=lambda rec: GSensitivity().fitted(rec.truth, "gyro_p")["G"],
         found_param=lambda d: _gyro_param(d, "p", "g_sensitivity"), null=lambda seed: _turn(seed)),
    Case("slip_ring_noise", "turn_table", {(a, "slip_ring_noise") for a in "pqr"},
         lambda seed, rms: _turn(seed, slip_rms_V=rms), 20e-6, sizes=(1e-6, 2e-6, 5e-6, 1e-5, 2e-5),
         size_unit="ring contact noise rms (V), depth 8 at the rough spots (the seed's rings: 20 uV)",
         truth_param=lambda rec: SlipRingNoise().fitted(rec.truth, "gyro_p")["peak_excess_noise_rms_V"],
         found_param=lambda d: _slip_ring_param(d, "p"), null=lambda seed: _turn(seed),
         notes="parameter: the excess noise rms of the noisiest 10-degree angle bin over the median bin (V)"),
    Case("temperature_hysteresis", "thermal", {(f"acc_{a}", "temperature_hysteresis") for a in "xyz"},
         _thermal, 5e-3, sizes=(2e-5, 5e-5, 1e-4, 3e-4, 1e-3), size_unit="bias hysteresis (m/s^2)",
         truth_param=_thermal_gap_truth, found_param=lambda d: _channel_param(d, "acc_x", "temperature_hysteresis"),
         null=lambda seed: _thermal(seed, 0.0)),
    Case("instrument_range_change", "rate_table_rows", {("voltmeter", "instrument_range_change")}, _range_change, 0.01,
         sizes=(0.0005, 0.001, 0.002, 0.005, 0.01), size_unit="gain step (relative)",
         truth_param=lambda rec: InstrumentRangeChange().fitted(rec.truth)["relative_gain_step"],
         found_param=lambda d: _voltmeter_param(d, "instrument_range_change", "relative_gain_step")),
    Case("mains_rate_factor", "rate_table_rows", {("rate", "mains_rate_factor")}, _mains, 1.0),
    Case("table_slip", "rate_table_rows", {("rate", "table_slip")}, _slip, 0.03,
         sizes=(0.0003, 0.001, 0.003, 0.01, 0.03), size_unit="slip coefficient s1"),
]


# a table set by its rate readout (setting error 3e-4 relative, 1 sigma) with a constant slip, so the
# round times do not sit on the timer's grid; on the seed's default 3e-3 setting error a 0.01 s
# stopwatch is 0.2 sigma at 100 deg/s and cannot be told from the table's scatter in 24 rows
TIMER_TABLE = {"mains_hz": 60.0, "slip_const": 0.012, "slip_coeff": 0.0, "dial_setting_error": 3e-4}
TIMER_SLIP_RANGE = (0.005, 0.02)


def _timer(seed, q):
    """SIMONA rows timed by a stopwatch of resolution ``q`` (s): T = q round(T_true / q).

    The table's constant slip is drawn per record, uniform in ``TIMER_SLIP_RANGE`` (the seed's
    table ran 1-8 % slow, varying from day to day; the shortfall model's constant absorbs it). That
    moves T_true of every row by 20-70 ms, many q, so the rounding errors are uniform on
    [-q/2, q/2], variance q^2 / 12, independently from record to record. With the slip fixed, T_true
    varied only by the 3e-4 setting error (1.3 ms at the top rate, below q): every seed got nearly
    the same rounding errors, their variance was not q^2 / 12 (0.56-0.83 of it at q = 0.015 s on
    the informative rows), and the power curve was not monotonic in q."""
    slip = float(random_streams.generator("concealed/timer/table-slip", seed).uniform(*TIMER_SLIP_RANGE))
    rec = _simona(seed, table=TurnTableErrors(**{**TIMER_TABLE, "slip_const": slip}), stopwatch_resolution_s=q,
                  printed_round_decimals=None)
    rec.truth["timer"] = {"resolution_s": q, "sigma_T_s": q / math.sqrt(12), "table_slip_const": slip}
    return rec


def _timer_param(d):
    f = d["timer_resolution"].get("finding")
    return None if f is None else (f["parameters"][0]["estimate"], f["parameters"][0]["std_error"])


CASES += [
    Case("timer_quantisation", "rate_table_rows", {("rate", "timer_quantisation")}, _timer, 0.01,
         sizes=(0.005, 0.007, 0.01, 0.015, 0.02, 0.03), size_unit="stopwatch resolution q (s); table setting error 3e-4",
         truth_param=lambda rec: TimerQuantisation().fitted(rec.truth)["sigma_T_s"], found_param=_timer_param,
         estimate_param=lambda d: (d["timer_resolution"]["test"]["sigma_T_s"], d["timer_resolution"]["test"]["sigma_T_se_s"]),
         null=lambda seed: _timer(seed, 1e-6),
         notes="the twin times rounds exactly; parameter = the round-time error sigma_T (s) "
               "= q / sqrt(12) (see _timer)"),
]


def _mag_case(effect, size, sizes, unit, twin_model, expected=None, notes=""):
    """A magnetometer case (imurig.concealed.magnetometer): one joint analysis of the three axes ('mag')."""
    return Case(effect, "magnetometer", expected or {("mag", effect)}, lambda seed, s: mag_cases.case_recording(effect, seed, s),
                size, sizes=sizes, size_unit=unit, truth_param=lambda rec: mag_cases.truth_param(effect, rec),
                found_param=lambda d: mag_cases.found_param(effect, d), twin={"twin_model": twin_model},
                null=lambda seed: mag_cases.null_recording(seed, twin_model), notes=notes)


CASES += [
    _mag_case("hard_iron", 2000.0, (0.01, 0.03, 0.1, 0.3, 1.0), "hard iron |b| (nT)", "nominal"),
    _mag_case("soft_iron", 0.02, (1e-6, 3e-6, 1e-5, 3e-5, 1e-4), "soft iron s_xy (1)", "nominal"),
    _mag_case("misalignment", 2e-3, (1e-6, 3e-6, 1e-5, 3e-5, 1e-4), "rotation w_xy (rad)", "nominal"),
    _mag_case("local_field_anomaly", 300.0, (0.1, 0.3, 1.0, 3.0, 10.0), "anomaly |dB| (nT)", "calibrated",
              notes="the anomaly's component along the IGRF field is absorbed by the gains (indistinguishable)"),
    _mag_case("temperature_drift", 2.0, (0.01, 0.03, 0.1, 0.3, 1.0), "offset tempco (nT/K), air +3 K", "calibrated"),
    _mag_case("time_delay", 2e-3, (3e-6, 1e-5, 3e-5, 1e-4, 3e-4), "output delay (s)", "nominal"),
    _mag_case("installation", 1.0, (), "(the campaign's drawn hard and soft iron and misalignment)", "nominal",
              expected={("mag", "hard_iron"), ("mag", "soft_iron"), ("mag", "misalignment")}),
]


def _tilt_case(effect, expected, size, sizes, unit, twin, null_twin=None, notes=""):
    """A tilt-table case whose recordings come from imurig.concealed.tilt_table.case_recording."""
    return Case(effect, "tilt_table", expected, lambda seed, s: tilt_cases.case_recording(effect, seed, s), size,
                sizes=sizes, size_unit=unit, truth_param=lambda rec: tilt_cases.truth_param(effect, rec),
                found_param=lambda d: tilt_cases.found_param(effect, d), twin=twin, null_twin=null_twin,
                null=lambda seed: tilt_cases.null_case_recording(effect, seed), notes=notes)


CASES += [
    _tilt_case("time_delay", {("y", "time_delay")}, 1e-4, (2e-5, 4e-5, 6e-5, 1e-4, 1.6e-4),
               "acc_y's multiplexer skew 2 / f_mux (s)", {"dynamics": True, "skew_in_twin": False},
               null_twin={"dynamics": True},
               notes="the seed's 20 kHz scan: acc_x is slot 0 (no skew); acc_z's 0.2 ms is below what the slews "
                     "resolve on acc_z (only tilting moves it)"),
    _tilt_case("lever_arm", {("acc", "lever_arm")}, 0.02, (1e-4, 2e-4, 5e-4, 1e-3, 2e-3),
               "triad offset |dr_x| (m), pattern (1, -0.75, 0.5)", {"dynamics": True}),
    _tilt_case("wrong_local_gravity", {("acc", "wrong_local_gravity")}, 9.80665 / 9.81242231 - 1,
               (-5.9e-4, 0.05, 0.1, 0.2, 0.4), "eps = g_twin / g_true - 1", {"dynamics": True},
               notes="not identifiable at its realistic size: the position means absorb it into the scale factors "
                     "exactly; in the slews it equals a lever-arm error eps x 0.09 m along the phi axis (53 um for "
                     "standard against Delft gravity), far below the slews' resolution"),
    _tilt_case("temperature_drift", {(a, "temperature_drift") for a in "xyz"}, 70e-6 * 9.80665 * 2,
               tuple(x * 1e-6 * 9.80665 for x in (5, 10, 20, 50, 140)), "bias tempco (m/s^2/K), air drift 3 K/h", {}),
]


def found_effects(d: dict) -> set:
    """(channel, effect) pairs a diagnosis reports (tilt table or rate-table rows)."""
    if "magnetometer" in d:
        return mag_cases.found_effects(d)
    out = set()
    if "axes" in d:
        for a, e in d["axes"].items():
            out |= {(a, f["effect"]) for f in e["findings"]}
            out |= {(a, e["scatter"][k]["effect"]) for k in ("finding_spikes", "finding_vibration") if k in e["scatter"]}
        out |= {(f["channel"], f["effect"]) for f in d.get("dynamic", {}).get("findings", [])}
    if "channels" in d:
        for ch, e in d["channels"].items():
            out |= {(ch, f["effect"]) for f in e["findings"]}
    if "gyros" in d and "earth_rate_in_twin" in d:
        for g, e in d["gyros"].items():
            out |= {(g, f["effect"]) for f in e["findings"]}
            if "finding" in e.get("scatter", {}):
                out.add((g, e["scatter"]["finding"]["effect"]))
    elif "gyros" in d:
        if d.get("rate_factor"):
            out.add(("rate", "mains_rate_factor"))
        out |= {("rate", f["effect"]) for f in d["shortfall"]["diagnosis"]["findings"]}
        if d.get("timer_resolution", {}).get("finding"):
            out.add(("rate", "timer_quantisation"))
        if "voltmeter" in d:  # the joint analysis of the gyros read by one voltmeter
            out |= {("voltmeter", f["effect"]) for f in d["voltmeter"]["findings"]}
        else:
            for g, e in d["gyros"].items():
                out |= {(g, f["effect"]) for f in e["findings"]}
    return out


def diagnose_case(case: Case, rec, seed: int, null: bool = False) -> dict:
    """Diagnose ``rec`` against the case's twin (``null``: the twin of its null study)."""
    rng = np.random.default_rng(seed)
    twin = case.null_twin if null and case.null_twin is not None else case.twin
    if case.rig == "tilt_table":
        return diagnose_tilt_table(rec, rng, **twin)
    if case.rig == "turn_table":
        return diagnose_turn_table(rec, rng, **twin)
    if case.rig == "thermal":
        return diagnose_thermal(rec, rng, **twin)
    if case.rig == "magnetometer":
        return diagnose_magnetometer(rec, rng, **twin)
    return diagnose_rate_rows(rec, rng, n_sim=200)


def null_recording(case: Case, seed: int):
    """A recording with nothing omitted from the case's twin."""
    if case.null is not None:
        return case.null(seed)
    if case.rig == "thermal":
        return _thermal(seed)
    return small_tilt(seed) if case.rig == "tilt_table" else _simona(seed)


def null_groups() -> dict:
    """One representative case per distinct (rig, twin, null data): the null studies to run."""
    out = {}
    for c in CASES:
        twin = c.null_twin if c.null_twin is not None else c.twin
        key = c.rig + (f" (twin {twin})" if twin else "")
        out.setdefault(key, c)
    return out
