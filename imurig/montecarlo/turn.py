"""The turn-table gyro campaign as a Monte-Carlo run (seed 4.4), and its Cramér-Rao bound.

One run, from its stream ``montecarlo/run`` (:mod:`imurig.kernel.random_streams`):

    draw the sensors (ImuLab.draw, FOG triad from its datasheet), apply user-set distributions
      -> the Genisco C181 in MuJoCo (TurnTable.simulate: mains factor, slip, dial setting error,
         ripple, wobble, index pulses) -> ImuLab sensor chain (FOG, slip rings, DAQ, timers)
      -> whole-round windows by the timer -> GLS inverse-model fit
         (imurig.calibration.gyro.GyroCalibration, the campaign's own calibration)
      -> parameter rows {name, unit, injected, estimate, std_error, z, within_bound, crlb}

Protocols. ``quick`` (the default, ~1 s per run): dial rates (10, 20, 40, 80, 100) deg/s,
both directions, p, q and r up, at least 8 s of whole rounds per step, logged at 200 Hz.
``full``: the seed's final calibration (4.4.4): dial rates (1, 2, 4, 8, 10, 20, 40, 80, 100)
deg/s (true rate x 5/6 on 50 Hz mains), both directions, three mountings, at least 10 s of
whole rounds, logged at 1 kHz; one round at 1 deg/s on the dial lasts ~7.5 min, so a full
run simulates ~1.5 h of table time (~20 s per run). ``schedules()`` gives the
design-of-experiments pair of issue 7: the seed's 9 rates against the 15 rates of its timer
study (4.4.3: 1 ... 500 deg/s). The Cramér-Rao bound of each run: :mod:`imurig.montecarlo.turn_crlb`.

The MuJoCo trajectory depends on the draw (dial setting errors per step), so nothing of the
rig is cached across runs.
"""
from __future__ import annotations

import math
import time
from dataclasses import replace
from typing import ClassVar

import numpy as np

from imurig.calibration.gyro import GyroCalibration, injected_parameters, round_windows
from imurig.campaigns.turn_table import (
    TIMERS,
    Z_BOUND,
    TurnTableCampaign,
    gyro_parameters,
)
from imurig.kernel.errors import ConfigError, ScheduleError
from imurig.kernel.random_streams import child_generator, child_seed_sequence
from imurig.kernel.recording import Recording
from imurig.kernel.site import Site
from imurig.kernel.units import DEG
from imurig.montecarlo.distributions import Source
from imurig.montecarlo.distributions import draw as draw_source
from imurig.montecarlo.rows import complete_rows, plain
from imurig.montecarlo.turn_crlb import crlb
from imurig.rigs.turn_table import (
    TurnTable,
    TurnTableErrors,
    TurnTableProtocol,
    _profile,
)
from imurig.sensors.adc import DAQ6036E
from imurig.sensors.chain import TURN_TABLE_SCAN, ImuLab
from imurig.sensors.disturbances import SlipRingNoise

#: dial rates (deg/s) of the seed's final gyro calibration (4.4.4) and of its timer study (4.4.3)
SEED_9_RATES = [1.0, 2.0, 4.0, 8.0, 10.0, 20.0, 40.0, 80.0, 100.0]
SEED_15_RATES = [1.0, 2.0, 4.0, 8.0, 10.0, 20.0, 40.0, 60.0, 80.0, 100.0, 150.0, 200.0, 300.0, 400.0, 500.0]
QUICK_RATES = [10.0, 20.0, 40.0, 80.0, 100.0]

#: seed 4.8: "For the final gyroscope calibration 16 measurements per gyro were taken. The time
#: needed was approximately 60 min per gyro inclusive assembly and checking of the datas."
SEED_MIN_PER_GYRO = 60.0
SEED_WARMUP_S = 15 * 60.0

PRESETS = {
    "quick": {"dial_rates_dps": QUICK_RATES, "min_window_s": 8.0, "sample_rate_hz": 200.0},
    "full": {"dial_rates_dps": SEED_9_RATES, "min_window_s": 10.0, "sample_rate_hz": 1000.0},
}

SOURCES = {s.name: s for s in (
    Source("gyro.bias_rad_s", "rad/s", (3,), "turn-on bias of each FOG (datasheet: N(0, 0.003 deg/s))"),
    Source("gyro.scale_factor_rel", "1", (3,), "relative scale-factor error (datasheet: uniform within 2 %)"),
    Source("gyro.misalignment_rad", "rad", (3, 3), "input-axis misalignment M, off-diagonal (datasheet: uniform "
           "within 2 mrad)"),
    Source("gyro.k2_per_rad_s", "1/(rad/s)", (3,), "scale-factor nonlinearity (datasheet: uniform within "
           "2e-6 per deg/s)"),
    Source("table.wobble_rad", "rad", (), "platform tilt against the spin axis (default fixed 20 arcsec)"),
)}


class TurnTableMC:
    """The turn-table gyro campaign for Monte-Carlo studies (see the module doc)."""

    name = "turn-table"
    doe_groups: ClassVar[dict] = {"sensitivity": ("sensitivity_", 1e6, "ppm of SF"), "misalignment": ("misalignment_", 1e6, "µrad"),
                  "bias": ("bias_", 3600 / DEG, "deg/h"), "nonlinearity": ("nonlinearity_", 1e6 * DEG, "ppm/(deg/s)")}

    # ------------------------------------------------------------ settings
    def default_params(self) -> dict:
        return {"protocol": "quick", **PRESETS["quick"], "directions": [1, -1], "mounts": ["p_up", "q_up", "r_up"],
                "settle_s": 4.0, "ramp_s": 2.0, "remount_s": 600.0, "timer": "hp6700", "model": "physical",
                "gls": True, "slip_rings": True, "mains_hz": 50.0, "start_time": "2005-06-15T18:00:00+02:00"}

    def validate(self, params: dict | None) -> dict:
        params = dict(params or {})
        preset = params.get("protocol", "quick")
        if preset not in PRESETS:
            raise ConfigError(f"turn-table protocol must be one of {sorted(PRESETS)}, got {preset!r}")
        p = self.default_params()
        unknown = set(params) - set(p)
        if unknown:
            raise ConfigError(f"unknown turn-table setting(s) {sorted(unknown)}; known: {sorted(p)}")
        p.update(PRESETS[preset])
        p.update(params)
        p["dial_rates_dps"] = [float(v) for v in p["dial_rates_dps"]]
        p["directions"] = [int(v) for v in p["directions"]]
        p["mounts"] = [str(m) for m in p["mounts"]]
        for k in ("min_window_s", "sample_rate_hz", "settle_s", "ramp_s", "remount_s", "mains_hz"):
            p[k] = float(p[k])
            if not (math.isfinite(p[k]) and p[k] >= 0):
                raise ConfigError(f"{k} must be a finite number >= 0, got {p[k]}")
        if p["timer"] not in TIMERS:
            raise ConfigError(f"timer must be one of {TIMERS}, got {p['timer']!r}")
        if p["model"] not in ("physical", "linear"):
            raise ConfigError(f"model must be 'physical' or 'linear' (fixed term sets with physical parameters), "
                              f"got {p['model']!r}")
        if p["sample_rate_hz"] > 1000:
            raise ScheduleError(f"the DAQ-6036E logs at most 1000 Hz, got {p['sample_rate_hz']:g} Hz")
        if p["model"] == "linear":
            raise ConfigError("the Monte-Carlo turn-table study compares the 15 physical parameters (with the "
                              "nonlinearity); use model 'physical'")
        # ScheduleError / UnidentifiableTermsError before any run
        self.campaign(p).check_identifiable()
        return p

    def sources(self) -> dict[str, Source]:
        return SOURCES

    @staticmethod
    def protocol(p: dict) -> TurnTableProtocol:
        return TurnTableProtocol(dial_rates_dps=tuple(p["dial_rates_dps"]), directions=tuple(p["directions"]),
                                 mounts=tuple(p["mounts"]), min_window_s=p["min_window_s"], settle_s=p["settle_s"],
                                 ramp_s=p["ramp_s"], remount_s=p["remount_s"], sample_rate_hz=p["sample_rate_hz"])

    def campaign(self, p: dict) -> TurnTableCampaign:
        return TurnTableCampaign(protocol=self.protocol(p), timer=p["timer"], model=p["model"],
                                 slip_rings=bool(p["slip_rings"]), mains_hz=p["mains_hz"], start_time=p["start_time"])

    def schedules(self) -> dict[str, dict]:
        """Design of experiments (issue 7): the seed's 9 dial rates against the 15 of its timer study."""
        return {"9 rates (seed 4.4.4)": {"dial_rates_dps": SEED_9_RATES},
                "15 rates (1-500 deg/s)": {"dial_rates_dps": SEED_15_RATES}}

    def lab_time(self, p: dict) -> dict:
        """Lab time of the schedule, in the seed's way (4.8) and on the virtual rig.

        Acquisition: whole rounds of the table, at least ``min_window_s`` per step, at the true
        rate dial x mains factor x (1 - slip). The seed took 60 min per gyro for its schedule,
        inclusive assembly and checking; what its schedule's acquisition leaves of that hour is
        spread over its measurements as the time to set, settle and check one step, and that
        per-measurement time is used for every schedule. Complete calibration = 15 min warm-up
        + one such hour-equivalent per mounting.
        """
        e = TurnTableErrors(mains_hz=p["mains_hz"])
        proto = self.protocol(p)
        acq = _acquisition_per_mount_s(p["dial_rates_dps"], p["directions"], p["min_window_s"], proto.min_rounds, e)
        seed_acq = _acquisition_per_mount_s(SEED_9_RATES, [1, -1], 10.0, 1, e)
        n_seed = len(SEED_9_RATES) * 2
        per_meas = (SEED_MIN_PER_GYRO * 60 - seed_acq) / n_seed
        n_meas = len(p["dial_rates_dps"]) * len(p["directions"])
        per_mount = acq + n_meas * per_meas
        nm = len(p["mounts"])
        rig_s = _rig_time_s(p, e)
        return {"positions": nm * n_meas, "measurements_per_gyro": n_meas, "acquiring_per_gyro_s": acq,
                "setting_and_checking_per_measurement_s": per_meas, "per_gyro_s": per_mount,
                "lab_time_seed_rates_s": SEED_WARMUP_S + nm * per_mount, "rig_time_s": rig_s,
                "samples": round((rig_s - (nm - 1) * p["remount_s"]) * p["sample_rate_hz"])}

    def table_4_7(self, p: dict) -> dict:
        """Rows in the style of the seed's Table 4.7 (seconds)."""
        lab = self.lab_time(p)
        nm = len(p["mounts"])
        return {"warm-up": SEED_WARMUP_S,
                "acquiring time per gyro (whole rounds, both directions)": lab["acquiring_per_gyro_s"],
                f"setting and checking, {lab['measurements_per_gyro']} measurements":
                    lab["measurements_per_gyro"] * lab["setting_and_checking_per_measurement_s"],
                "one gyro (incl. assembly and checking)": lab["per_gyro_s"],
                f"complete calibration ({nm} gyros)": lab["lab_time_seed_rates_s"],
                "virtual rig time (ramps, settling, pulse waits, rounds, remounts)": lab["rig_time_s"]}

    lab_time_note = ("`lab_time_seed_rates_s`: 15 min warm-up, then per gyro the whole-round acquisition plus "
                     "95 s per measurement to set, settle and check (what the seed's 60 min per gyro leave after "
                     "its schedule's acquisition, seed 4.8); `rig_time_s`: the virtual table's ramps, settling, "
                     "pulse waits, rounds and remounts.")
    table_4_7_note = ("All rows in minutes. The seed (4.8): 16 measurements per gyro, about 60 min per gyro "
                      "inclusive assembly and checking; its schedule is 9 dial rates x 2 directions. The time "
                      "its acquisition leaves of that hour is spread over its 18 measurements "
                      "(setting, settling, checking) and used for every schedule.")

    # ------------------------------------------------------------ one run
    def draw_lab(self, p: dict, ss: np.random.SeedSequence, distributions: dict | None = None):
        dist = distributions or {}
        errors = TurnTableErrors(mains_hz=p["mains_hz"])
        if "table.wobble_rad" in dist:
            errors = replace(errors, wobble_rad=float(draw_source(dist["table.wobble_rad"],
                                                                  child_generator(ss, "run/user_wobble"))))
        lab = ImuLab.draw(child_generator(ss, "run/sensor_errors"))
        g = lab.gyros
        if "gyro.bias_rad_s" in dist:
            g.bias_rad_s = draw_source(dist["gyro.bias_rad_s"], child_generator(ss, "run/user_gyro_bias"))
        if "gyro.scale_factor_rel" in dist:
            rel = draw_source(dist["gyro.scale_factor_rel"], child_generator(ss, "run/user_gyro_scale"))
            g.scale_V_per_rad_s = g.nominal_scale_V_per_rad_s * (1 + rel)
        if "gyro.misalignment_rad" in dist:
            M = draw_source(dist["gyro.misalignment_rad"],
                            child_generator(ss, "run/user_gyro_misalignment"))
            np.fill_diagonal(M, 0.0)
            g.misalignment_rad = M
        if "gyro.k2_per_rad_s" in dist:
            g.k2_per_rad_s = draw_source(dist["gyro.k2_per_rad_s"], child_generator(ss, "run/user_gyro_k2"))
        lab = replace(lab, adc=DAQ6036E(scan_list=TURN_TABLE_SCAN, sample_rate_hz=p["sample_rate_hz"]),
                      slip_rings=SlipRingNoise(enabled=bool(p["slip_rings"])))
        return errors, lab

    def simulate(self, p: dict, ss: np.random.SeedSequence, distributions: dict | None = None) -> Recording:
        errors, lab = self.draw_lab(p, ss, distributions)
        table = TurnTable(errors=errors, site=Site())
        rig = table.simulate(self.protocol(p), p["start_time"], child_generator(ss, "run/rig"))
        rec = lab.measure(rig, child_seed_sequence(ss, "run/sensor-chain"))
        rec.meta["campaign"] = {"name": "turn-table (Monte-Carlo)", **p}
        return rec

    def run(self, p: dict, ss: np.random.SeedSequence, distributions: dict | None = None, estimator=None) -> dict:
        t0 = time.perf_counter()
        rec = self.simulate(p, ss, distributions)
        t1 = time.perf_counter()
        if estimator is None:
            cal = GyroCalibration(model=p["model"], timer=p["timer"], gls=bool(p["gls"])).fit(rec)
            rw, rate = cal.windows_, cal.table_rate_
            rows = gyro_parameters(cal, rec)
        else:
            rw, rate = round_windows(rec, p["timer"])
            rows = complete_rows(estimator(rec.without_truth()),
                                 injected_parameters(rec.truth, list(rec.segments["mount"])), Z_BOUND)
        t2 = time.perf_counter()
        bound = crlb(p, rec, rw, rate)
        for r in rows:
            r["crlb"] = bound.get(r["name"])
        t3 = time.perf_counter()
        return {"rows": [plain(r) for r in rows],
                "info": {"samples": int(rec.n), "channels": len(rec.channels), "simulate_s": t1 - t0,
                         "estimate_s": t2 - t1, "crlb_s": t3 - t2, "steps": int(rw.n_segments)}}


# -------------------------------------------------------------------- lab time
def _true_rate_dps(dial, e: TurnTableErrors) -> np.ndarray:
    return np.abs(e.true_rate_dps(np.asarray(dial, float)))


def _acquisition_per_mount_s(dial, directions, min_window_s, min_rounds, e: TurnTableErrors) -> float:
    """Whole-round acquisition of one mounting (s): per step max(min_rounds, ceil(window / T)) rounds."""
    t_round = 360.0 / _true_rate_dps(dial, e)
    rounds = np.maximum(min_rounds, np.ceil(min_window_s / t_round))
    return float(np.sum(rounds * t_round) * len(directions))


def _rig_time_s(p: dict, e: TurnTableErrors) -> float:
    """The virtual rig's time for the schedule (the MuJoCo table's command profile, no setting error)."""
    proto = TurnTableMC.protocol(p)
    dt = 1.0 / min(p["sample_rate_hz"], 100.0)   # the profile's length does not need the logging rate
    total = 0.0
    for m in proto.mounts:
        st = [s for s in proto.steps(e.mains_factor) if s.mount == m]
        prof, _ = _profile(st, e, proto.settle_s, proto.ramp_s, dt, np.zeros(len(st)), proto.min_rounds)
        total += prof.size * dt
    return total + (len(proto.mounts) - 1) * proto.remount_s


TURN_TABLE = TurnTableMC()
