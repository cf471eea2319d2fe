"""Score a user's navigation filter on the project's simulated flight (issue 6 wired to issue 8).

The flight is the chain the ``imurig flight`` job uses (:mod:`imurig.campaigns.flight`), made short:

    plan --MuJoCo--> FlightTruth (100 Hz at the IMU)
        -> IMU lab drawn from ``seed`` -> raw volts (Q-Flex, FOG, fluxgate, DAQ-6036E)
        -> datasheet-nominal conversions:   f_B = V_acc / S_acc,nom      [m/s^2]   (n, 3)
                                            w_IB_B = V_gyro / S_gyro,nom [rad/s]   (n, 3)
                                            B_B = V_mag / 4e4 V/T        [T]       (n, 3)
        -> Euro4 RTK receiver at 1 Hz: antenna fixes, time of validity = tag − latency − Δt_IMU/2

(``calibrated=True`` instead applies the tilt-/turn-table and magnetometer-rig calibrations of
the same IMU, as the job's "calibrated" run; slower.)

Frames handed to the filter and used for the truth (the scorer's, :mod:`imurig.scoring.interface`):
N0 is NED tangent to the WGS-84 ellipsoid at the flight's first IMU position (``meta['origin_deg']``),
fixed to the Earth; ``r_N`` are metres from that origin, ``v_N`` the velocity w.r.t. Earth in N0
axes, ``q_NB`` maps body FRD to N0. With C_EN(φ, λ) the local-NED-to-ECEF rotation,

    C_N0N = C_EN(φ0, λ0)ᵀ C_EN(φ, λ);   v_N0 = C_N0N v_N;   C_N0B = C_N0N C_NB

(the local-level frame N at the vehicle turns away from N0 by ~0.5 mrad per 3 km flown, so this
matters at the 0.1 deg level). GPS positions are of the antenna (lever arm ``meta['lever_gps_B_m']``).

The filter never sees truth: streams hold measured data only; ``meta`` holds what an operator
knows beforehand (origin, site, date, lever arms, datasheet noise figures, receiver settings,
IGRF declination), never the drawn sensor errors or the true trajectory.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace
from types import SimpleNamespace

import numpy as np

from imurig.campaigns import flight as study
from imurig.flights import earth as E
from imurig.flights import ekf
from imurig.flights.plan import DoubleDoublet, FlightPlan, Level, simulate_flight
from imurig.kernel.errors import ConfigError
from imurig.kernel.estimator import Estimator
from imurig.kernel.navdata import GpsFixes, ImuStream
from imurig.kernel.site import decimal_year, parse_time
from imurig.scoring.interface import (
    EstimatesError,
    MagStream,
    NavFilter,
    NavSolution,
    NavStreams,
    fitted_solution,
)
from imurig.scoring.nav import quat_mul, rotvec_to_quat, score_navigation
from imurig.sensors.chain import ImuLab

DEG = math.pi / 180
BLOCK_UNITS = {"position": "m", "velocity": "m/s", "attitude": "rad"}


def default_plan():
    """A short airborne flight (~84 s): 20 s level at 1500 m and 120 m/s, an elevator double
    doublet (24 s), 40 s level. Starts trimmed in the air, so alignment needs no ground phase."""
    return FlightPlan(phases=(Level(20.0), DoubleDoublet(), Level(40.0)))


# ------------------------------------------------------------------------------------ frames
def C_N0N(lat_rad, lon_rad, lat0_rad: float, lon0_rad: float) -> np.ndarray:
    """(k, 3, 3) rotation from local NED at (φ, λ) to the fixed NED N0 at (φ0, λ0)."""
    return np.einsum("ji,kjl->kil", E.C_EN(lat0_rad, lon0_rad), E.C_EN(np.atleast_1d(lat_rad), np.atleast_1d(lon_rad)))


def to_fixed_frame(origin, lat, lon, h, v_N=None, q_NB=None):
    """Geodetic position / local-NED velocity and attitude -> (r_N0 (k,3) m, v_N0, q_N0B)."""
    lat0, lon0, h0 = origin
    r = E.ned_from_geodetic(lat, lon, h, lat0, lon0, h0)
    C = C_N0N(lat, lon, lat0, lon0)
    v = None if v_N is None else np.einsum("kij,kj->ki", C, v_N)
    q = None if q_NB is None else E.q_from_C(C @ E.C_from_q(q_NB))
    return r, v, q


# ------------------------------------------------------------------------------------ streams
@dataclass
class _Opt:   # what imurig.campaigns.flight.gps_fixes reads and writes
    gps_rate_hz: float = 1.0
    gps_latency_s: float = 0.0
    gps_time_sigma_s: float = 0.0


def simulate_truth(plan=None, duration_s: float | None = None):
    """The flight's :class:`imurig.kernel.navdata.FlightTruth`, cut to ``duration_s`` if given."""
    tr = simulate_flight(plan or default_plan(), progress_bar=False)
    if duration_s is not None:
        if duration_s <= 10:
            raise ConfigError(f"duration_s {duration_s:g} s is too short; give more than 10 s")
        tr = tr.slice(tr.time_s[0], tr.time_s[0] + duration_s)
    return tr


def flight_streams(seed: int, duration_s: float | None = None, plan=None, *, calibrated: bool = False,
                   truth=None, nav_rate_hz: float = 25.0):
    """Measured streams of a simulated flight, the truth in the scorer's frames, and meta.

    Returns ``(NavStreams, truth: NavSolution, meta)``. ``seed`` draws the IMU's errors, its noise
    and the receiver's errors exactly as ``imurig flight --seed`` does (same seed => identical
    streams). ``plan`` defaults to :func:`default_plan`; ``duration_s`` cuts it; ``truth`` (a
    FlightTruth) skips the MuJoCo flight. The truth NavSolution (time_s (n,), r_N, v_N, q_NB at
    the IMU, 100 Hz) is for scoring only and is not in the streams; ``meta`` (dict) describes the
    run (plan, seed, wall times) and is also not given to the filter.
    """
    t0 = time.perf_counter()
    tr = truth if truth is not None else simulate_truth(plan, duration_s)
    if truth is not None and duration_s is not None:
        tr = tr.slice(tr.time_s[0], tr.time_s[0] + duration_s)
    t_sim = time.perf_counter() - t0
    lab = study.flight_lab(seed)
    volts = study.measure_volts(tr, lab, seed)
    opt = _Opt()
    gps = study.gps_fixes(tr, opt, seed)           # sets opt.gps_latency_s, opt.gps_time_sigma_s
    cals = None
    if calibrated:
        cals = study.calibrations(seed, True)
        cals["magnetometer"] = study.mag_calibration(lab, seed)
    st = study.imu_stream(tr, volts, lab, cals)
    origin = (float(tr.lat_rad[0]), float(tr.lon_rad[0]), float(tr.h_m[0]))

    valid = np.asarray(gps.valid, bool)
    g_r, g_v, _ = to_fixed_frame(origin, gps.lat_rad[valid], gps.lon_rad[valid], gps.h_m[valid],
                                 v_N=np.asarray(gps.v_N, float)[valid])
    rx = (gps.meta or {}).get("receiver", {})
    nominal = ImuLab()                           # datasheet values, no drawn errors
    noise = _noise_dict(nominal, tr.rate_hz)
    stream_meta = {
        "origin_deg": [math.degrees(origin[0]), math.degrees(origin[1]), origin[2]],
        "frame": "N0: NED tangent at origin_deg (Earth-fixed); B: body FRD; q_NB scalar first",
        "start_time": tr.meta.get("start_time"), "imu_rate_hz": float(tr.rate_hz), "nav_rate_hz": nav_rate_hz,
        "imu_conversion": "calibrated (tilt/turn table, mag rig)" if calibrated else "datasheet nominal",
        "lever_gps_B_m": np.asarray(tr.lever_gps_B, float).tolist(),
        "lever_mag_B_m": np.asarray(tr.lever_mag_B, float).tolist(),
        "declination_rad": float(study.flight_declination(tr)),
        "gps_time": "time of validity = logger tag − receiver latency − Δt_IMU/2; the fix is "
                    "available gps_latency_s after time_s",
        "gps_latency_s": float(opt.gps_latency_s), "gps_time_sigma_s": float(opt.gps_time_sigma_s),
        "gps_mode": gps.mode, "gps_pos_tau_s": rx.get("tau_gm_s"),
        "gps_pos_sigma_white_N_m": list(rx.get("sigma_white_N_m", (0.0, 0.0, 0.0))),
        "imu_noise": noise,
        "initial_r_N": (g_r[0]).tolist(), "initial_v_N": g_v[0].tolist(), "initial_time_s": float(gps.time_s[valid][0]),
    }
    streams = NavStreams(
        imu=ImuStream(time_s=np.array(st.time_s, float), f_B=np.array(st.f_B, float),
                      w_IB_B=np.array(st.w_IB_B, float), samples=st.samples),
        gps=GpsFixes(time_s=np.array(gps.time_s, float)[valid], r_N=g_r, v_N=g_v,
                     sigma_pos_N=np.array(gps.sigma_pos_N, float)[valid],
                     sigma_vel_N=np.array(gps.sigma_vel_N, float)[valid]),
        mag=MagStream(np.array(st.time_s, float), np.array(st.B_B, float)),
        meta=stream_meta)
    r, v, q = to_fixed_frame(origin, tr.lat_rad, tr.lon_rad, tr.h_m, v_N=tr.v_N, q_NB=tr.q_NB)
    truth_sol = NavSolution(np.array(tr.time_s, float), r, v, q)
    meta = {"seed": int(seed), "duration_s": float(tr.time_s[-1] - tr.time_s[0]), "vehicle": tr.vehicle,
            "phases": [list(p) for p in tr.phases], "calibrated": bool(calibrated),
            "plan": tr.meta.get("plan"), "sim_wall_s": t_sim, "streams_wall_s": time.perf_counter() - t0}
    return streams, truth_sol, meta


def _noise_dict(lab, rate_hz: float) -> dict:
    n = ekf.ImuNoise.from_sensors(lab.accelerometers, lab.gyros, rate_hz)
    return {k: float(getattr(n, k)) for k in ("vrw", "arw", "gyro_bias_sigma", "gyro_bias_tau_s", "acc_bias_rw",
                                                "temp_rw", "scale_rw")}


# ------------------------------------------------------------------------------------ scoring
def trim_solution(sol: NavSolution, t_start: float) -> NavSolution:
    """The epochs of ``sol`` at or after ``t_start`` (s)."""
    m = np.asarray(sol.time_s, float) >= t_start
    if not np.any(m):
        raise EstimatesError(f"the solution has no epoch after {t_start:.3f} s (settling time)")
    kw = {k: (None if getattr(sol, k) is None else np.asarray(getattr(sol, k))[m])
          for k in ("time_s", "r_N", "v_N", "q_NB", "P_r", "P_v", "P_att")}
    return NavSolution(**kw)


def score_nav_filter_on_flight(nav_filter: NavFilter, seed: int = 2005, duration_s: float | None = None,
                               plan=None, *, settle_s: float = 10.0, calibrated: bool = False,
                               streams=None) -> dict:
    """Fit ``nav_filter`` on the flight's streams (:func:`flight_streams`) and score it with
    :func:`imurig.scoring.nav.score_navigation` after ``settle_s`` s of alignment transient.

    Returns ``{"position"|"velocity"|"attitude": {rms, max_abs, rms_norm, unit, [anees, nees_interval,
    consistent]}, "meta": {...}}``. ``streams`` = (NavStreams, truth, meta) reuses a flight.
    """
    s, truth, meta = streams if streams is not None else flight_streams(seed, duration_s, plan, calibrated=calibrated)
    t0 = time.perf_counter()
    sol = fitted_solution(nav_filter, s)
    wall = time.perf_counter() - t0
    out = score_navigation(trim_solution(sol, float(s.imu.time_s[0]) + settle_s), truth)
    out["meta"] = {**{k: v for k, v in meta.items() if k != "plan"}, "settle_s": settle_s, "filter_wall_s": wall,
                   "filter": type(nav_filter).__name__}
    return out


class NavScoreFailure(AssertionError):
    """A navigation score missed its bound; the message names the quantity and the miss."""


def assert_nav_meets(score: dict, max_rms_norm: dict | None = None, *, consistent: tuple = ()) -> None:
    """Assert ``score[block]['rms_norm'] <= max_rms_norm[block]`` for each given block
    (position m, velocity m/s, attitude rad), and ANEES inside its interval for the blocks in
    ``consistent``. Raises :class:`NavScoreFailure` naming every quantity that missed, by how much."""
    misses = []
    for block, bound in (max_rms_norm or {}).items():
        if block not in score:
            misses.append(f"{block}: not reported by the filter")
            continue
        v = score[block]["rms_norm"]
        if not v <= bound:
            misses.append(f"{block} RMS error {v:.4g} {BLOCK_UNITS[block]} exceeds the bound {bound:.4g} "
                          f"{BLOCK_UNITS[block]} ({v / bound:.3g}x)")
    for block in consistent:
        r = score.get(block, {})
        if "anees" not in r:
            misses.append(f"{block}: no covariance reported, consistency cannot be checked")
        elif not r["consistent"]:
            lo, hi = r["nees_interval"]
            misses.append(f"{block} ANEES {r['anees']:.3g} outside [{lo:.3g}, {hi:.3g}]")
    if misses:
        raise NavScoreFailure("navigation score failed: " + "; ".join(misses))


# ------------------------------------------------------------------------------------ baseline
class ProjectEKF(Estimator):
    """The project's loosely coupled EKF (:class:`imurig.flights.ekf.LooseEKF`): the paper's 18 states and,
    when the stream names the receiver's Gauss-Markov error, its 3 error states (21), set up
    as ``imurig flight`` sets it up (25 Hz, magnetic heading σ 2 deg, IGRF declination along the route,
    GPS latency and Gauss-Markov error states, accelerometer-levelling + compass alignment over the
    first 5 s), behind the
    :class:`NavFilter` interface: it uses only the streams and their meta.

    ``use_gps=False`` gives the same filter without GPS (dead reckoning + compass), a deliberately
    poor filter for tests. Covariances P_r, P_v, P_att are reported (rotated into N0).
    Fitted: ``solution_`` (:class:`NavSolution` in N0) and ``filter_`` (the fitted LooseEKF).
    """

    def __init__(self, use_gps: bool = True, nav_rate_hz: float | None = None):
        self.use_gps = use_gps
        self.nav_rate_hz = nav_rate_hz

    def apply(self) -> NavSolution:
        """The filtered solution in N0 (``solution_``)."""
        self.check_fitted()
        return self.solution_

    def fit(self, streams: NavStreams) -> ProjectEKF:
        self._clear_fitted()
        m = streams.meta
        lat0, lon0 = math.radians(m["origin_deg"][0]), math.radians(m["origin_deg"][1])
        origin = (lat0, lon0, float(m["origin_deg"][2]))
        t = np.asarray(streams.imu.time_s, float)
        B = None
        if streams.mag is not None:
            B = np.stack([np.interp(t, streams.mag.time_s, streams.mag.B_B[:, j]) for j in range(3)], 1)
        imu = ImuStream(time_s=t, f_B=np.asarray(streams.imu.f_B, float), w_IB_B=np.asarray(streams.imu.w_IB_B, float),
                        B_B=B, samples=streams.imu.samples)
        g = streams.gps
        lat, lon, h = E.geodetic_from_ned(np.asarray(g.r_N, float), *origin)
        C = C_N0N(lat, lon, lat0, lon0)
        v_loc = np.einsum("kji,kj->ki", C, np.asarray(g.v_N, float))
        gps = GpsFixes(time_s=np.asarray(g.time_s, float), lat_rad=lat, lon_rad=lon, h_m=h, v_N=v_loc,
                       sigma_pos_N=g.sigma_pos_N, sigma_vel_N=g.sigma_vel_N, mode=m.get("gps_mode", ""))
        extra = {}
        if m.get("gps_pos_tau_s"):
            extra = {"gps_pos_tau_s": float(m["gps_pos_tau_s"]), "gps_pos_states": True,
                     "gps_pos_sigma_white_N_m": tuple(m["gps_pos_sigma_white_N_m"])}
        cfg = ekf.FilterConfig(nav_rate_hz=self.nav_rate_hz or m.get("nav_rate_hz", 25.0),
                               mag_heading_sigma_rad=2 * DEG, gps_latency_s=m["gps_latency_s"],
                               gps_time_sigma_s=m["gps_time_sigma_s"], **extra)
        noise = ekf.ImuNoise(**m["imu_noise"])
        lever = np.asarray(m["lever_gps_B_m"], float)
        # IGRF declination along the route at the flight's date (a constant one is 0.13 deg off on average
        # over the default route); the stream's constant ``declination_rad`` only without a start time
        decl = m["declination_rad"]
        if m.get("start_time"):
            decl = ekf.IgrfDeclination(decimal_year(parse_time(m["start_time"])))
        f = ekf.LooseEKF(cfg, noise, lever_gps_B=lever, declination=decl)
        x0 = study.align(SimpleNamespace(rate_hz=m["imu_rate_hz"], lever_gps_B=lever), imu, gps, decl)
        self.filter_ = f.fit(imu, gps if self.use_gps else None, x0)
        res = f.solution_
        r, v, q = to_fixed_frame(origin, res.lat_rad, res.lon_rad, res.h_m, v_N=res.v_N, q_NB=res.q_NB)
        Cn = C_N0N(res.lat_rad, res.lon_rad, lat0, lon0)
        Pn = np.asarray(res.P_nav, float)

        def rot(Pb):
            return np.einsum("kij,kjl,kml->kim", Cn, Pb, Cn)

        self.solution_ = NavSolution(np.asarray(res.time_s, float), r, v, q, P_r=rot(Pn[:, 0:3, 0:3]),
                                     P_v=rot(Pn[:, 3:6, 3:6]), P_att=rot(Pn[:, 6:9, 6:9]))
        return self


class AttitudeOffset(Estimator):
    """Wraps a filter and rotates its attitude by a fixed body-frame offset ``rotvec_B`` (rad):
    q_NB' = q_NB ⊗ q(rotvec_B). A deliberately biased filter for tests (fits ``inner`` in place)."""

    def __init__(self, inner, rotvec_B: tuple = (0.0, 0.0, 2.0 * DEG)):
        self.inner = inner
        self.rotvec_B = rotvec_B

    def fit(self, streams: NavStreams) -> AttitudeOffset:
        self._clear_fitted()
        s = fitted_solution(self.inner, streams)
        dq = rotvec_to_quat(np.asarray(self.rotvec_B, float))
        self.solution_ = replace(s, q_NB=quat_mul(np.asarray(s.q_NB, float), np.broadcast_to(dq, s.q_NB.shape)))
        return self

    def apply(self) -> NavSolution:
        self.check_fitted()
        return self.solution_
