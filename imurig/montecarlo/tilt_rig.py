"""The tilt table's rest windows for the Monte-Carlo tilt-table campaign (:mod:`imurig.montecarlo.tilt`).

The drawn table errors (levelling, phi-plane error, per-position setting error) enter the
MuJoCo servo commands and base orientation, so the MuJoCo trajectory is *not* independent of
the draw and cannot be cached across runs. The calibration, however, only uses the
acquisition windows, where the table is at rest and the truth is the closed form

    f_C = R_MC' Rz(phi + phi0 + e_phi)' Ry(theta + theta0 + e_theta)' Rx(lev)' (0, 0, g)
    w_C, B_C: the Earth rate and the IGRF field rotated the same way

(seed eq. 4.33-4.38 with the table errors), which the MuJoCo rig reproduces to 1e-11 g
(tests/test_tilt_table.py, and tests/test_montecarlo.py against this module). So the default
``rig="static"`` evaluates that closed form per window (:func:`static_rig`; the window
layout, computed once per worker by :func:`window_layout`, follows the MuJoCo rig's timing
exactly: slews at 6 deg/s, 2 s settle, 15 min remount); ``rig="mujoco"`` runs the full MuJoCo
table per run and keeps its windows (:func:`keep_windows`).
"""
from __future__ import annotations

import json
from functools import lru_cache

import numpy as np

from imurig.kernel.recording import Recording
from imurig.kernel.site import Site, parse_time
from imurig.kernel.units import DEG
from imurig.rigs.tilt_table import (
    MOUNTS,
    TableSurvey,
    TiltTableErrors,
    TiltTableProtocol,
    _command_profile,
    rot_x,
    rot_y,
    rot_z,
)

LAYOUT_KEYS = ("theta_deg", "phi_deg", "mounts", "dwell_s", "settle_s", "slew_rate_deg_s", "remount_s",
               "sample_rate_hz")


def table_protocol(p: dict) -> TiltTableProtocol:
    """The rig protocol of the Monte-Carlo settings ``p``."""
    return TiltTableProtocol(theta_deg=tuple(p["theta_deg"]), phi_deg=tuple(p["phi_deg"]),
                             runs=tuple(p["mounts"]), dwell_s=float(p["dwell_s"]), settle_s=float(p["settle_s"]),
                             slew_rate_deg_s=float(p["slew_rate_deg_s"]), remount_s=float(p["remount_s"]),
                             sample_rate_hz=float(p["sample_rate_hz"]))


def layout_key(p: dict) -> str:
    """The settings that fix the window layout, as a hashable JSON key for :func:`window_layout`."""
    return json.dumps({k: p[k] for k in LAYOUT_KEYS}, sort_keys=True)


@lru_cache(maxsize=16)
def window_layout(key: str) -> dict:
    """Acquisition windows of the schedule (computed once per worker): the MuJoCo rig's timing."""
    p = json.loads(key)
    proto = table_protocol(p).validate()
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
    lay = window_layout(layout_key(p))
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
    proto = table_protocol(p)
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


def keep_windows(rig: Recording) -> Recording:
    """The acquisition windows of a full MuJoCo rig recording (what the logger saves)."""
    keep = np.concatenate([np.arange(s.start, s.stop) for s in rig.segment_slices()])
    return rig.replace(time_s=rig.time_s[keep], channels={k: v[keep] for k, v in rig.channels.items()},
                       truth_signals={k: v[keep] for k, v in rig.truth_signals.items()})
