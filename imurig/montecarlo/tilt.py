"""The tilt-table campaign as a Monte-Carlo run (seed 4.3), and its Cramér-Rao bound.

One run, from its stream ``montecarlo/run`` (:mod:`imurig.kernel.random_streams`):

    draw table errors (TiltTableErrors.draw), survey them (TableSurvey.measure), draw the
    sensors (ImuLab.draw), apply user-set distributions
      -> rig truth at the IMU for every acquisition window
      -> ImuLab sensor chain -> Recording (100 Hz averaged logging by default)
      -> per-position medians -> inverse-model least squares (imurig.campaigns.tilt_table.calibrate)
      -> parameter rows {name, unit, injected, estimate, std_error, z, within_bound, crlb}

The Monte-Carlo schedule. The seed's campaign logs every channel at 1 kHz for 15 s per
position (7.4 M samples, ~40 s per run with the MuJoCo slews). The Monte-Carlo default keeps
the seed's 240 positions and 15 s dwell but logs at 100 Hz, each sample the mean of ten
1 kHz conversions (the lab's averaged logging, as the thermal and magnetometer campaigns
log), and keeps only the acquisition windows ("For every position, 15 sec of data was
saved", seed 4.3.2): 360 k samples, about 1 s per run. ``logging="direct"`` with
``sample_rate_hz=1000`` gives the seed's own logger (lowpass + downsample as in the campaign).

The rig. The drawn table errors (levelling, phi-plane error, per-position setting error)
enter the MuJoCo servo commands and base orientation, so the MuJoCo trajectory is *not*
independent of the draw and cannot be cached across runs. The calibration, however, only
uses the acquisition windows, where the table is at rest and the truth is the closed form

    f_C = R_MC' Rz(phi + phi0 + e_phi)' Ry(theta + theta0 + e_theta)' Rx(lev)' (0, 0, g)
    w_C, B_C: the Earth rate and the IGRF field rotated the same way

(seed eq. 4.33-4.38 with the table errors), which the MuJoCo rig reproduces to 1e-11 g
(tests/test_tilt_table.py, and tests/test_montecarlo.py against this module). So the default
``rig="static"`` evaluates that closed form per window (the window layout, computed once
per worker, follows the MuJoCo rig's timing exactly: slews at 6 deg/s, 2 s settle, 15 min
remount); ``rig="mujoco"`` runs the full MuJoCo table per run for checking.
"""
from __future__ import annotations

import json
import math
import time
from dataclasses import replace
from functools import lru_cache

import numpy as np

from imurig.calibration.accelerometer import AXES, injected_parameters
from imurig.calibration.preprocess import lowpass_downsample
from imurig.campaigns.tilt_table import (
    Z_BOUND,
    TiltTableCampaign,
    calibrate,
    compare_with_truth,
)
from imurig.kernel.errors import ConfigError, ScheduleError
from imurig.kernel.random_streams import child_generator, child_seed_sequence
from imurig.montecarlo.crlb import (
    crlb_covariance,
    fisher_information,
    numerical_jacobian,
)
from imurig.montecarlo.distributions import Source
from imurig.montecarlo.distributions import draw as draw_source
from imurig.montecarlo.registry import register
from imurig.kernel.recording import Recording
from imurig.rigs.tilt_table import (
    MOUNTS,
    TableSurvey,
    TiltTable,
    TiltTableErrors,
    TiltTableProtocol,
    _command_profile,
    rot_x,
    rot_y,
    rot_z,
    specific_force_C,
)
from imurig.sensors.adc import DAQ6036E
from imurig.sensors.chain import DEFAULT_SCAN, ImuLab
from imurig.sensors.disturbances import PeopleTransients, PumpVibration
from imurig.kernel.site import Site, parse_time
from imurig.kernel.units import ARCMIN, ARCSEC, DEG

THETA_SEED = [0.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0, 90.0]
PHI_12 = [float(v) for v in range(0, 360, 30)]
PHI_6 = [float(v) for v in range(0, 360, 60)]

#: seed Table 4.7: 120 min for the 10 tilt angles x 12 positions of one mounting with 15 s
#: acquisition -> 60 s per position, i.e. 45 s to set and check the angles besides the dwell
SEED_SETTING_OVERHEAD_S = 45.0
SEED_WARMUP_S = 15 * 60.0

PARAM_NAMES = ([f"sensitivity_{a}" for a in AXES]
               + [f"misalignment_{AXES[i]}{AXES[j]}" for i in range(3) for j in range(3) if i != j]
               + [f"bias_{a}" for a in AXES] + [f"nonlinearity_{a}" for a in AXES])

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
                "sample_rate_hz": 100.0, "logging": "averaged", "model": "physical", "statistic": "median",
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
        if p["statistic"] not in ("median", "mean"):
            raise ConfigError(f"statistic must be 'median' or 'mean', got {p['statistic']!r}")
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

    @staticmethod
    def protocol(p: dict) -> TiltTableProtocol:
        return TiltTableProtocol(theta_deg=tuple(p["theta_deg"]), phi_deg=tuple(p["phi_deg"]),
                                 runs=tuple(p["mounts"]), dwell_s=float(p["dwell_s"]), settle_s=float(p["settle_s"]),
                                 slew_rate_deg_s=float(p["slew_rate_deg_s"]), remount_s=float(p["remount_s"]),
                                 sample_rate_hz=float(p["sample_rate_hz"]))

    def lab_time(self, p: dict) -> dict:
        """Lab time of the schedule: the virtual rig's (slews, settling, dwell, remount) and the
        seed's Table 4.7 rates (15 min warm-up, 60 s per position at 15 s dwell, remount)."""
        lay = _layout(_key(p))
        npos = len(p["theta_deg"]) * len(p["phi_deg"])
        nruns = len(p["mounts"])
        rig_s = nruns * lay["run_s"] + (nruns - 1) * p["remount_s"]
        seed_s = SEED_WARMUP_S + nruns * npos * (p["dwell_s"] + SEED_SETTING_OVERHEAD_S) + (nruns - 1) * p["remount_s"]
        return {"positions": nruns * npos, "dwell_s": p["dwell_s"], "acquiring_s": nruns * npos * p["dwell_s"],
                "rig_time_s": rig_s, "lab_time_seed_rates_s": seed_s,
                "samples": int(lay["n_window"] * nruns), "sample_rate_hz": p["sample_rate_hz"]}

    def table_4_7(self, p: dict) -> dict:
        """The seed's Table 4.7 rows for this schedule (seconds)."""
        from imurig.montecarlo.doe import table_47

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
            rig = _keep_windows(rig)
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
            rows = complete_rows(estimator(rec.without_truth()), injected_parameters(rec.truth))
        t2 = time.perf_counter()
        bound = crlb(p, rec)
        for r in rows:
            r["crlb"] = bound.get(r["name"])
        t3 = time.perf_counter()
        return {"rows": [_plain(r) for r in rows],
                "info": {"samples": int(rec.n), "channels": len(rec.channels), "simulate_s": t1 - t0,
                         "estimate_s": t2 - t1, "crlb_s": t3 - t2}}


def complete_rows(rows: list[dict], injected: dict) -> list[dict]:
    """Fill a user estimator's rows {name, estimate, std_error[, unit]} with injected, z, within_bound."""
    out = []
    for r in rows:
        if "name" not in r or "estimate" not in r:
            raise ConfigError(f"an estimator row needs 'name' and 'estimate' (and 'std_error'), got {r!r}")
        v = injected.get(r["name"])
        se = r.get("std_error")
        z = None if v is None or not se or se <= 0 else (r["estimate"] - v) / se
        out.append({"name": r["name"], "unit": r.get("unit", ""), "injected": None if v is None else float(v),
                    "estimate": float(r["estimate"]), "std_error": None if se is None else float(se), "z": z,
                    "within_bound": None if z is None else bool(abs(z) <= Z_BOUND)})
    return out


def _plain(r: dict) -> dict:
    return {k: (float(v) if isinstance(v, (np.floating, float)) else v) for k, v in r.items()}


# -------------------------------------------------------------------- the rig
def _key(p: dict) -> str:
    keys = ("theta_deg", "phi_deg", "mounts", "dwell_s", "settle_s", "slew_rate_deg_s", "remount_s", "sample_rate_hz")
    return json.dumps({k: p[k] for k in keys}, sort_keys=True)


@lru_cache(maxsize=16)
def _layout(key: str) -> dict:
    """Acquisition windows of the schedule (computed once per worker): the MuJoCo rig's timing."""
    p = json.loads(key)
    proto = TiltTableMC.protocol(p).validate()
    dt = 1.0 / proto.sample_rate_hz
    nt, nphi = len(proto.theta_deg), len(proto.phi_deg)
    set_theta = np.repeat(np.asarray(proto.theta_deg, float) * DEG, nphi)
    set_phi = np.tile(np.asarray(proto.phi_deg, float) * DEG, nt)
    cmd, windows = _command_profile(proto, set_theta, set_phi, dt)
    nstep = cmd.shape[0]
    idx = np.concatenate([np.arange(a, b) for a, b in windows])
    pos = np.concatenate([np.full(b - a, k) for k, (a, b) in enumerate(windows)])
    return {"dt": dt, "nstep": nstep, "run_s": nstep * dt, "windows": windows, "idx": idx, "pos": pos,
            "set_theta": set_theta, "set_phi": set_phi, "n_window": idx.size}


@lru_cache(maxsize=8)
def _field_W(start_time: str, site: Site) -> tuple:
    return tuple(site.magnetic_field_W(parse_time(start_time)))


def world_to_case(v_W: np.ndarray, theta, phi, mount: str, level_x: float = 0.0) -> np.ndarray:
    """A world (ENU) vector in the IMU case frame at rest: (n, 3) for angle arrays (n,) [rad].

    v_C = R_MC' Rz(phi)' Ry(theta)' Rx(level_x)' v_W   (the table's kinematics, as specific_force_C).
    """
    v_B = rot_x(np.float64(level_x)).T @ np.asarray(v_W, float)
    v_T = np.einsum("...ji,j->...i", rot_y(np.asarray(theta, float)), v_B)
    v_P = np.einsum("...ji,...j->...i", rot_z(np.asarray(phi, float)), v_T)
    return v_P @ MOUNTS[mount]


def static_rig(p: dict, errors: TiltTableErrors, survey: TableSurvey, rng: np.random.Generator,
               site: Site) -> Recording:
    """Rig Recording of the acquisition windows only, truth in closed form (module doc).

    Draws the per-position setting errors from ``rng`` exactly as TiltTable.simulate does
    (one uniform (n_pos, 2) block per mounting), so both rigs see the same table.
    """
    lay = _layout(_key(p))
    runs = list(p["mounts"])
    res = errors.setting_resolution_rad
    npos = lay["set_theta"].size
    when = parse_time(p["start_time"])
    B_W = np.array(_field_W(p["start_time"], site))
    g = site.gravity_m_s2
    up = np.array([0.0, 0.0, g])
    t_list, f_list, w_list, b_list, th_list, ph_list = [], [], [], [], [], []
    seg = {"start_s": [], "stop_s": [], "run": [], "theta": [], "phi": [], "mount": []}
    setting_err = {}
    for i, r in enumerate(runs):
        err = rng.uniform(-res / 2, res / 2, size=(npos, 2)) if res > 0 else np.zeros((npos, 2))
        setting_err[r] = err
        theta = lay["set_theta"] + errors.theta_zero_rad + err[:, 0]
        phi = lay["set_phi"] + errors.phi_zero_rad[r] + err[:, 1]
        t0 = i * (lay["run_s"] + p["remount_s"])
        t_list.append(t0 + lay["idx"] * lay["dt"])
        pos = lay["pos"]
        f_list.append(world_to_case(up, theta, phi, r, errors.level_x_rad)[pos])
        w_list.append(world_to_case(site.earth_rate_W(), theta, phi, r, errors.level_x_rad)[pos])
        b_list.append(world_to_case(B_W, theta, phi, r, errors.level_x_rad)[pos])
        th_list.append(theta[pos])
        ph_list.append(phi[pos])
        for k, (a, b) in enumerate(lay["windows"]):
            seg["start_s"].append(t0 + a * lay["dt"])
            seg["stop_s"].append(t0 + b * lay["dt"])
        seg["run"] += [i] * npos
        seg["mount"] += [r] * npos
        seg["theta"].append(lay["set_theta"])
        seg["phi"].append(lay["set_phi"])
    time_s = np.concatenate(t_list)
    f_C, w_C, B_C = (np.concatenate(x) for x in (f_list, w_list, b_list))
    pos_all = np.concatenate([lay["pos"] + i * npos for i in range(len(runs))])
    set_theta = np.concatenate(seg["theta"])
    set_phi = np.concatenate(seg["phi"])
    segments = {"start_s": np.array(seg["start_s"]), "stop_s": np.array(seg["stop_s"]),
                "run": np.array(seg["run"]), "theta": set_theta, "phi": set_phi, "mount": np.array(seg["mount"])}
    seg_units = {"start_s": "s", "stop_s": "s", "run": "1", "theta": "rad", "phi": "rad", "mount": ""}
    truth_signals = {"theta_true": np.concatenate(th_list), "phi_true": np.concatenate(ph_list)}
    units = {"theta_true": "rad", "phi_true": "rad"}
    for name, arr, unit in (("f_C", f_C, "m/s^2"), ("w_C", w_C, "rad/s"), ("B_C", B_C, "T")):
        for j, ax in enumerate("xyz"):
            truth_signals[f"{name}_{ax}"] = np.ascontiguousarray(arr[:, j])
            units[f"{name}_{ax}"] = unit
    proto = TiltTableMC.protocol(p)
    meta = {"rig": "tilt_table", "rig_model": "static windows (closed form)", "site": site.to_dict(),
            "start_time": when.isoformat(), "sample_rate_hz": float(p["sample_rate_hz"]), "runs": runs,
            "protocol": proto.to_dict(), "table_survey": survey.to_dict(), "table_azimuth_deg": 0.0,
            "setpoints": ["theta", "phi"],
            "frames": "W: local level ENU; C: IMU case (site 'imu'); specific force and rates in C"}
    truth = {"rig": {"tilt_table": errors.to_dict(), "setting_error_rad": {r: setting_err[r].tolist() for r in runs},
                     "magnetic_field_W_T": B_W.tolist()}}
    return Recording(time_s=time_s, channels={"theta": set_theta[pos_all], "phi": set_phi[pos_all]},
                     units={"theta": "rad", "phi": "rad"}, segments=segments, segment_units=seg_units, meta=meta,
                     truth=truth, truth_signals=truth_signals, truth_units=units)


def _keep_windows(rig: Recording) -> Recording:
    """The acquisition windows of a full MuJoCo rig recording (what the logger saves)."""
    keep = np.concatenate([np.arange(s.start, s.stop) for s in rig.segment_slices()])
    return rig.replace(time_s=rig.time_s[keep], channels={k: v[keep] for k, v in rig.channels.items()},
                       truth_signals={k: v[keep] for k, v in rig.truth_signals.items()})


# -------------------------------------------------------------------- Cramér-Rao bound
def forward_volts(theta_p: np.ndarray, psi: np.ndarray, p: dict, mounts: list[str], set_theta, set_phi,
                  e_theta, e_phi, g: float) -> np.ndarray:
    """Noise-free accelerometer voltages per position, (n_pos_total, 3) V.

    theta_p (15,): sensitivity S (V/(m/s^2)), misalignment M_xy, M_xz, M_yx, M_yz, M_zx, M_zy (rad),
    bias b (m/s^2), nonlinearity k2 (1/(m/s^2)); psi: theta_zero, level_x, phi_zero per mount (rad).
    V = S (a + b + k2 a^2), a = (I + M) f_C (QFlexTriad.ideal_voltage at the reference temperature).
    """
    S, m, b, k2 = theta_p[0:3], theta_p[3:9], theta_p[9:12], theta_p[12:15]
    M = np.array([[0, m[0], m[1]], [m[2], 0, m[3]], [m[4], m[5], 0]])
    th0, lev = psi[0], psi[1]
    fs = []
    for i, r in enumerate(mounts):
        sl = slice(i * set_theta.size, (i + 1) * set_theta.size)
        fs.append(specific_force_C(set_theta + th0 + e_theta[sl], set_phi + psi[2 + i] + e_phi[sl], r, g,
                                   level_x=lev))
    f = np.concatenate(fs)
    a = f + f @ M.T
    return S * (a + b + k2 * a**2)


def window_noise_cov(p: dict, lab: ImuLab, n_window: int) -> np.ndarray:
    """Covariance (3, 3) V^2 of the mean of one window of ``n_window`` logged samples of the
    three accelerometer channels, from the chain's noise model:

    - Q-Flex current noise x R_L in its three bands: a band reaching DC (0-10 Hz) contributes
      rms^2 / (g_f^2 N) with g_f^2 the mean power gain of its shaping filter (|H(0)| = 1); bands
      above DC (band-pass/high-pass, |H(0)| = 0) average out; with direct logging the bands
      above fs/2 alias as white noise (rms^2 / N); with averaged logging they average out.
    - ADC common-mode noise (same on every channel, off the diagonal too) sigma_cm^2 / N
      (not with DIFF wiring); converter input noise and quantisation (q^2/12 + (e q)^2) / N,
      divided by the averaging count with averaged logging.
    Left out: people transients (rare, non-Gaussian; the median rejects most) and the pump
    (off in the evening).
    """
    acc, adc = lab.accelerometers, lab.adc
    fs = float(p["sample_rate_hz"])
    averaged = p["logging"] == "averaged"
    var_i = np.zeros(3)
    for lo, hi, rms in acc.noise_bands:
        if rms <= 0:
            continue
        if averaged:
            if lo >= fs / 2:
                continue
            rms = rms * np.sqrt((min(hi, fs / 2) - lo) / (hi - lo))
            hi = min(hi, fs / 2)
        if lo >= fs / 2 or (lo <= 0 and hi >= fs / 2):
            var_i += rms**2 / n_window
        elif lo <= 0:
            var_i += rms**2 / (_power_gain(fs, hi) * n_window)
        # band-pass above DC: zero mean power at DC, nothing left in a long window mean
    cov = np.diag(var_i * acc.load_resistor_ohm**2)
    cov += np.eye(3) * adc.sample_variance_V2() / n_window
    if adc.grounding != "DIFF":
        cov += adc.common_mode_noise_V_rms**2 / n_window
    return cov


@lru_cache(maxsize=32)
def _power_gain(fs: float, hi: float) -> float:
    """Mean power gain of band_noise's low-pass shaping filter (unit DC gain)."""
    from scipy import signal

    sos = signal.butter(4, hi / (fs / 2), "lowpass", output="sos")
    _, h = signal.sosfreqz(sos, worN=8192)
    return float(np.mean(np.abs(h) ** 2))


def crlb(p: dict, rec: Recording) -> dict[str, float]:
    """Cramér-Rao bound (1 sigma) of the 15 physical parameters for this run's true sensor,
    table, schedule and noise: {parameter name: bound}.

    Observations: the window means of the three accelerometer voltages at every position
    (covariance :func:`window_noise_cov` plus the per-position angle-setting error, uniform
    within +-res/2 so variance res^2/12 in theta and phi, propagated through the forward
    model), and the survey's readings of the table errors (variance survey_accuracy^2).
    Parameters: the 15 sensor parameters and the 2 + n_mounts table errors (nuisance).
    F = sum_k J_k' C_k^-1 J_k + diag(0, 1/s_survey^2); bound = sqrt(diag((F^-1)[:15, :15])).
    """
    t = rec.truth
    acc = t["sensors"]["accelerometers"]
    table = t["rig"]["tilt_table"]
    mounts = list(p["mounts"])
    lay = _layout(_key(p))
    g = Site.from_dict(rec.meta.get("site", {})).gravity_m_s2
    M = np.asarray(acc["misalignment_rad"], float)
    theta_p = np.concatenate([acc["sensitivity_V_per_m_s2"], [M[i, j] for i in range(3) for j in range(3) if i != j],
                              acc["bias_m_s2"], acc["k2_per_m_s2"]])
    psi = np.array([table["theta_zero_rad"], table["level_x_rad"]] + [table["phi_zero_rad"][m] for m in mounts])
    npos = lay["set_theta"].size * len(mounts)
    set_theta = lay["set_theta"]
    set_phi = lay["set_phi"]
    zero = np.zeros(npos)

    def h_all(x):
        return forward_volts(x[:15], x[15:], p, mounts, set_theta, set_phi, zero, zero, g)

    x0 = np.concatenate([theta_p, psi])
    step = np.concatenate([np.abs(theta_p[:3]) * 1e-6, np.full(6, 1e-6), np.full(3, 1e-6), np.full(3, 1e-8),
                           np.full(psi.size, 1e-7)])
    J = numerical_jacobian(h_all, x0, step)                             # (npos, 3, P)
    h = 1e-7

    def fv(et, ep):
        return forward_volts(theta_p, psi, p, mounts, set_theta, set_phi, et, ep, g)

    A = np.stack([(fv(zero + h, zero) - fv(zero - h, zero)) / (2 * h),
                  (fv(zero, zero + h) - fv(zero, zero - h)) / (2 * h)], axis=-1)   # (npos, 3, 2) V/rad
    lab_stub = ImuLab(accelerometers=_triad_from_truth(acc),
                      adc=DAQ6036E(**{k: v for k, v in rec.meta["adc"].items()
                                       if k in DAQ6036E.__dataclass_fields__ and k != "scan_list"},
                                   scan_list=tuple(rec.meta["adc"]["scan_list"])))
    n_window = round(p["dwell_s"] * p["sample_rate_hz"])
    Sv = window_noise_cov(p, lab_stub, n_window)
    res = float(table["setting_resolution_rad"])
    C = Sv + (res**2 / 12) * np.einsum("nia,nja->nij", A, A)
    F = fisher_information(J, C)
    s_survey = p["survey_accuracy_arcsec"] * ARCSEC
    if s_survey > 0:
        F[15:, 15:] += np.eye(psi.size) / s_survey**2
        cov = crlb_covariance(F, 15, PARAM_NAMES + ["theta_zero", "level_x"] + [f"phi_zero_{m}" for m in mounts])
    else:  # the table errors are known exactly
        cov = crlb_covariance(F[:15, :15], 15, PARAM_NAMES)
    return dict(zip(PARAM_NAMES, np.sqrt(np.diag(cov)).tolist()))


def _triad_from_truth(acc: dict):
    from imurig.sensors.accelerometer import QFlexTriad

    fields = {k: acc[k] for k in QFlexTriad.__dataclass_fields__ if k in acc}
    fields["noise_bands"] = tuple(tuple(b) for b in fields.get("noise_bands", ()))
    return QFlexTriad(**fields)


TILT_TABLE = register(TiltTableMC())
