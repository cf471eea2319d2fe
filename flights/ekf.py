"""Loosely coupled GPS/INS error-state EKF with the 18 states of the paper's section 4.2, as an
estimator of the bench's contract (:mod:`imurig.kernel.estimator`)::

    f = LooseEKF(config, noise, lever_gps_B=l_B, declination=D)   # settings only
    f.fit(imu, gps, x0, P0=P0)                                     # runs the filter; returns f
    f.solution_                                                    # the FilterResult
    f.apply()                                                      # the filtered solution

The modules behind it, by responsibility:

- :mod:`imurig.flights.filter_config`: the error state's layout (δr_N, δv_N, ψ_N, δb_a, δb_g, δT_a
  and the optional blocks), the sensor noise model :class:`ImuNoise`, the settings
  :class:`FilterConfig`;
- :mod:`imurig.flights.ekf_model`: the linearised error dynamics F, Q, P0 (initial and from a static
  alignment), the attitude reset and the propagation between epochs;
- :mod:`imurig.flights.ekf_updates`: the GPS position and velocity, compass and temperature updates;
- :mod:`imurig.flights.compass`: the magnetic heading, its Jacobians and the IGRF declination;
- :mod:`imurig.flights.ekf_state`: the running estimate (x̂, P, sensor-error estimates) and the record.

The paper's "3 accelerometer temperatures" are implemented as states T_a (the accelerometers'
own temperatures) measured by the Q-Flex temperature channels and coupled into the specific
force through the bias temperature slope k_T (m/s²/K, from the thermal calibration; zero
without one). The INS (:mod:`imurig.flights.ins`) runs on the corrected increments at the
navigation rate. Each update records its normalised innovation squared (NIS) and dof.
"""
from __future__ import annotations

import bisect
from dataclasses import dataclass, field
from typing import Self

import numpy as np
from imurig.flights import ins
from imurig.flights import navmath as nm
from imurig.flights.compass import (IgrfDeclination, declination_rad, mag_corrected_field, mag_heading,
                                    mag_heading_jacobian, mag_iron_hessian, mag_iron_jacobian, mag_iron_prior_cov)
from imurig.flights.ekf_model import (alignment_covariance, attitude_reset_jacobian, error_dynamics,
                                      initial_covariance, process_noise, propagate)
from imurig.flights.ekf_state import EpochData, FilterState, SolutionRecord
from imurig.flights.ekf_updates import GpsSchedule, consider_mask, gps_updates, mag_update, temp_update
from imurig.flights.filter_config import (BASE_STATES, GPS_STATES, GYRO_GM_STATES, K2_STATES, MAG_IRON_STATES,
                                          MIS_PAIRS, MIS_STATES, SCALE_STATES, THERMAL_STATES, FilterConfig,
                                          ImuNoise)
from imurig.sensors.thermal import hysteresis_state

from imurig.kernel.errors import ConfigError, RecordingError
from imurig.kernel.estimator import Estimator
from imurig.kernel.navdata import GpsFixes, ImuStream

__all__ = [  # the filter's public names, importable from here
    "LooseEKF", "FilterResult", "FilterConfig", "ImuNoise", "check_gps", "nees_nav", "IgrfDeclination",
    "declination_rad", "mag_heading", "mag_heading_jacobian", "mag_corrected_field", "mag_iron_jacobian",
    "mag_iron_hessian", "mag_iron_prior_cov", "attitude_reset_jacobian", "BASE_STATES", "SCALE_STATES",
    "GPS_STATES", "GYRO_GM_STATES", "K2_STATES", "THERMAL_STATES", "MIS_PAIRS", "MIS_STATES", "MAG_IRON_STATES",
]


@dataclass
class FilterResult:
    """Filter output at the navigation epochs ``time_s`` (M,)."""

    time_s: np.ndarray
    lat_rad: np.ndarray
    lon_rad: np.ndarray
    h_m: np.ndarray
    v_N: np.ndarray
    q_NB: np.ndarray
    acc_bias_m_s2: np.ndarray
    gyro_bias_rad_s: np.ndarray
    temp_acc_K: np.ndarray
    scale_acc: np.ndarray
    scale_gyro: np.ndarray
    P_diag: np.ndarray           # (M, n) variances of the error state
    P_nav: np.ndarray            # (M, 9, 9) covariance of δr, δv, ψ
    state_names: tuple
    updates: dict                # kind -> dict(time_s, nis, dof, innovation)
    meta: dict = field(default_factory=dict)


def _check_stream(imu: ImuStream) -> np.ndarray:
    t = np.asarray(imu.time_s, float)
    for name in ("w_IB_B", "f_B", "B_B", "T_acc_K"):
        a = getattr(imu, name)
        if a is None:
            continue
        a = np.asarray(a, float)
        if a.shape != (t.size, 3):
            raise RecordingError(f"IMU stream '{name}' has shape {a.shape}, expected ({t.size}, 3)")
        if not np.all(np.isfinite(a)):
            raise RecordingError(f"IMU stream '{name}' contains NaN/inf; clean the recording first")
    return t


def check_gps(gps: GpsFixes, imu_rate_hz: float) -> np.ndarray:
    """Refuse GPS fixes that cannot be used: local (r_N) instead of geodetic positions, NaN in valid
    fixes, non-increasing times, or a fix rate above the IMU rate."""
    if not gps.geodetic:
        raise RecordingError("the filter needs geodetic GPS fixes (lat_rad, lon_rad, h_m); convert r_N with the "
                             "origin of its frame (imurig.flights.earth.geodetic_from_ned)")
    t = np.asarray(gps.time_s, float)
    if t.size == 0:
        raise RecordingError("no GPS fixes: the loosely coupled filter needs at least one")
    if np.any(np.diff(t) <= 0):
        raise RecordingError("GPS fix time tags must be strictly increasing")
    if t.size > 1:
        rate = 1.0 / float(np.median(np.diff(t)))
        if rate > imu_rate_hz:
            raise ConfigError(f"GPS rate {rate:g} Hz is above the IMU rate {imu_rate_hz:g} Hz; "
                              "use a GPS rate at or below the IMU rate")
    valid = np.asarray(gps.valid, bool)
    for name in ("lat_rad", "lon_rad", "h_m", "v_N", "sigma_pos_N", "sigma_vel_N"):
        v = getattr(gps, name)
        if v is None:
            raise RecordingError(f"GPS fixes without '{name}': the filter needs positions, velocities and their σ")
        if not np.all(np.isfinite(np.asarray(v, float)[valid])):
            raise RecordingError(f"GPS field '{name}' has NaN/inf in fixes marked valid")
    return t


def epoch_data(imu: ImuStream, cfg: FilterConfig) -> EpochData:
    """The stream pre-integrated to the navigation rate (K samples per epoch) and the per-step inputs
    the optional states need (:class:`imurig.flights.ekf_state.EpochData`)."""
    t_imu = _check_stream(imu)
    fs = 1.0 / float(np.median(np.diff(t_imu)))
    K = max(1, round(fs / cfg.nav_rate_hz))
    inc = ins.preintegrate(t_imu, imu.w_IB_B, imu.f_B, K, samples=imu.samples)
    M = inc.dtheta_B.shape[0]
    idx = np.arange(M + 1) * K
    f2 = None
    if cfg.estimate_nonlinearity:                  # mean of f² over each step's K samples (held)
        f2 = np.square(np.asarray(imu.f_B, float)[: M * K]).reshape(M, K, 3).mean(axis=1)
    dT = dh = None
    if cfg.estimate_thermal_terms:
        if imu.T_acc_K is None:
            raise ConfigError("estimate_thermal_terms needs the accelerometer temperature channels (T_acc_K)")
        Tacc = np.asarray(imu.T_acc_K, float)
        hacc = np.stack([hysteresis_state(Tacc[:, j], cfg.hysteresis_width_K, fs) for j in range(3)], 1)
        # step means over each navigation interval, relative to the first step (the alignment)
        dT = Tacc[: M * K].reshape(M, K, 3).mean(axis=1)
        dh = hacc[: M * K].reshape(M, K, 3).mean(axis=1)
        dT, dh = dT - dT[0], dh - dh[0]
    return EpochData(t_s=inc.t_s, T=inc.T_s, K=K, idx=idx, dtheta_B=inc.dtheta_B, dv_B=inc.dv_B,
                     f_B=np.asarray(imu.f_B)[idx], w_B=np.asarray(imu.w_IB_B)[idx], f2_B=f2, dT=dT, dh=dh,
                     T_acc_K=None if imu.T_acc_K is None else np.asarray(imu.T_acc_K, float),
                     B_B=imu.B_B, fs=fs)


class LooseEKF(Estimator):
    """The loosely coupled error-state filter (module doc).

    Settings: ``config`` (:class:`FilterConfig`, default ``FilterConfig()``), ``noise``
    (:class:`ImuNoise`, default ``ImuNoise()``), ``lever_gps_B`` (3,) m the antenna relative to the
    IMU in body axes, ``declination`` the IGRF declination in rad (east positive), a constant or a
    callable D(lat_rad, lon_rad, h_m) such as :class:`IgrfDeclination`, ``compiled`` whether the paper's
    18-state filter (also with the receiver's error states) runs its propagation between updates
    in compiled code (:mod:`imurig.flights.ekf_kernel`, the default; False: the plain Python path,
    the reference it is tested against; with sensor-error or compass states it always runs in Python).

    Fitted: ``solution_`` (:class:`FilterResult`), the filtered solution at the navigation epochs.
    """

    def __init__(self, config: FilterConfig | None = None, noise: ImuNoise | None = None,
                 lever_gps_B=(0.0, 0.0, 0.0), declination=0.0, compiled: bool = True):
        self.config = config
        self.noise = noise
        self.lever_gps_B = lever_gps_B
        self.declination = declination
        self.compiled = compiled

    # ------------------------------------------------------------------ settings, resolved
    @property
    def cfg(self) -> FilterConfig:
        return self.config if self.config is not None else FilterConfig()

    def _noise(self) -> ImuNoise:
        return self.noise if self.noise is not None else ImuNoise()

    def _lever(self) -> np.ndarray:
        return np.asarray(self.lever_gps_B, float)

    def _validate(self) -> FilterConfig:
        c = self.cfg
        if c.nav_rate_hz <= 0:
            raise ConfigError("nav_rate_hz must be positive")
        if c.gps_pos_tau_s is not None and not c.gps_pos_tau_s > 0:
            raise ConfigError(f"gps_pos_tau_s must be > 0 s, got {c.gps_pos_tau_s!r}")
        if c.mag_error_state and c.mag_iron_states:
            raise ConfigError("mag_error_state and mag_iron_states model the same compass error: choose one")
        if c.mag_iron_states:
            Pm = None if c.mag_iron_prior_cov is None else np.asarray(c.mag_iron_prior_cov, float)
            if Pm is None or Pm.shape != (12, 12) or not np.all(np.isfinite(Pm)) or np.any(np.linalg.eigvalsh(
                    0.5 * (Pm + Pm.T)) < 0):
                raise ConfigError("mag_iron_states needs mag_iron_prior_cov: a finite positive semi-definite "
                                  "(12, 12) covariance of [b (T), ΔA] (see ekf.mag_iron_prior_cov)")
        return c

    def _declination(self, x: ins.NavState) -> float:
        d = self.declination
        return d(x.lat_rad, x.lon_rad, x.h_m) if callable(d) else float(d)

    # ------------------------------------------------------------------ model queries
    def error_dynamics(self, x: ins.NavState, f_B, w_B, C, thermal=None) -> np.ndarray:
        """F (n, n) at ``x`` (:func:`imurig.flights.ekf_model.error_dynamics`)."""
        return error_dynamics(self.cfg, self._noise(), x, f_B, w_B, C, thermal)

    def initial_covariance(self, gps_gm_var=None) -> np.ndarray:
        """P0 (n, n) from the configured initial 1σ (:func:`imurig.flights.ekf_model.initial_covariance`)."""
        return initial_covariance(self._validate(), self._noise(), gps_gm_var)

    def alignment_covariance(self, x0: ins.NavState, f_B, B_B, gps: GpsFixes, *, window_s: float,
                             sigma_mag_rad: float, sigma_level_f_m_s2: float | None = None) -> np.ndarray:
        """P0 (n, n) of a static alignment (:func:`imurig.flights.ekf_model.alignment_covariance`)."""
        return alignment_covariance(self._validate(), self._noise(), self._lever(), x0, f_B, B_B, gps,
                                    window_s=window_s, sigma_mag_rad=sigma_mag_rad,
                                    sigma_level_f_m_s2=sigma_level_f_m_s2)

    # ------------------------------------------------------------------ the contract
    def fit(self, imu: ImuStream, gps: GpsFixes | None, x0: ins.NavState, *, P0=None, progress=None) -> Self:
        """Run the filter over the IMU stream from ``x0`` (:class:`imurig.flights.ins.NavState` at
        ``imu.time_s[0]``) with the geodetic GPS fixes ``gps`` (None: no GPS) and the stream's
        magnetometer and temperature channels. ``P0`` (n, n) defaults to :meth:`initial_covariance`;
        ``progress`` (optional) is called with the number of epochs done. Returns ``self`` with
        ``solution_``."""
        self._clear_fitted()
        c = self._validate()
        noise = self._noise()
        ep = epoch_data(imu, c)
        sched = None
        gps_gm_var = np.zeros(3)
        if gps is not None:
            check_gps(gps, ep.fs)
            sched = GpsSchedule(gps, c, ep.t_s, ep.T)
            if c.augment_gps and np.any(sched.valid):
                s2_first = np.asarray(gps.sigma_pos_N, float)[np.flatnonzero(sched.valid)[0]] ** 2
                gps_gm_var = np.maximum(s2_first - np.asarray(c.gps_pos_sigma_white_N_m, float) ** 2, 0.0)
        n = c.n_states
        Pm = initial_covariance(c, noise, gps_gm_var) if P0 is None else np.array(P0, float)
        if Pm.shape != (n, n):
            raise ConfigError(f"P0 has shape {Pm.shape}, the filter has {n} states ({', '.join(c.state_names())})")
        st = FilterState(c, x0, Pm, process_noise(c, noise, gps_gm_var), gps_gm_var,
                         None if ep.T_acc_K is None else ep.T_acc_K[0], noise)
        rec = SolutionRecord(ep.M, n)
        self._run(st, rec, ep, gps, sched, noise, progress)
        rec.finish()
        self.solution_ = FilterResult(
            ep.t_s, rec.lat, rec.lon, rec.h, rec.v, rec.q, rec.ba, rec.bg, rec.T, rec.sa, rec.sg, rec.P_diag,
            rec.P_nav, c.state_names(), st.update_record(),
            meta={"nav_rate_hz": 1.0 / ep.T, "imu_rate_hz": ep.fs, "samples_per_step": ep.K,
                  "misalignment_acc_rad": st.Ma.tolist(), "misalignment_gyro_rad": st.Mg.tolist(),
                  "nonlinearity_acc_s2_m": st.k2.tolist(), "thermal_terms_acc": st.th.tolist(),
                  "gyro_bias_gm_rad_s": st.bgm.tolist(), "mag_hard_iron_T": st.theta_m[:3].tolist(),
                  "mag_matrix_error": st.theta_m[3:].reshape(3, 3).tolist()})
        return self

    def _run(self, st: FilterState, rec: SolutionRecord, ep: EpochData, gps, sched, noise: ImuNoise,
             progress) -> None:
        """Epochs 0..M: the updates due at epoch k, the record, the propagation to k+1."""
        c = st.cfg
        lever = self._lever()
        consider = consider_mask(c, st.lay)
        mag_every = max(1, round(c.nav_rate_hz / c.mag_rate_hz)) if (c.use_magnetometer and ep.B_B is not None) else 0
        temp_every = max(1, round(c.nav_rate_hz / c.temp_rate_hz)) if ep.T_acc_K is not None else 0
        spans = None
        if self.compiled and st.compilable:   # the paper's states: the epochs between updates compiled
            from imurig.flights import ekf_kernel   # lazy: numba (~0.4 CPU-s to import)
            spans = ekf_kernel.SpanPropagator(st, ep, rec)
        gps_at = sorted(sched.at) if sched is not None else []
        k = 0
        while True:
            if sched is not None and k in sched.at:
                gps_updates(st, rec, ep, gps, sched, k, lever)
            if mag_every and k % mag_every == 0:
                mag_update(st, ep, k, self._declination(st.x), consider)
            C = nm.dcm(st.x.q_NB.tolist())   # C_NB the propagation linearises at (before the temperatures)
            if temp_every and k % temp_every == 0:
                temp_update(st, ep, k)
            rec.store(k, st)
            if k == ep.M:
                break
            if spans is not None:            # to the next epoch with an update (or a progress call)
                k1 = _next_event(k, ep.M, gps_at, (mag_every, temp_every, 500 if progress is not None else 0))
                spans.run(k, k1, C)
            else:
                propagate(st, ep, k, C, noise)
                k1 = k + 1
            if progress is not None and k % 500 == 0:
                progress(k)
            k = k1

    def apply(self) -> FilterResult:
        """The filtered solution (``solution_``)."""
        self.check_fitted()
        return self.solution_


def _next_event(k: int, M: int, gps_at: list, every: tuple) -> int:
    """The first epoch after k at which the filter does more than propagate: a GPS fix is used
    (``gps_at`` sorted), a multiple of a nonzero period in ``every`` (compass, temperatures,
    progress), or the last epoch M."""
    i = bisect.bisect_right(gps_at, k)
    nxt = [M] + ([gps_at[i]] if i < len(gps_at) else []) + [(k // e + 1) * e for e in every if e]
    return min(nxt)


def nees_nav(res: FilterResult, truth, idx) -> np.ndarray:
    """NEES (M,) of the 9 navigation error states (δr, δv, ψ) against ``truth`` at indices
    ``idx`` (M,): e = [r_est − r_true (NED m), v_est − v_true, ψ]; NEES = eᵀ P⁻¹ e (dof 9)."""
    sol = ins.NavSolution(res.time_s, res.lat_rad, res.lon_rad, res.h_m, res.v_N, res.q_NB)
    err = ins.nav_errors(sol, truth, idx)
    e = np.concatenate([err["pos_N_m"], err["vel_N_m_s"], err["att_N_rad"]], axis=1)
    return np.einsum("ni,ni->n", e, np.linalg.solve(res.P_nav, e[..., None])[..., 0])

