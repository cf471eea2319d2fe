"""Concealed-effect suite: recordings where one library effect is present at a chosen size
but absent from the nominal model, and null recordings with none. Shared by the tests and
``benchmarks/bench_diagnose.py`` (detection rate, false discoveries, parameter error, power).

Each case maps an effect size (in units of the noise where that is natural) to a recording,
and says which (channel, effect) pairs a correct diagnosis must report.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from imurig.rigs.tilt_table import TiltTableProtocol

SMALL_TILT = TiltTableProtocol(theta_deg=(0, 30, 60, 90), phi_deg=(0, 60, 120, 180, 240, 300), dwell_s=4.0,
                               settle_s=1.0, slew_rate_deg_s=30.0)


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
    extra: dict = field(default_factory=dict)


def _tilt(seed, **kw):
    from imurig.campaigns.tilt_table import TiltTableCampaign

    return TiltTableCampaign(protocol=SMALL_TILT, seed=seed, **kw).simulate()


def _crosstalk(seed, c):
    """Crosstalk of relative size c: choose f_mux so that exp(-1/(f tau)) = c."""
    tau = 0.59e-6
    f = -1.0 / (tau * math.log(c))
    return _tilt(seed, mux_frequency_hz=f)


def _pump(seed, rms):
    from dataclasses import replace

    from imurig.campaigns.tilt_table import TiltTableCampaign
    from imurig.sensors.disturbances import PumpVibration

    camp = TiltTableCampaign(protocol=SMALL_TILT, seed=seed, start_time="2005-06-14T10:00:00+02:00")
    table, lab, ss = camp.build()
    lab = replace(lab, pump=PumpVibration(rms_m_s2=rms, broadband_rms_m_s2=rms / 3))
    from imurig.sensors.noise import child_rng

    rig = table.simulate(camp.protocol, camp.start_time, child_rng(ss, "rig"))
    return lab.measure(rig, np.random.SeedSequence(seed, spawn_key=(1,)))


def _cable(seed, rate_hz):
    from dataclasses import replace

    from imurig.campaigns.tilt_table import TiltTableCampaign
    from imurig.sensors.disturbances import LooseCable
    from imurig.sensors.noise import child_rng

    camp = TiltTableCampaign(protocol=SMALL_TILT, seed=seed)
    table, lab, ss = camp.build()
    lab = replace(lab, cable=LooseCable(enabled=True, rate_hz=rate_hz))
    rig = table.simulate(camp.protocol, camp.start_time, child_rng(ss, "rig"))
    return lab.measure(rig, np.random.SeedSequence(seed, spawn_key=(1,)))


def _simona(seed, **setup_kw):
    from imurig.campaigns.turn_table import SimonaSetup, simona_virtual
    from imurig.rigs.turn_table import TurnTableErrors
    from imurig.sensors.gyro import FOGTriad
    from imurig.sensors.voltmeter import AutoscaleVoltmeter

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


def _range_change(seed, step):
    return _simona(seed, gain=1.0 - step)


def _mains(seed, _size):
    from imurig.rigs.turn_table import TurnTableErrors

    return _simona(seed, table=TurnTableErrors(mains_hz=50.0, slip_const=0.0, slip_coeff=0.0))


def _slip(seed, s1):
    from imurig.rigs.turn_table import TurnTableErrors

    return _simona(seed, table=TurnTableErrors(mains_hz=60.0, slip_const=0.0, slip_coeff=s1))


def _param(d, axis, effect):
    for f in d["axes"][axis]["findings"]:
        if f["effect"] == effect:
            return f["parameters"][0]["estimate"], f["parameters"][0]["std_error"]
    return None


CASES = [
    Case("adc_crosstalk", "tilt_table", {("y", "adc_crosstalk"), ("z", "adc_crosstalk")}, _crosstalk, 2e-4,
         sizes=(1e-5, 2e-5, 5e-5, 1e-4, 2e-4), size_unit="settling residual c (V/V)",
         truth_param=lambda rec: -rec.truth["chain"]["adc"]["crosstalk_coefficient"] / (
             rec.truth["sensors"]["accelerometers"]["sensitivity_V_per_m_s2"][1]
             * (1 - rec.truth["chain"]["adc"]["crosstalk_coefficient"])),
         found_param=lambda d: _param(d, "y", "adc_crosstalk")),
    Case("building_vibration", "tilt_table", {(a, "building_vibration") for a in "xyz"}, _pump, 0.03,
         sizes=(0.001, 0.002, 0.005, 0.01, 0.03), size_unit="pump rms (m/s^2)"),
    Case("cable_fault_spikes", "tilt_table", {("y", "cable_fault_spikes")}, _cable, 0.5,
         sizes=(0.005, 0.02, 0.05, 0.2, 0.5), size_unit="spike rate (1/s)"),
    Case("instrument_range_change", "rate_table_rows", {("voltmeter", "instrument_range_change")}, _range_change, 0.01,
         sizes=(0.0005, 0.001, 0.002, 0.005, 0.01), size_unit="gain step (relative)"),
    Case("mains_rate_factor", "rate_table_rows", {("rate", "mains_rate_factor")}, _mains, 1.0),
    Case("table_slip", "rate_table_rows", {("rate", "table_slip")}, _slip, 0.03,
         sizes=(0.0003, 0.001, 0.003, 0.01, 0.03), size_unit="slip coefficient s1"),
]


def found_effects(d: dict) -> set:
    """(channel, effect) pairs a diagnosis reports (tilt table or rate-table rows)."""
    out = set()
    if "axes" in d:
        for a, e in d["axes"].items():
            out |= {(a, f["effect"]) for f in e["findings"]}
            out |= {(a, e["scatter"][k]["effect"]) for k in ("finding_spikes", "finding_vibration") if k in e["scatter"]}
    if "gyros" in d:
        if d.get("rate_factor"):
            out.add(("rate", "mains_rate_factor"))
        out |= {("rate", f["effect"]) for f in d["shortfall"]["diagnosis"]["findings"]}
        if "voltmeter" in d:  # the joint analysis of the gyros read by one voltmeter
            out |= {("voltmeter", f["effect"]) for f in d["voltmeter"]["findings"]}
        else:
            for g, e in d["gyros"].items():
                out |= {(g, f["effect"]) for f in e["findings"]}
    return out


def diagnose_case(case: Case, rec, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    if case.rig == "tilt_table":
        from imurig.diagnose.tilt_table import diagnose_tilt_table

        return diagnose_tilt_table(rec, rng)
    from imurig.diagnose.rate_table import diagnose_rate_rows

    return diagnose_rate_rows(rec, rng, n_sim=200)


def null_recording(rig: str, seed: int):
    return _tilt(seed) if rig == "tilt_table" else _simona(seed)
