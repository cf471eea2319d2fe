"""GPS receiver: NovAtel Euro4 L1/L2 RTK (seed table 2.1) with its 512C antenna.

Measurement equations, per GPS epoch t_k (true time; k = 0, 1, ... at ``rate_hz``):

    r_ant(t)  = r_IMU(t) + C_NB(t) l_B                                  antenna position (lever arm l_B)
    v_ant(t)  = v_N(t) + C_NB(t) (ω_EB_B × l_B)                         [m/s] antenna velocity w.r.t. Earth
    δr_N,k    = x_k + e_k,  x_{k+1} = φ x_k + √(1−φ²) σ_GM n_k,  φ = e^{−Δt/τ}   [m] per NED axis
    e_k       ~ N(0, σ_w²)                                               [m] white part
    fix_k     = r_ant(t_k) + δr_N,k    (converted to lat, lon, h)
    vel_k     = v_ant(t_k) + N(0, σ_v²)                                  [m/s]
    tag_k     = ⌈(t_k + latency + offset + jitter_k) / Δt_IMU⌉ Δt_IMU   [s] IMU-clock time tag

σ_GM, τ, σ_w per mode (stand-alone, differential, RTK; RTK adds b·ppm of the baseline to
the Delft reference station). The time tag is the IMU sample at which the logger sees the
fix: the fix refers to t_k but is stamped later by the receiver latency, a constant clock
offset, a white jitter and the quantisation to the IMU clock. Outages (true-time windows)
yield ``valid = False`` and NaN values; after each outage the correlated error is redrawn
(the receiver re-acquires and, in RTK, resolves its ambiguities anew).

Datasheet figures (OEM4/Euro4 family, NovAtel): single point L1/L2 1.5 m CEP, DGPS
0.45 m CEP, RT-2 1 cm + 1 ppm CEP; velocity 0.03 m/s RMS; 20 Hz maximum rate; latency
< 20 ms; time 20 ns RMS. CEP converts to a per-axis σ as σ = CEP / 1.1774 (circular
normal); vertical σ is taken 1.7 × the horizontal one. The correlation times are
assumptions (atmospheric and multipath errors of code solutions decorrelate over minutes;
RTK errors over about a minute).
"""
from __future__ import annotations

import itertools
from dataclasses import asdict, dataclass

import numpy as np
from imurig.flights import earth
from imurig.flights.truth import offset_position
from scipy import signal

from imurig.kernel.errors import ConfigError
from imurig.kernel.navdata import FlightTruth, GpsFixes

MODES = ("standalone", "differential", "rtk")
CEP_TO_SIGMA = 1.0 / 1.1774
DELFT_REFERENCE = (52.0, 4.37, 45.0)   # DGPS/RTK base: the Geodesy institute roof (seed 5.2)


@dataclass(frozen=True)
class GpsReceiver:
    """The receiver's error model in SI. Use :meth:`euro4` for datasheet units."""

    mode: str = "rtk"
    rate_hz: float = 1.0
    sigma_gm_N_m: tuple = (0.0085, 0.0085, 0.0144)     # correlated part, per NED axis
    tau_gm_s: float = 60.0
    sigma_white_N_m: tuple = (0.003, 0.003, 0.005)
    ppm_of_baseline: float = 1e-6                        # RTK: σ grows by this × baseline (per axis)
    reference_deg: tuple = DELFT_REFERENCE
    sigma_vel_m_s: tuple = (0.03, 0.03, 0.05)
    latency_s: float = 0.020
    time_offset_s: float = 0.0                           # constant tag error vs the IMU clock
    time_jitter_s: float = 0.0005
    epoch_phase_s: float = 0.0                           # first epoch after the IMU clock's zero
    quantise_to_imu: bool = True
    outages: tuple = ()                                  # ((t0, t1), ...) true time, s

    def __post_init__(self):
        if self.mode not in MODES:
            raise ConfigError(f"GPS mode {self.mode!r} is unknown; use one of {MODES}")
        if not self.rate_hz > 0 or self.rate_hz > 20:
            raise ConfigError(f"GPS rate {self.rate_hz!r} Hz: the Euro4 gives 0 < rate <= 20 Hz")
        if not self.tau_gm_s > 0:
            raise ConfigError(f"tau_gm_s must be > 0, got {self.tau_gm_s!r}")
        for name in ("sigma_gm_N_m", "sigma_white_N_m", "sigma_vel_m_s"):
            v = np.asarray(getattr(self, name), float)
            if v.shape != (3,) or np.any(v < 0) or not np.all(np.isfinite(v)):
                raise ConfigError(f"{name} must be three finite non-negative numbers (N, E, D), got {v!r}")
        if self.latency_s < 0:
            raise ConfigError(f"latency_s must be >= 0, got {self.latency_s}")
        for o in self.outages:
            if len(o) != 2 or not o[1] > o[0]:
                raise ConfigError(f"outage {o!r} must be (t_start, t_end) with t_end > t_start")

    @classmethod
    def euro4(cls, mode: str = "rtk", rate_hz: float = 1.0, *, single_point_cep_m: float = 1.5,
              dgps_cep_m: float = 0.45, rtk_cep_cm: float = 1.0, rtk_ppm: float = 1.0,
              vertical_factor: float = 1.7, correlated_fraction: float = 0.9,
              tau_s: dict | None = None, velocity_rms_m_s: float = 0.03, latency_ms: float = 20.0,
              time_offset_ms: float = 0.0, jitter_ms: float = 0.5, epoch_phase_s: float = 0.0,
              outages: tuple = ()) -> GpsReceiver:
        """The Euro4 in datasheet units (CEP in m or cm, ppm, ms). ``correlated_fraction`` of the
        position variance is time-correlated (Gauss-Markov, ``tau_s[mode]``), the rest white."""
        if mode not in MODES:
            raise ConfigError(f"GPS mode {mode!r} is unknown; use one of {MODES}")
        cep = {"standalone": single_point_cep_m, "differential": dgps_cep_m, "rtk": rtk_cep_cm / 100.0}[mode]
        tau = {"standalone": 300.0, "differential": 120.0, "rtk": 60.0} | (tau_s or {})
        s_h = cep * CEP_TO_SIGMA
        sig = np.array([s_h, s_h, vertical_factor * s_h])
        gm = sig * np.sqrt(correlated_fraction)
        wh = sig * np.sqrt(1.0 - correlated_fraction)
        return cls(mode=mode, rate_hz=rate_hz, sigma_gm_N_m=tuple(gm), tau_gm_s=tau[mode],
                   sigma_white_N_m=tuple(wh), ppm_of_baseline=rtk_ppm * 1e-6 if mode == "rtk" else 0.0,
                   sigma_vel_m_s=(velocity_rms_m_s, velocity_rms_m_s, vertical_factor * velocity_rms_m_s),
                   latency_s=latency_ms / 1000.0, time_offset_s=time_offset_ms / 1000.0,
                   time_jitter_s=jitter_ms / 1000.0, epoch_phase_s=epoch_phase_s, outages=tuple(outages))

    def settings(self) -> dict:
        d = asdict(self)
        d["model"] = "NovAtel Euro4 L1/L2 RTK, 512C antenna"
        return d

    # ------------------------------------------------------------------------------------
    def epochs(self, truth: FlightTruth) -> np.ndarray:
        """True epochs t_k within the truth's time span."""
        dt = 1.0 / self.rate_hz
        t0, t1 = truth.time_s[0], truth.time_s[-1]
        k0 = np.ceil((t0 - self.epoch_phase_s) / dt - 1e-9)
        k1 = np.floor((t1 - self.epoch_phase_s) / dt + 1e-9)
        return self.epoch_phase_s + np.arange(k0, k1 + 1) * dt

    def _gauss_markov(self, n: int, dt: float, restart: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """(n,3) unit-σ first-order Gauss-Markov sequences, stationary, restarted where ``restart``."""
        phi = np.exp(-dt / self.tau_gm_s)
        drive = rng.standard_normal((n, 3)) * np.sqrt(1.0 - phi ** 2)
        starts = np.flatnonzero(restart)
        out = np.empty((n, 3))
        bounds = list(starts) + [n]
        for a, b in itertools.pairwise(bounds):
            d = drive[a:b].copy()
            d[0] = rng.standard_normal(3)
            out[a:b] = signal.lfilter([1.0], [1.0, -phi], d, axis=0)
        return out

    def measure(self, truth: FlightTruth, rng: np.random.Generator) -> GpsFixes:
        """Fixes of this receiver along ``truth`` (equations in the module docstring): geodetic
        :class:`~imurig.kernel.navdata.GpsFixes` whose ``time_s`` are the logger's IMU-clock tags (time of
        validity + latency + offset + jitter, quantised), ``t_true_s`` the epochs they refer to."""
        if self.rate_hz > truth.rate_hz:
            raise ConfigError(f"GPS rate {self.rate_hz:g} Hz is above the IMU rate {truth.rate_hz:g} Hz; the "
                              "logger time-tags fixes on the IMU clock, so use a GPS rate <= the IMU rate")
        t_k = self.epochs(truth)
        if t_k.size < 2:
            raise ConfigError("the flight is shorter than two GPS epochs; fly longer or raise rate_hz")
        n, dt = t_k.size, 1.0 / self.rate_hz
        lat, lon, h, v_ant = antenna_track(truth, t_k)
        valid = np.ones(n, bool)
        for a, b in self.outages:
            valid &= ~((t_k >= a) & (t_k < b))
        restart = np.zeros(n, bool)
        restart[0] = True
        restart[1:] |= valid[1:] & ~valid[:-1]
        sig_gm = np.asarray(self.sigma_gm_N_m, float)
        sig_w = np.asarray(self.sigma_white_N_m, float)
        extra = np.zeros(n)
        if self.ppm_of_baseline > 0:
            rl, ro, rh = self.reference_deg
            base = earth.ned_from_geodetic(lat, lon, h, np.radians(rl), np.radians(ro), rh)
            extra = self.ppm_of_baseline * np.linalg.norm(base, axis=1)
        s_gm = np.sqrt(sig_gm ** 2 + extra[:, None] ** 2)
        d_N = self._gauss_markov(n, dt, restart, rng) * s_gm + rng.standard_normal((n, 3)) * sig_w
        lat_m, lon_m, h_m = offset_position(lat, lon, h, d_N)
        sig_v = np.asarray(self.sigma_vel_m_s, float)
        v_m = v_ant + rng.standard_normal((n, 3)) * sig_v
        tag = t_k + self.latency_s + self.time_offset_s + self.time_jitter_s * rng.standard_normal(n)
        if self.quantise_to_imu:
            dti = 1.0 / truth.rate_hz
            tag = np.ceil(tag / dti - 1e-9) * dti
        sigma_pos = np.sqrt(s_gm ** 2 + sig_w ** 2)
        nan = ~valid
        for arr in (lat_m, lon_m, h_m):
            arr[nan] = np.nan
        v_m[nan] = np.nan
        meta = {"receiver": self.settings()}
        return GpsFixes(time_s=tag, lat_rad=lat_m, lon_rad=lon_m, h_m=h_m, v_N=v_m,
                        sigma_pos_N=sigma_pos, sigma_vel_N=np.broadcast_to(sig_v, (n, 3)).copy(),
                        mode=self.mode, valid=valid, t_true_s=t_k, meta=meta)


def antenna_track(truth: FlightTruth, t: np.ndarray):
    """Antenna (lat, lon, h) and velocity v_N (n,3) at times ``t`` (true time), from the truth at
    the IMU by cubic Hermite interpolation (positions use their exact rates from v_N, so the
    interpolation error is O(Δt⁴ ȧ) ≈ 1e-7 m at 100 Hz) and the lever arm."""
    ts = truth.time_s
    dt = 1.0 / truth.rate_hz
    i = np.clip(np.floor((t - ts[0]) / dt).astype(int), 0, ts.size - 2)
    s = (t - ts[i]) / dt
    h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
    rates = np.stack(earth.geodetic_rates(truth.lat_rad, truth.h_m, truth.v_N), axis=1)
    P = np.stack([truth.lat_rad, truth.lon_rad, truth.h_m], axis=1)
    pos = (h00[:, None] * P[i] + h10[:, None] * dt * rates[i] + h01[:, None] * P[i + 1]
           + h11[:, None] * dt * rates[i + 1])
    v = truth.v_N[i] + s[:, None] * (truth.v_N[i + 1] - truth.v_N[i])
    q = earth.q_normalize(truth.q_NB[i] + s[:, None] * (truth.q_NB[i + 1] - truth.q_NB[i]))
    w_IB = truth.w_IB_B[i] + s[:, None] * (truth.w_IB_B[i + 1] - truth.w_IB_B[i])
    C = earth.C_from_q(q)
    w_EB_B = w_IB - np.einsum("nji,nj->ni", C, earth.omega_IE_N(pos[:, 0]))
    l_B = np.asarray(truth.lever_gps_B, float)
    lat, lon, h = offset_position(pos[:, 0], pos[:, 1], pos[:, 2], C @ l_B)
    v_ant = v + np.einsum("nij,nj->ni", C, np.cross(w_EB_B, l_B))
    return lat, lon, h, v_ant
