"""The tilt-table accelerometer campaign, end to end (seed sections 2, 3, 4.1-4.3).

    protocol -> TiltTable (MuJoCo + imperfections) -> truth at the IMU
      -> ImuLab sensor chain -> Recording (1 kHz)
      -> low-pass + 100 Hz -> per-position Huber M-estimates (the seed's medians: statistic="median")
      -> inverse-model least squares
      -> physical parameters vs injected truth -> report, summary.json, .rrd

``imurig campaign tilt-table`` streams the campaign (:func:`imurig.campaigns.tilt_stream.stream_campaign`:
bounded memory, ADC codes, the HDF5 file written as it goes); :meth:`TiltTableCampaign.simulate` gives
the same data as one in-memory 1 kHz Recording: one seed, one data set. A lab the stream does not model
(:func:`imurig.sensors.stream.unsupported`) runs the whole-record chain
(:meth:`imurig.sensors.chain.ImuLab.measure`) in both.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace

import numpy as np

from imurig.calibration.accelerometer import (AXES, INPUTS, MODELS, AccelerometerCalibration, injected_parameters)
from imurig.calibration.preprocess import segment_statistic
from imurig.calibration.regression import check_identifiable, fit_ols
from imurig.calibration.terms import TermLibrary
from imurig.campaigns.delft_2005 import Delft2005, check_lab
from imurig.campaigns.delft_2005_imu import ACCELEROMETER_UNITS, accelerometer_unit  # noqa: F401 (re-exported)
from imurig.campaigns.tilt_rig import build_table
from imurig.campaigns.tilt_stream import record_campaign
# the reference and the fit are calibration maths (shared with the diagnosis); the campaign's API re-exports them
from imurig.calibration.tilt_reference import calibrate, tilt_table_reference  # noqa: F401
from imurig.kernel import random_streams
from imurig.kernel.errors import ConfigError, UnidentifiableTermsError
from imurig.kernel.recording import Recording
from imurig.rigs.tilt_table import TiltTable, TiltTableProtocol, specific_force_C
from imurig.sensors.accelerometer import QFlexTriad
from imurig.sensors.adc import DAQ6036E
from imurig.sensors.chain import DEFAULT_SCAN, ImuLab
from imurig.sensors.disturbances import LooseCable, PeopleTransients, PumpVibration
from imurig.kernel.site import Site

#: per-position statistics of the calibration (huber: the default; median: the seed's)
STATISTICS = ("huber", "median", "mean")
#: z-score bound used to call an estimate consistent with the injected value
Z_BOUND = 4.0


@dataclass
class TiltTableCampaign:
    """Settings of a virtual tilt-table campaign. Defaults reproduce the seed's final
    calibration: evening hours (pump and air conditioning off), repaired cable, NRSE
    wiring, 20 kHz multiplexing, full 10 x 12 x 2 protocol."""

    protocol: TiltTableProtocol = field(default_factory=TiltTableProtocol)
    seed: int = 2005
    start_time: str = "2005-06-14T18:00:00+02:00"
    model: str = "physical"
    #: per-position statistic of the calibration: huber (robust M-estimate), median (the seed's) or mean
    statistic: str = "huber"
    draw_sensor_errors: bool = True
    draw_table_errors: bool = True
    survey_accuracy_arcsec: float = 2.0
    mux_frequency_hz: float = 20e3
    grounding: str = "NRSE"
    crosstalk: bool = True
    pump: bool = True
    people: bool = True
    loose_cable: bool = False
    scan_list: tuple = DEFAULT_SCAN
    #: further lab disturbances (effect objects of stage specific_force or analog), e.g. a lab's own
    lab_effects: tuple = ()
    site: Site = field(default_factory=Site)
    #: "quiet" (default) or "delft-2005": the seed's lab imperfections at sizes fitted to Tab. 4.3
    #: (:mod:`imurig.campaigns.delft_2005`; the table's setting error, the y line's settling, the lab's sources)
    lab: str = "quiet"
    #: "drawn" (default: errors drawn within the datasheet), "tab-4.6": the seed's own unit as its Tab. 4.6
    #: measured it (:class:`imurig.campaigns.delft_2005_imu.Tab46Triad`; temperature terms and noise drawn), or
    #: "tab-4.6-affine": that unit's scale, bias and misalignment alone
    accelerometers: str = "drawn"

    def to_dict(self) -> dict:
        d = asdict(self)
        d["scan_list"] = list(self.scan_list)
        d["lab_effects"] = [{"effect": e.name, **e.settings()} for e in self.lab_effects]
        return d

    # ---------------------------------------------------------------- setup
    def build(self) -> tuple[TiltTable, ImuLab, np.random.SeedSequence]:
        """Rig and sensor chain with their (seeded) errors, and the chain's stream
        (``campaign/tilt-table/sensor-chain``, :mod:`imurig.kernel.random_streams`)."""
        table = build_table(self.seed, self.protocol, self.draw_table_errors, self.survey_accuracy_arcsec,
                            self.site, check_lab(self.lab))
        preset = Delft2005.fitted() if self.lab == "delft-2005" else None
        sensor_rng = random_streams.generator("sensor_errors", self.seed)
        base = ImuLab.draw(sensor_rng) if self.draw_sensor_errors else ImuLab()
        base = replace(base, accelerometers=accelerometer_unit(base.accelerometers, self.accelerometers))
        adc = DAQ6036E(scan_list=tuple(self.scan_list), mux_frequency_hz=self.mux_frequency_hz,
                       grounding=self.grounding, crosstalk_enabled=self.crosstalk)
        effects = tuple(self.lab_effects)
        if preset is not None:
            adc = replace(adc, settling_tau_s=preset.settling_tau_s, channel_settling_tau_s=preset.channel_settling(),
                          channel_slow_settling=preset.channel_slow_settling())
            effects = effects + preset.effects()
        lab = replace(base, adc=adc,
                      pump=PumpVibration(enabled=self.pump, **({"rms_m_s2": preset.pump_rms_m_s2} if preset else {})),
                      people=PeopleTransients(enabled=self.people),
                      cable=LooseCable(enabled=self.loose_cable), effects=effects)
        return table, lab, random_streams.seed_sequence("campaign/tilt-table/sensor-chain", self.seed)

    def check_identifiable(self) -> None:
        """Refuse a protocol whose positions cannot separate the model's terms (before simulating)."""
        if self.statistic not in STATISTICS:
            raise ConfigError(f"tilt-table campaign: statistic must be one of {', '.join(STATISTICS)}, got "
                              f"{self.statistic!r}")
        self.protocol.validate()
        if self.model in ("stepwise", "backward"):
            model = "linear"
        else:
            model = self.model
        segs = {"theta": np.array([p[1] for p in self.protocol.positions()]),
                "phi": np.array([p[2] for p in self.protocol.positions()]),
                "mount": np.array([p[0] for p in self.protocol.positions()])}
        f = np.concatenate([specific_force_C(segs["theta"][segs["mount"] == m], segs["phi"][segs["mount"] == m],
                                             m, self.site.gravity_m_s2) for m in dict.fromkeys(segs["mount"])])
        inputs = {n: f[:, j] for j, n in enumerate(INPUTS)}
        for a in AXES:
            lib = MODELS[model](a)
            try:
                check_identifiable(lib.design(inputs), lib.names)
            except UnidentifiableTermsError as e:
                raise UnidentifiableTermsError(
                    f"this schedule ({len(self.protocol.theta_deg)} tilt angle(s) {list(self.protocol.theta_deg)} "
                    f"deg, phi {list(self.protocol.phi_deg)} deg, runs {list(self.protocol.runs)}) cannot identify "
                    f"the '{model}' model of A_{a}: {e}", e.terms) from None

    def simulate(self) -> Recording:
        """Simulate the campaign: the 1 kHz Recording with truth that ``imurig campaign tilt-table`` writes
        for the same seed, bit for bit (:func:`imurig.campaigns.tilt_stream.record_campaign`: the streamed
        chain, volts = ADC code * lsb_V; the whole-record chain where the stream does not model the lab)."""
        return record_campaign(self)


# -------------------------------------------------------------------- analysis
def compare_with_truth(cal: AccelerometerCalibration, truth: dict | None) -> list[dict]:
    """Every estimated physical parameter with its injected value and z = (est - inj) / se."""
    params = cal.physical_parameters()
    inj = injected_parameters(truth) if truth else {}
    for p in params:
        v = inj.get(p["name"])
        p["injected"] = None if v is None else float(v)
        if v is not None and p["std_error"] > 0:
            p["z"] = (p["estimate"] - v) / p["std_error"]
            p["within_bound"] = bool(abs(p["z"]) <= Z_BOUND)
        else:
            p["z"] = None
            p["within_bound"] = None
    return params


def coefficient_table(cal: AccelerometerCalibration, rec100: Recording) -> list[dict]:
    """Every inverse-model coefficient as {name, unit, injected, estimate, std_error, z}.

    'injected' is what the same model gives on the noise-free twin of the experiment: the
    true sensor (from the recording's truth) fed with the true static specific force of
    each position (truth-signal medians), regressed on the same reference. It is None for
    a recording without truth.
    """
    twin = None
    if rec100.truth and "f_C_x" in rec100.truth_signals:
        t = rec100.truth["sensors"]["accelerometers"]
        fields = {k: t[k] for k in QFlexTriad.__dataclass_fields__ if k in t and k != "noise_bands"}
        triad = QFlexTriad(**fields)
        f_true = segment_statistic(rec100, [f"f_C_{a}" for a in AXES], "median", source="truth_signals")
        u_true = triad.ideal_voltage(f_true) / cal.sensitivity_
        ref, _, _ = tilt_table_reference(rec100)
        inputs = {n: u_true[:, j] for j, n in enumerate(INPUTS)}
        twin = {}
        for j, a in enumerate(AXES):
            lib = TermLibrary.from_names(cal.results_[a].names)
            twin[a] = fit_ols(lib.design(inputs), ref[:, j], lib.names)
    rows = []
    for a in AXES:
        r = cal.results_[a]
        lib = TermLibrary.from_names(r.names)
        for term, est, se in zip(lib, r.coef_, r.std_error_):
            unit = {0: "m/s^2", 1: "1"}.get(term.degree, f"(m/s^2)^{1 - term.degree}")
            inj = None if twin is None else float(twin[a].coef(term.name))
            rows.append({"name": f"A_{a}:{term.name}", "unit": unit, "injected": inj, "estimate": float(est),
                         "std_error": float(se), "z": None if inj is None or se == 0 else (est - inj) / se})
    return rows
