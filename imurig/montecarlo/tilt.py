"""The tilt-table campaign as a Monte-Carlo run (seed 4.3).

One run, from its stream ``montecarlo/run`` (:mod:`imurig.kernel.random_streams`):

    draw table errors (TiltTableErrors.draw), survey them (TableSurvey.measure), draw the
    sensors (ImuLab.draw), apply user-set distributions
      -> rig truth at the IMU for every acquisition window
      -> ImuLab sensor chain -> Recording (100 Hz averaged logging by default)
      -> per-position statistics (Huber M-estimates by default; the seed's medians with
         statistic="median") -> inverse-model least squares (imurig.campaigns.tilt_table.calibrate)
      -> parameter rows {name, unit, injected, estimate, std_error, z, within_bound, crlb}

The Monte-Carlo schedule. The seed's campaign logs every channel at 1 kHz for 15 s per
position (7.4 M samples, ~40 s per run with the MuJoCo slews). The Monte-Carlo default keeps
the seed's 240 positions and 15 s dwell but logs at 100 Hz, each sample the mean of ten
1 kHz conversions (the lab's averaged logging, as the thermal and magnetometer campaigns
log), and keeps only the acquisition windows ("For every position, 15 sec of data was
saved", seed 4.3.2): 360 k samples, about 1 s per run. ``logging="direct"`` with
``sample_rate_hz=1000`` gives the seed's own logger (lowpass + downsample as in the campaign).

The rig: ``rig="static"`` (default) evaluates the closed-form truth of the rest windows,
``rig="mujoco"`` runs the full MuJoCo table (:mod:`imurig.montecarlo.tilt_rig`). The
Cramér-Rao bound of each run: :mod:`imurig.montecarlo.tilt_crlb`.
"""
from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np

from imurig.calibration.accelerometer import injected_parameters
from imurig.calibration.preprocess import lowpass_downsample
from imurig.campaigns.tilt_table import (
    STATISTICS,
    Z_BOUND,
    TiltTableCampaign,
    calibrate,
    compare_with_truth,
)
from imurig.kernel.errors import ConfigError, ScheduleError
from imurig.kernel.random_streams import child_generator, child_seed_sequence
from imurig.kernel.recording import Recording
from imurig.kernel.site import Site
from imurig.kernel.units import ARCMIN, ARCSEC
from imurig.montecarlo.distributions import Source
from imurig.montecarlo.distributions import draw as draw_source
from imurig.montecarlo.rows import complete_rows, plain
from imurig.montecarlo.tilt_crlb import crlb
from imurig.montecarlo.tilt_rig import keep_windows, layout_key, static_rig, table_protocol, window_layout
from imurig.rigs.tilt_table import TableSurvey, TiltTable, TiltTableErrors
from imurig.sensors.adc import DAQ6036E
from imurig.sensors.chain import DEFAULT_SCAN, ImuLab
from imurig.sensors.disturbances import PeopleTransients, PumpVibration

THETA_SEED = [0.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0, 90.0]
PHI_12 = [float(v) for v in range(0, 360, 30)]
PHI_6 = [float(v) for v in range(0, 360, 60)]

#: seed Table 4.7: 120 min for the 10 tilt angles x 12 positions of one mounting with 15 s
#: acquisition -> 60 s per position, i.e. 45 s to set and check the angles besides the dwell
SEED_SETTING_OVERHEAD_S = 45.0
SEED_WARMUP_S = 15 * 60.0

SOURCES = {s.name: s for s in (
    Source("accelerometer.bias_m_s2", "m/s^2", (3,), "bias b of each Q-Flex (datasheet: uniform within 8 mg)"),
    Source("accelerometer.scale_factor_rel", "1", (3,), "relative scale-factor error of K1 (datasheet: "
           "uniform within 1 %)"),
    Source("accelerometer.misalignment_rad", "rad", (3, 3), "input-axis misalignment M, off-diagonal "
           "(datasheet: uniform within 2 mrad)"),
    Source("accelerometer.k2_per_m_s2", "1/(m/s^2)", (3,), "second-order nonlinearity (datasheet: uniform "
           "within 48 ug/g^2)"),
    Source("table.theta_zero_rad", "rad", (), "levelling error about the theta axis (seed 4.3.1: ~1 arcmin)"),
    Source("table.level_x_rad", "rad", (), "base tilt about x (below the inclinometer's accuracy)"),
    Source("table.phi_zero_rad", "rad", (), "phi-plane error of each mounting (seed 4.3.1: 80-105 arcmin "
           "uniform)"),
)}


class TiltTableMC:
    """The tilt-table campaign for Monte-Carlo studies (see the module doc)."""

    name = "tilt-table"

    # ------------------------------------------------------------ settings
    def default_params(self) -> dict:
        return {"theta_deg": list(THETA_SEED), "phi_deg": list(PHI_12), "mounts": ["z_down", "z_up"],
                "dwell_s": 15.0, "settle_s": 2.0, "slew_rate_deg_s": 6.0, "remount_s": 900.0,
                "sample_rate_hz": 100.0, "logging": "averaged", "model": "physical", "statistic": "huber",
                "start_time": "2005-06-14T18:00:00+02:00", "survey_accuracy_arcsec": 2.0,
                "setting_resolution_arcmin": 0.25, "mux_khz": 20.0, "grounding": "NRSE", "pump": True,
                "people": True, "rig": "static"}

    def validate(self, params: dict | None) -> dict:
        p = self.default_params()
        unknown = set(params or {}) - set(p)
        if unknown:
            raise ConfigError(f"unknown tilt-table setting(s) {sorted(unknown)}; known: {sorted(p)}")
        p.update(params or {})
        for k in ("theta_deg", "phi_deg"):
            p[k] = [float(v) for v in p[k]]
        p["mounts"] = [str(m) for m in p["mounts"]]
        if p["logging"] not in ("averaged", "direct"):
            raise ConfigError(f"logging must be 'averaged' or 'direct', got {p['logging']!r}")
        if p["rig"] not in ("static", "mujoco"):
            raise ConfigError(f"rig must be 'static' (closed-form rest windows) or 'mujoco', got {p['rig']!r}")
        if p["statistic"] not in STATISTICS:
            raise ConfigError(f"statistic must be one of {', '.join(STATISTICS)} (huber: the default, median: the "
                              f"seed's), got {p['statistic']!r}")
        if p["model"] not in ("physical", "linear", "cross"):
            raise ConfigError(f"model must be physical, linear or cross (fixed term sets), got {p['model']!r}")
        rate = float(p["sample_rate_hz"])
        if p["logging"] == "averaged" and (rate > 1000 or abs(1000 / rate - round(1000 / rate)) > 1e-9):
            raise ScheduleError(f"averaged logging needs a rate that divides the 1 kHz converter rate, got {rate} Hz")
        if p["logging"] == "direct" and rate > 100 and abs(rate / 100 - round(rate / 100)) > 1e-9:
            raise ScheduleError(f"direct logging at {rate} Hz: the calibration low-passes to 100 Hz, so the rate "
                                "must be a whole multiple of 100 Hz")
        for k in ("survey_accuracy_arcsec", "setting_resolution_arcmin"):
            if not (math.isfinite(p[k]) and p[k] >= 0):
                raise ConfigError(f"{k} must be >= 0, got {p[k]}")
        camp = TiltTableCampaign(protocol=self.protocol(p), model=p["model"])
        camp.check_identifiable()  # ScheduleError / UnidentifiableTermsError before any run
        return p

    def sources(self) -> dict[str, Source]:
        return SOURCES

    protocol = staticmethod(table_protocol)

    def lab_time(self, p: dict) -> dict:
        """Lab time of the schedule: the virtual rig's (slews, settling, dwell, remount) and the
        seed's Table 4.7 rates (15 min warm-up, 60 s per position at 15 s dwell, remount)."""
        lay = window_layout(layout_key(p))
        npos = len(p["theta_deg"]) * len(p["phi_deg"])
        nruns = len(p["mounts"])
        rig_s = nruns * lay["run_s"] + (nruns - 1) * p["remount_s"]
        seed_s = SEED_WARMUP_S + nruns * npos * (p["dwell_s"] + SEED_SETTING_OVERHEAD_S) + (nruns - 1) * p["remount_s"]
        return {"positions": nruns * npos, "dwell_s": p["dwell_s"], "acquiring_s": nruns * npos * p["dwell_s"],
                "rig_time_s": rig_s, "lab_time_seed_rates_s": seed_s,
                "samples": int(lay["n_window"] * nruns), "sample_rate_hz": p["sample_rate_hz"]}

    def table_4_7(self, p: dict) -> dict:
        """The seed's Table 4.7 rows for this schedule (seconds)."""
        return table_47(self, p)

    def schedules(self) -> dict[str, dict]:
        """Design-of-experiments variants (issue 7): 12 vs 6 phi positions, 15 vs 60 s dwell."""
        return {"12 phi, 15 s (seed)": {}, "6 phi, 15 s": {"phi_deg": PHI_6},
                "12 phi, 60 s": {"dwell_s": 60.0}, "6 phi, 60 s": {"phi_deg": PHI_6, "dwell_s": 60.0}}

    # ------------------------------------------------------------ one run
    def draw_lab(self, p: dict, ss: np.random.SeedSequence, distributions: dict | None = None):
        """Table errors, survey and sensor chain of one virtual lab, drawn from ``ss``."""
        dist = distributions or {}
        errors = TiltTableErrors.draw(child_generator(ss, "run/table"), tuple(p["mounts"]))
        over = {}
        if "table.theta_zero_rad" in dist:
            over["theta_zero_rad"] = float(draw_source(dist["table.theta_zero_rad"],
                                                       child_generator(ss, "run/user_theta_zero")))
        if "table.level_x_rad" in dist:
            over["level_x_rad"] = float(draw_source(dist["table.level_x_rad"],
                                                    child_generator(ss, "run/user_level_x")))
        if "table.phi_zero_rad" in dist:
            r = child_generator(ss, "run/user_phi_zero")
            over["phi_zero_rad"] = {m: float(draw_source(dist["table.phi_zero_rad"], r)) for m in p["mounts"]}
        errors = replace(errors, setting_resolution_rad=p["setting_resolution_arcmin"] * ARCMIN, **over)
        survey = TableSurvey.measure(errors, child_generator(ss, "run/survey"),
                                     p["survey_accuracy_arcsec"] * ARCSEC)
        lab = ImuLab.draw(child_generator(ss, "run/sensor_errors"))
        acc = lab.accelerometers
        if "accelerometer.bias_m_s2" in dist:
            acc.bias_m_s2 = draw_source(dist["accelerometer.bias_m_s2"], child_generator(ss, "run/user_bias"))
        if "accelerometer.scale_factor_rel" in dist:
            nominal = acc.nominal_sensitivity_V_per_m_s2() / acc.load_resistor_ohm
            acc.k1_A_per_m_s2 = nominal * (1 + draw_source(dist["accelerometer.scale_factor_rel"],
                                                           child_generator(ss, "run/user_scale")))
        if "accelerometer.misalignment_rad" in dist:
            M = draw_source(dist["accelerometer.misalignment_rad"],
                            child_generator(ss, "run/user_misalignment"))
            np.fill_diagonal(M, 0.0)
            acc.misalignment_rad = M
        if "accelerometer.k2_per_m_s2" in dist:
            acc.k2_per_m_s2 = draw_source(dist["accelerometer.k2_per_m_s2"], child_generator(ss, "run/user_k2"))
        averaging = round(1000 / p["sample_rate_hz"]) if p["logging"] == "averaged" else 1
        lab = replace(lab, adc=DAQ6036E(scan_list=DEFAULT_SCAN, sample_rate_hz=float(p["sample_rate_hz"]),
                                        mux_frequency_hz=p["mux_khz"] * 1e3, grounding=p["grounding"],
                                        averaging=averaging),
                      pump=PumpVibration(enabled=bool(p["pump"])), people=PeopleTransients(enabled=bool(p["people"])))
        return errors, survey, lab

    def simulate(self, p: dict, ss: np.random.SeedSequence, distributions: dict | None = None) -> Recording:
        """The Recording of one run (with truth), as the estimator sees it."""
        errors, survey, lab = self.draw_lab(p, ss, distributions)
        site = Site()
        if p["rig"] == "mujoco":
            table = TiltTable(errors=errors, survey=survey, site=site)
            rig = table.simulate(self.protocol(p), p["start_time"], child_generator(ss, "run/rig"))
            rig = keep_windows(rig)
        else:
            rig = static_rig(p, errors, survey, child_generator(ss, "run/rig"), site)
        rig.meta["averaged_logging"] = p["logging"] == "averaged"
        rec = lab.measure(rig, child_seed_sequence(ss, "run/sensor-chain"))
        rec.meta["campaign"] = {"name": "tilt-table (Monte-Carlo)", **p}
        return rec

    def run(self, p: dict, ss: np.random.SeedSequence, distributions: dict | None = None, estimator=None) -> dict:
        t0 = time.perf_counter()
        rec = self.simulate(p, ss, distributions)
        t1 = time.perf_counter()
        if estimator is None:
            processed = rec if rec.sample_rate_hz <= 100.0 + 1e-9 else lowpass_downsample(rec)
            cal = calibrate(rec, model=p["model"], statistic=p["statistic"], processed=processed)
            rows = compare_with_truth(cal, rec.truth)
        else:
            rows = complete_rows(estimator(rec.without_truth()), injected_parameters(rec.truth), Z_BOUND)
        t2 = time.perf_counter()
        bound = crlb(p, rec)
        for r in rows:
            r["crlb"] = bound.get(r["name"])
        t3 = time.perf_counter()
        return {"rows": [plain(r) for r in rows],
                "info": {"samples": int(rec.n), "channels": len(rec.channels), "simulate_s": t1 - t0,
                         "estimate_s": t2 - t1, "crlb_s": t3 - t2}}


def table_47(campaign, params: dict) -> dict:
    """The seed's Table 4.7 rows for a tilt-table schedule, at the seed's rates (seconds)."""
    per_pos = params["dwell_s"] + SEED_SETTING_OVERHEAD_S
    nphi, nth, nm = len(params["phi_deg"]), len(params["theta_deg"]), len(params["mounts"])
    lab = campaign.lab_time(params)
    return {"warm-up": SEED_WARMUP_S, "acquiring time per position": params["dwell_s"],
            f"{nphi} positions in the phi plane": nphi * per_pos,
            f"{nth} tilt angles (one mounting)": nth * nphi * per_pos,
            f"complete calibration ({nm} mountings)": lab["lab_time_seed_rates_s"],
            "virtual rig time (slews, settling, dwell, remount)": lab["rig_time_s"]}


TILT_TABLE = TiltTableMC()
