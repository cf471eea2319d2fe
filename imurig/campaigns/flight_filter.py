"""The flight's navigation filter as ``imurig flight`` runs it: priors, alignment, the loosely
coupled EKF (:class:`imurig.flights.ekf.LooseEKF`), and its errors against the truth.
"""
from __future__ import annotations

import math

import numpy as np

from imurig.campaigns.flight_priors import declination_model, filter_settings, imu_noise
from imurig.flights import earth as E
from imurig.flights import ekf, ins
from imurig.sensors.chain import ImuLab

DEG = math.pi / 180
ALIGN_WINDOW_S = 5.0   # s of levelling and compass averaging for the initial attitude


def run_filter(truth, stream, gps, opt, lab: ImuLab, pbar=None, cals: dict | None = None):
    """The filter as ``imurig flight`` runs it: priors from the datasheet (``cals`` None) or from the
    calibrations' standard errors, the states of the variant ``opt.filter``
    (:func:`imurig.campaigns.flight_priors.filter_settings`: ``paper18``, the paper's 18, or
    ``extended``, which adds the scale-factor and misalignment states the nominal conversions need at
    1-2 % and 2 mrad, and the other sensor-error states); P0 from the alignment's own error
    propagation (:meth:`ekf.LooseEKF.alignment_covariance`). ``opt`` (a
    :class:`imurig.campaigns.flight.FlightOptions`) gives the navigation rate, the GPS time of validity
    (``gps_latency_s``, ``gps_time_sigma_s``) and, with ``extended``, in ``mag_iron_states`` the
    uncalibrated compass's error model (iron states instead of the Gauss-Markov heading error)."""
    noise = imu_noise(lab, truth.rate_hz)
    settings = filter_settings(opt.filter, truth, gps, noise, cals, opt.mag_iron_states)
    cfg = ekf.FilterConfig(nav_rate_hz=opt.nav_rate_hz, gps_latency_s=opt.gps_latency_s,
                           gps_time_sigma_s=opt.gps_time_sigma_s, **settings)
    decl = declination_model(truth)
    f = ekf.LooseEKF(cfg, noise, lever_gps_B=truth.lever_gps_B, declination=decl)
    x0 = align(truth, stream, gps, decl)
    f_m, B_m = alignment_means(truth, stream)
    P0 = f.alignment_covariance(x0, f_m, B_m, gps, window_s=ALIGN_WINDOW_S, sigma_mag_rad=cfg.mag_heading_sigma_rad)
    last = [0]

    def cb(k):
        if pbar is not None:
            pbar.update(k - last[0])
        last[0] = k

    return f.fit(stream, gps, x0, P0=P0, progress=cb).solution_


def alignment_means(truth, stream, window_s: float = ALIGN_WINDOW_S):
    """Mean specific force (3,) m/s² and mean field (3,) T over the first ``window_s`` s."""
    n = max(1, int(window_s * truth.rate_hz))
    return np.asarray(stream.f_B[:n], float).mean(0), np.asarray(stream.B_B[:n], float).mean(0)


def align(truth, stream, gps, decl, window_s=ALIGN_WINDOW_S) -> ins.NavState:
    """Initial state: position/velocity from the first fix, roll/pitch by accelerometer levelling
    over the first ``window_s`` s, heading from the magnetometer (+ declination ``decl``: rad, or a
    callable D(lat, lon, h) evaluated at the first fix)."""
    fm, Bm = alignment_means(truth, stream, window_s)
    roll = math.atan2(-fm[1], -fm[2])
    pitch = math.atan2(fm[0], math.hypot(fm[1], fm[2]))
    if callable(decl):
        i = int(np.flatnonzero(np.asarray(gps.valid, bool))[0])
        decl = decl(float(gps.lat_rad[i]), float(gps.lon_rad[i]), float(gps.h_m[i]))
    yaw = ekf.mag_heading(Bm, roll, pitch, decl)
    q = E.q_from_euler(roll, pitch, yaw)
    i = int(np.flatnonzero(np.asarray(gps.valid, bool))[0])
    Cl = E.C_from_q(q) @ np.asarray(truth.lever_gps_B, float)
    lat, lon, h = E.geodetic_from_ned(-Cl, gps.lat_rad[i], gps.lon_rad[i], gps.h_m[i])
    return ins.NavState(float(lat), float(lon), float(h), np.asarray(gps.v_N[i], float).copy(), q)


def errors(res: ekf.FilterResult, truth) -> dict:
    K = res.meta["samples_per_step"]
    idx = np.arange(res.time_s.size) * K
    sol = ins.NavSolution(res.time_s, res.lat_rad, res.lon_rad, res.h_m, res.v_N, res.q_NB)
    e = ins.nav_errors(sol, truth, idx)
    r_est, p_est, y_est = E.euler_from_q(res.q_NB)
    r_t, p_t, y_t = E.euler_from_q(truth.q_NB[idx])
    return {"idx": idx, "pos_N_m": e["pos_N_m"], "vel_N_m_s": e["vel_N_m_s"],
            "roll_rad": E.wrap_pi(r_est - r_t), "pitch_rad": E.wrap_pi(p_est - p_t),
            "heading_rad": E.wrap_pi(y_est - y_t), "nees": ekf.nees_nav(res, truth, idx)}


def mag_heading_error_rms_deg(truth, stream, decl, every_s: float = 1.0) -> float:
    """RMS (deg) of the magnetometer's own heading (levelled with the TRUE roll and pitch, + IGRF
    declination ``decl``: rad, or a callable D(lat, lon, h)) against the true heading, once per
    ``every_s``: the compass error alone."""
    step = max(1, round(every_s * truth.rate_hz))
    i = np.arange(0, truth.n, step)
    _, _, y = E.euler_from_q(truth.q_NB[i])
    return _rms(E.wrap_pi(compass_heading(truth, stream, decl, i) - y)) / DEG


def compass_heading(truth, stream, decl, i: np.ndarray) -> np.ndarray:
    """The magnetometer's own heading (rad) at the samples ``i``: ``stream.B_B`` levelled with the
    TRUE roll and pitch, plus the declination ``decl`` (rad, or a callable D(lat, lon, h))."""
    r, p_, _ = E.euler_from_q(truth.q_NB[i])
    dec = (lambda j: decl(truth.lat_rad[j], truth.lon_rad[j], truth.h_m[j])) if callable(decl) else (lambda j: decl)
    return np.array([ekf.mag_heading(stream.B_B[j], r[k], p_[k], dec(j)) for k, j in enumerate(i)])


def _rms(x):
    return float(np.sqrt(np.mean(np.square(x))))


#: the filter's settling after alignment, left out of the error statistics (s)
SETTLE_S = 60.0


def summarise(err: dict, res: ekf.FilterResult, settle_s: float = SETTLE_S) -> dict:
    m = res.time_s >= res.time_s[0] + settle_s
    out = {"roll_rms_deg": _rms(err["roll_rad"][m]) / DEG, "pitch_rms_deg": _rms(err["pitch_rad"][m]) / DEG,
           "heading_rms_deg": _rms(err["heading_rad"][m]) / DEG,
           "horizontal_position_rms_m": _rms(np.linalg.norm(err["pos_N_m"][m, :2], axis=1)),
           "vertical_position_rms_m": _rms(err["pos_N_m"][m, 2]),
           "velocity_rms_m_s": _rms(np.linalg.norm(err["vel_N_m_s"][m], axis=1)),
           "mean_nees_9dof": float(np.mean(err["nees"][m]))}
    for kind, u in res.updates.items():
        if len(u["nis"]):
            out[f"mean_nis_per_dof_{kind}"] = float(u["nis"].sum() / u["dof"].sum())
    return out
