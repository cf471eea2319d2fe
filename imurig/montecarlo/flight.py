"""The flight as a Monte-Carlo run: the navigation error after calibration, as an error budget.

One flight trajectory per study (the truth does not depend on the sensor errors; it is flown
once per worker and cached): a short airborne plan of the Citation in MuJoCo
(:func:`imurig.flights.plan.simulate_flight`). One run, from its stream ``montecarlo/run``
(:mod:`imurig.kernel.random_streams`; children ``run/sensor_errors``, ``run/sensor-chain``,
``run/residual_<source>``, ``run/gps``):

    draw the IMU (ImuLab.draw: the true sensor errors, as the rig campaigns draw them)
      -> measure_flight: the flight's truth through the full sensor chain -> volts (once per run)
      -> draw the residual error of every calibrated parameter after calibration, per source,
         delta ~ N(0, sigma_source^2) (``residuals``: the rig calibrations' Monte-Carlo RMS, or
         the datasheet spread for an uncalibrated IMU)
      -> for each configuration (no residual / one source alone / all sources):
           SI stream = the exact inverse of the sensor models with the parameters true + delta
           (only the configuration's sources perturbed) -> GPS fixes (Euro4 model) -> LooseEKF
           -> RMS of roll, pitch, heading, horizontal and vertical position, velocity after settling
      -> rows {name: "<metric> | <configuration>", injected 0, estimate: the RMS error}

Every configuration of a run shares the volts, the GPS fixes and the residual draws, so the
differences between configurations are paired: the sensor and GPS noise cancel in them.

The budget (:func:`budget`). For metric m, MS_c = mean over runs of RMS_c^2 (mean square over
the flight). The share of source s is the mean square it adds on its own, MS_s - MS_none;
the sum over sources is compared with what all of them add together, MS_all - MS_none (equal if
the sources add in variance: independent and linear). MS_none is the floor: sensor noise, GPS
and the filter, with a perfect calibration.

The inverse sensor models (SI, per sample; the true temperatures and hysteresis state of the
chain are used, i.e. the thermal calibration is taken as perfect and is not in the budget):
    accelerometer: y = V / (R_L K1 (1 + k_s dT + s_h h)) - (b + b_T(dT) + b_h h),
                   a_S = 2 y / (1 + sqrt(1 + 4 k2 y)),  f_C = (I + M)^-1 a_S        [m/s^2]
    gyro:          y = V / (SF (1 + k_s dT)) - b - k_b dT,
                   w_S = 2 y / (1 + sqrt(1 + 4 k2 y)),  w_C = (I + M)^-1 w_S        [rad/s]
    magnetometer:  B_C = A^-1 (V / s - b_hi),  A = soft iron (I + M); the residual: a rotation
                   about the body z axis by delta_psi plus a hard-iron error            [T]
"""
from __future__ import annotations

import math
import time
from functools import lru_cache

import numpy as np

from imurig.campaigns.flight import (
    FlightOptions,
    align,
    errors,
    flight_declination,
    gps_error_model,
    receiver_fixes,
    summarise,
)
from imurig.flights import ekf, ins
from imurig.flights.imu import measure_flight
from imurig.flights.plan import AlphaDotSTurns, FlightPlan, Level, simulate_flight
from imurig.kernel.errors import ConfigError
from imurig.kernel.navdata import ImuStream
from imurig.kernel.random_streams import child_generator, child_seed_sequence
from imurig.montecarlo.distributions import Source
from imurig.sensors.chain import ImuLab

DEG = math.pi / 180
G0 = 9.80665

METRICS = {"roll_rms_deg": "deg", "pitch_rms_deg": "deg", "heading_rms_deg": "deg",
           "horizontal_position_rms_m": "m", "vertical_position_rms_m": "m", "velocity_rms_m_s": "m/s"}

#: residual 1-sigma after calibration. Accelerometers: the RMS errors of the 200-run tilt-table
#: study with the weighted joint fit (seed 2005; README); gyros: the RMS errors of the 200-run turn-table study (quick
#: protocol); magnetometer: assumed (heading alignment 0.1 deg, hard iron 20 nT), not measured.
CALIBRATED = {
    "acc_bias": {"bias_m_s2": [2.84e-6, 2.95e-6, 4.10e-6]},
    "acc_scale_misalignment": {"scale_rel": [2.9e-7, 3.1e-7, 1.8e-7],
                               "misalignment_rad": [[0, 6.3e-6, 4.0e-7], [6.3e-6, 0, 3.9e-7], [5.7e-7, 5.2e-7, 0]]},
    "acc_nonlinearity": {"k2_per_m_s2": [5.3e-8, 5.1e-8, 5.5e-8]},
    "gyro_bias": {"bias_rad_s": [6.18e-6, 6.90e-6, 7.07e-6]},
    "gyro_scale_misalignment": {"scale_rel": [9.2e-6, 8.8e-6, 9.4e-6],
                                "misalignment_rad": [[0, 8.0e-6, 8.9e-6], [8.6e-6, 0, 7.7e-6], [8.0e-6, 8.1e-6, 0]]},
    "gyro_nonlinearity": {"k2_per_rad_s": [6.85e-6, 5.59e-6, 6.30e-6]},
    "magnetometer": {"heading_rad": 0.1 * DEG, "hard_iron_T": 20e-9},
}
#: an uncalibrated IMU: the datasheet spread (uniform within +-limit -> sigma = limit / sqrt 3)
DATASHEET = {
    "acc_bias": {"bias_m_s2": 8e-3 * G0 / math.sqrt(3)},
    "acc_scale_misalignment": {"scale_rel": 0.01 / math.sqrt(3), "misalignment_rad": 2e-3 / math.sqrt(3)},
    "acc_nonlinearity": {"k2_per_m_s2": 48e-6 / G0 / math.sqrt(3)},
    "gyro_bias": {"bias_rad_s": 0.003 * DEG},
    "gyro_scale_misalignment": {"scale_rel": 0.02 / math.sqrt(3), "misalignment_rad": 2e-3 / math.sqrt(3)},
    "gyro_nonlinearity": {"k2_per_rad_s": 2e-6 / DEG / math.sqrt(3)},
    "magnetometer": {"heading_rad": 2.0 * DEG, "hard_iron_T": 200e-9},
}
SOURCE_NAMES = tuple(CALIBRATED)


class FlightMC:
    """The flight error budget for Monte-Carlo studies (see the module doc)."""

    name = "flight"
    generic_figures = False
    lab_time_note = "`flight_s`: the flight's length; one navigation filter run per configuration and run."

    def default_params(self) -> dict:
        return {"plan": "short", "duration_s": None, "imu_rate_hz": 100.0, "nav_rate_hz": 10.0, "gps_rate_hz": 1.0,
                "settle_s": 30.0, "residuals": "calibrated", "sources": list(SOURCE_NAMES),
                "budget": "one-at-a-time"}

    def validate(self, params: dict | None) -> dict:
        p = self.default_params()
        unknown = set(params or {}) - set(p)
        if unknown:
            raise ConfigError(f"unknown flight setting(s) {sorted(unknown)}; known: {sorted(p)}")
        p.update(params or {})
        if p["plan"] not in ("short", "default"):
            raise ConfigError(f"plan must be 'short' (~2 min airborne) or 'default' (the 15 min flight), "
                              f"got {p['plan']!r}")
        if p["residuals"] not in ("calibrated", "datasheet"):
            raise ConfigError(f"residuals must be 'calibrated' or 'datasheet', got {p['residuals']!r}")
        if p["budget"] not in ("one-at-a-time", "all-on"):
            raise ConfigError(f"budget must be 'one-at-a-time' or 'all-on', got {p['budget']!r}")
        p["sources"] = [str(s) for s in p["sources"]]
        bad = [s for s in p["sources"] if s not in SOURCE_NAMES]
        if bad or not p["sources"]:
            raise ConfigError(f"unknown or no error source(s) {bad}; choose from {list(SOURCE_NAMES)}")
        for k in ("imu_rate_hz", "nav_rate_hz", "gps_rate_hz", "settle_s"):
            p[k] = float(p[k])
            if not (math.isfinite(p[k]) and p[k] >= 0):
                raise ConfigError(f"{k} must be a finite number >= 0, got {p[k]}")
        if not 0 < p["nav_rate_hz"] <= p["imu_rate_hz"] <= 1000:
            raise ConfigError("need 0 < nav_rate_hz <= imu_rate_hz <= 1000 Hz")
        if p["duration_s"] is not None:
            p["duration_s"] = float(p["duration_s"])
            if not p["duration_s"] > p["settle_s"] + 10:
                raise ConfigError(f"duration_s must exceed settle_s + 10 s, got {p['duration_s']}")
        return p

    def sources(self) -> dict[str, Source]:
        return {}

    def configurations(self, p: dict) -> list[str]:
        if p["budget"] == "all-on":
            return ["none", "all"]
        return ["none", *p["sources"], "all"]

    def lab_time(self, p: dict) -> dict:
        tr = flight_truth(_truth_key(p))
        return {"flight_s": float(tr.time_s[-1] - tr.time_s[0]), "imu_samples": int(tr.n),
                "filter_runs_per_run": len(self.configurations(p))}

    def schedules(self) -> dict[str, dict]:
        return {"calibrated": {"residuals": "calibrated"}, "datasheet (uncalibrated)": {"residuals": "datasheet"}}

    # ------------------------------------------------------------ one run
    def run(self, p: dict, ss: np.random.SeedSequence, distributions: dict | None = None, estimator=None) -> dict:
        if estimator is not None:
            raise ConfigError("the flight campaign has no estimator hook (its estimator is the navigation filter)")
        t0 = time.perf_counter()
        truth = flight_truth(_truth_key(p))
        lab = ImuLab.draw(child_generator(ss, "run/sensor_errors"))
        rec = measure_flight(truth, lab, child_seed_sequence(ss, "run/sensor-chain"))
        residual = draw_residuals(p["residuals"], p["sources"], ss)
        t1 = time.perf_counter()
        gps, opt = _gps(truth, p, ss)
        rows, nav = [], {}
        for cfg in self.configurations(p):
            on = set(p["sources"]) if cfg == "all" else ({cfg} if cfg != "none" else set())
            stream = calibrated_stream(truth, rec, lab, {k: v for k, v in residual.items() if k in on})
            s = navigate(truth, stream, gps, opt, lab, p)
            nav[cfg] = s
            for m, unit in METRICS.items():
                rows.append({"name": f"{m} | {cfg}", "unit": unit, "injected": 0.0, "estimate": float(s[m]),
                             "std_error": None, "z": None, "within_bound": None, "crlb": None})
        t2 = time.perf_counter()
        info = {"samples": int(truth.n), "simulate_s": t1 - t0, "estimate_s": t2 - t1, "crlb_s": 0.0,
                "filter_runs": len(nav), "mean_nees_9dof_all": float(nav["all"].get("mean_nees_9dof", np.nan))}
        return {"rows": rows, "info": info}


# -------------------------------------------------------------------- truth
def _truth_key(p: dict) -> tuple:
    return (p["plan"], p["duration_s"], p["imu_rate_hz"])


def short_plan_phases() -> tuple:
    """~2 min airborne over the North Sea: level, S-turns at 20 and 30 deg of bank, level."""
    return (Level(20.0, 1500.0, 120.0, name="level_in"),
            AlphaDotSTurns(banks_first_deg=(20.0, 30.0), banks_second_deg=(20.0, 30.0)),
            Level(20.0, 1500.0, 120.0, name="level_out"))


@lru_cache(maxsize=2)
def flight_truth(key: tuple):
    """The flight's truth, flown once per worker (MuJoCo Citation)."""
    plan, duration, rate = key
    fp = FlightPlan(phases=short_plan_phases(), rate_hz=rate) if plan == "short" else FlightPlan(rate_hz=rate)
    tr = simulate_flight(fp, progress_bar=False)
    if duration is not None:
        tr = tr.slice(tr.time_s[0], tr.time_s[0] + duration)
    return tr


# -------------------------------------------------------------------- residual errors
def draw_residuals(kind: str, sources, ss: np.random.SeedSequence) -> dict:
    """delta per source, each from its own generator (so a source's draw does not depend on the others)."""
    table = CALIBRATED if kind == "calibrated" else DATASHEET
    out = {}
    for s in sources:
        rng = child_generator(ss, f"run/residual_{s}")
        d = {}
        for k, sig in table[s].items():
            shape = (3, 3) if k == "misalignment_rad" else (() if k == "heading_rad" else (3,))
            sig = np.broadcast_to(np.asarray(sig, float), shape)
            v = sig * rng.standard_normal(shape)
            if k == "misalignment_rad":
                np.fill_diagonal(v, 0.0)
            d[k] = v
        out[s] = d
    return out


def residual_sigmas(kind: str) -> dict:
    return CALIBRATED if kind == "calibrated" else DATASHEET


def _quad_inverse(y: np.ndarray, k2: np.ndarray) -> np.ndarray:
    """x with x + k2 x^2 = y (the root near y), stable for k2 -> 0."""
    return 2 * y / (1 + np.sqrt(np.clip(1 + 4 * k2 * y, 0, None)))


def calibrated_stream(truth, rec, lab: ImuLab, residual: dict):
    """The filter's SI input: the exact inverse sensor models (module doc) with the parameters
    true + the residuals given (sources absent from ``residual`` are calibrated perfectly)."""
    acc, gy, mag = lab.accelerometers, lab.gyros, lab.magnetometer
    ts = rec.truth_signals
    zero3 = np.zeros(3)
    # accelerometers
    ra = residual.get("acc_bias", {})
    rs = residual.get("acc_scale_misalignment", {})
    rk = residual.get("acc_nonlinearity", {})
    Va = rec.stack(("acc_x", "acc_y", "acc_z"))
    dT = np.asarray(ts["T_acc"], float).reshape(-1, 1) - acc.reference_temperature_K
    h = np.asarray(ts.get("h_acc", 0.0), float)
    h = h.reshape(-1, 1) if h.ndim == 1 else h
    k1 = acc.k1_A_per_m_s2 * (1 + rs.get("scale_rel", zero3))
    y = Va / (acc.load_resistor_ohm * k1 * (1 + acc.scale_tempco_per_K * dT + acc.scale_hysteresis * h))
    y = y - (acc.bias_m_s2 + ra.get("bias_m_s2", zero3) + acc.bias_tempco_m_s2_per_K * dT
             + acc.bias_tempco2_m_s2_per_K2 * dT**2 + acc.bias_tempco3_m_s2_per_K3 * dT**3
             + acc.bias_hysteresis_m_s2 * h)
    a_S = _quad_inverse(y, acc.k2_per_m_s2 + rk.get("k2_per_m_s2", zero3))
    M = acc.misalignment_rad + rs.get("misalignment_rad", np.zeros((3, 3)))
    f_C = np.linalg.solve(np.eye(3) + M, a_S.T).T
    # gyros
    gb = residual.get("gyro_bias", {})
    gs = residual.get("gyro_scale_misalignment", {})
    gk = residual.get("gyro_nonlinearity", {})
    Vg = rec.stack(("gyro_p", "gyro_q", "gyro_r"))
    dTg = np.asarray(ts["T_gyro"], float).reshape(-1, 1) - gy.reference_temperature_K
    sf = gy.scale_V_per_rad_s * (1 + gs.get("scale_rel", zero3))
    y = Vg / (sf * (1 + gy.scale_tempco_per_K * dTg)) - gy.bias_rad_s - gb.get("bias_rad_s", zero3) \
        - gy.bias_tempco_rad_s_per_K * dTg
    w_S = _quad_inverse(y, gy.k2_per_rad_s + gk.get("k2_per_rad_s", zero3))
    Mg = gy.misalignment_rad + gs.get("misalignment_rad", np.zeros((3, 3)))
    w_C = np.linalg.solve(np.eye(3) + Mg, w_S.T).T
    # magnetometer (C_BC = I: case = body)
    rm = residual.get("magnetometer", {})
    Vm = rec.stack(("mag_x", "mag_y", "mag_z"))
    A = mag.soft_iron @ (np.eye(3) + mag.misalignment_rad)
    B = np.linalg.solve(A, (Vm / mag.sensitivity_V_per_T - mag.hard_iron_T - rm.get("hard_iron_T", zero3)).T).T
    dpsi = float(rm.get("heading_rad", 0.0))
    if dpsi:
        c, s = math.cos(dpsi), math.sin(dpsi)
        B = np.column_stack([c * B[:, 0] - s * B[:, 1], s * B[:, 0] + c * B[:, 1], B[:, 2]])
    sensor = lab.temp_sensors["temp_acc_x"]
    Tk = np.stack([sensor.temperature_K(rec.channels[f"temp_acc_{a}"]) for a in "xyz"], 1)
    return ImuStream(time_s=truth.time_s, f_B=f_C, w_IB_B=w_C, B_B=B, T_acc_K=Tk, samples=ins.sample_semantics(truth))


# -------------------------------------------------------------------- GPS and filter
def _gps(truth, p: dict, ss: np.random.SeedSequence):
    """The Euro4 receiver's fixes (:func:`imurig.campaigns.flight.receiver_fixes`) on this run's
    stream ``run/gps``."""
    opt = FlightOptions(nav_rate_hz=p["nav_rate_hz"], imu_rate_hz=p["imu_rate_hz"], gps_rate_hz=p["gps_rate_hz"])
    return receiver_fixes(truth, opt, child_generator(ss, "run/gps")), opt


def navigate(truth, stream, gps, opt, lab: ImuLab, p: dict) -> dict:
    """LooseEKF with priors from the residuals' sigma (what a calibrated system knows); RMS errors."""
    noise = ekf.ImuNoise.from_sensors(lab.accelerometers, lab.gyros, truth.rate_hz)
    sig = residual_sigmas(p["residuals"])
    s_ab = float(np.max(sig["acc_bias"]["bias_m_s2"]))
    s_gb = float(np.max(sig["gyro_bias"]["bias_rad_s"]))
    cfg = ekf.FilterConfig(nav_rate_hz=opt.nav_rate_hz, gps_latency_s=opt.gps_latency_s,
                           gps_time_sigma_s=opt.gps_time_sigma_s,
                           sigma0_acc_bias_m_s2=max(s_ab, 1e-6),
                           sigma0_gyro_bias_rad_s=math.hypot(s_gb, noise.gyro_bias_sigma),
                           mag_heading_sigma_rad=max(float(sig["magnetometer"]["heading_rad"]), 0.05 * DEG),
                           **gps_error_model(gps), gps_pos_states=True)
    decl = flight_declination(truth)
    f = ekf.LooseEKF(cfg, noise, lever_gps_B=truth.lever_gps_B, declination=decl)
    res = f.fit(stream, gps, align(truth, stream, gps, decl)).solution_
    return summarise(errors(res, truth), res, settle_s=p["settle_s"])


# -------------------------------------------------------------------- the budget
def budget(rows_by_run: dict, configurations: list[str]) -> dict:
    """Error budget per metric: mean square of each configuration, the share each source adds
    on its own, and how far the shares add up to the all-on excess (module doc)."""
    runs = sorted(rows_by_run)
    val = {}
    for i in runs:
        for r in rows_by_run[i]:
            m, cfg = (x.strip() for x in r["name"].split("|"))
            val.setdefault(m, {}).setdefault(cfg, {})[i] = r["estimate"]
    out = {}
    for m, by in val.items():
        common = [i for i in runs if all(i in by.get(c, {}) for c in configurations)]
        if not common:
            continue
        X = {c: np.array([by[c][i] for i in common]) ** 2 for c in configurations}
        n = len(common)
        ms = {c: float(np.mean(X[c])) for c in configurations}
        d_all = X["all"] - X["none"]
        srcs = [c for c in configurations if c not in ("none", "all")]
        added = {}
        for s in srcs:
            d = X[s] - X["none"]
            added[s] = {"mean_square_added": float(np.mean(d)),
                        "se": float(np.std(d, ddof=1) / math.sqrt(n)) if n > 1 else None,
                        "rms_alone": math.sqrt(ms[s]),
                        "share_of_all": float(np.mean(d) / np.mean(d_all)) if np.mean(d_all) != 0 else None}
        total = float(sum(a["mean_square_added"] for a in added.values()))
        out[m] = {"unit": METRICS.get(m, ""), "runs": n, "rms": {c: math.sqrt(ms[c]) for c in configurations},
                  "floor_mean_square": ms["none"], "all_mean_square_added": float(np.mean(d_all)),
                  "all_se": float(np.std(d_all, ddof=1) / math.sqrt(n)) if n > 1 else None,
                  "sources": added, "sum_of_sources": total,
                  "additivity": total / float(np.mean(d_all)) if srcs and np.mean(d_all) != 0 else None}
    return out


FLIGHT = FlightMC()
