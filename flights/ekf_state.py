"""The running estimate of the GPS/INS filter between epochs, and what a run records.

:class:`FilterState` holds the navigation state x̂ (:class:`imurig.flights.ins.NavState`), the
error-state covariance P (n, n), the sensor-error estimates the filter corrects the IMU with
(biases, scale factors, misalignments, nonlinearity, thermal terms, the receiver's and the
compass's systematic errors) and the record of every measurement update (NIS, dof, innovation).
The Kalman update (Joseph form, for any gain)

    S = H P Hᵀ + R,   K = P Hᵀ S⁻¹,   δx̂ = K z,   P ← (I − K H) P (I − K H)ᵀ + K R Kᵀ

is followed by the injection of δx̂ (estimate minus truth) into x̂ and the sensor-error estimates,
with the attitude reset P ← G P Gᵀ (:func:`imurig.flights.ekf_model.attitude_reset_jacobian`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from imurig.flights import ins
from imurig.flights import navmath as nm
from imurig.flights.ekf_model import ErrorDynamics, attitude_reset_jacobian
from imurig.flights.filter_config import BA, BG, MIS_PAIRS, SA, SG, TA, A, FilterConfig, ImuNoise, V

UPDATE_KINDS = ("gps_pos", "gps_vel", "mag", "temp")


class StateLayout:
    """Where each optional block of the error state sits (slices into the n states, None when the
    block is not estimated), computed once per run from the :class:`FilterConfig`."""

    def __init__(self, cfg: FilterConfig):
        self.n = cfg.n_states
        self.G = cfg.gps_slice() if cfg.augment_gps else None
        self.GM = cfg.gyro_gm_slice() if cfg.gyro_bias_gm_states else None
        self.MI = cfg.mag_iron_slice() if cfg.mag_iron_states else None
        self.MA, self.MG = cfg.mis_slices()
        self.K2 = cfg.k2_slice()
        self.TH = cfg.thermal_slice()
        self.mag = cfg.mag_index() if cfg.mag_error_state else None
        self.mis_i = tuple(i for i, _ in MIS_PAIRS)
        self.mis_j = tuple(j for _, j in MIS_PAIRS)


@dataclass
class EpochData:
    """The IMU stream reduced to the navigation epochs k = 0..M (interval T = K / f_s).

    ``t_s`` (M+1,) s epoch times; ``dtheta_B``, ``dv_B`` (M, 3) coning/sculling increments;
    ``f_B``, ``w_B`` (M+1, 3) the samples at the epochs (for F and the lever arms); ``f2_B`` (M, 3)
    the mean of f² over each step (nonlinearity states); ``dT``, ``dh`` (M, 3) step means of the
    accelerometer temperatures and hysteresis states relative to the first step (thermal-term
    states); ``T_acc_K`` and ``B_B`` the stream's temperature channels and field (or None); ``idx``
    (M+1,) the sample index of each epoch."""

    t_s: np.ndarray
    T: float
    K: int
    idx: np.ndarray
    dtheta_B: np.ndarray
    dv_B: np.ndarray
    f_B: np.ndarray
    w_B: np.ndarray
    f2_B: np.ndarray | None
    dT: np.ndarray | None
    dh: np.ndarray | None
    T_acc_K: np.ndarray | None
    B_B: np.ndarray | None
    fs: float

    def __post_init__(self):
        # the per-epoch vectors as flat lists of Python floats (epoch k at [3k, 3k+3)) for the
        # plain-float propagation; flat, so that the garbage collector has no containers to scan
        self.dtheta_l, self.dv_l = self.dtheta_B.ravel().tolist(), self.dv_B.ravel().tolist()
        self.f_l, self.w_l = (np.asarray(a, float).ravel().tolist() for a in (self.f_B, self.w_B))

    @property
    def M(self) -> int:
        return int(self.dtheta_B.shape[0])


class FilterState:
    """x̂, P and the sensor-error estimates of one run (module doc); ``qc`` (n,) the process-noise
    intensity (its GPS block follows the fixes' reported σ), ``gps_gm_var`` (3,) m² the variance of
    the receiver's Gauss-Markov error, ``gps_used`` whether a fix has been used."""

    def __init__(self, cfg: FilterConfig, x0: ins.NavState, P0: np.ndarray, qc: np.ndarray, gps_gm_var,
                 T_acc0_K: np.ndarray | None, noise: ImuNoise | None = None):
        self.cfg = cfg
        self.lay = StateLayout(cfg)
        self.x = x0.copy()
        n = self.lay.n
        # P lives in one buffer (updated in place; its diagonal and navigation block are views)
        self.P = np.array(P0, float, order="C")
        self.P_diag, self.P_nav = self.P.reshape(-1)[:: n + 1], self.P[:9, :9]
        self.dynamics = ErrorDynamics(cfg, ImuNoise() if noise is None else noise)
        self.work = tuple(np.empty((n, n)) for _ in range(3))     # F T, Φ, scratch of the propagation
        self.work_diag = self.work[1].reshape(-1)[:: n + 1]
        self.qc = qc
        self.gps_gm_var = gps_gm_var
        self.gps_used = False
        self.I_n = np.eye(self.lay.n)
        self.ba = np.zeros(3)          # accelerometer bias estimate, m/s²
        self.bg = np.zeros(3)          # gyro bias estimate (turn-on + Gauss-Markov parts), rad/s
        self.bgm = np.zeros(3)         # its Gauss-Markov part, when cfg.gyro_bias_gm_states
        self.Ta = (np.full(3, cfg.reference_temperature_K) if T_acc0_K is None
                   else np.asarray(T_acc0_K, float).copy())
        self.sa = np.zeros(3)
        self.sg = np.zeros(3)
        self.Ma = np.zeros((3, 3))     # misalignment estimates (zero diagonal): f = (I − diag(s) − M) f_in
        self.Mg = np.zeros((3, 3))
        self.k2 = np.zeros(3)          # accelerometer nonlinearity estimate, s²/m
        self.th = np.zeros(12)         # thermal-term estimates (k_T, s_T, H_b, H_s per axis)
        self.bgps = np.zeros(3)        # the receiver's Gauss-Markov position error estimate, NED m
        self.emag = 0.0                # the compass's systematic heading error estimate, rad
        self.theta_m = np.zeros(12)    # the magnetometer's installation errors [b (T), ΔA]
        self.updates = {k: {"time_s": [], "nis": [], "dof": [], "innovation": []} for k in UPDATE_KINDS}
        # the estimates above are replaced, never changed in place; ``version`` counts the changes of
        # b̂_a, b̂_g, T̂_a, ŝ_a, ŝ_g (injections, the Gauss-Markov decay), which the cached corrections
        # and the record follow
        self.version = 0
        self._corrections = (-1, None)

    @property
    def compilable(self) -> bool:
        """Whether the compiled span propagation (:mod:`imurig.flights.ekf_kernel`) covers this
        configuration: the 18 base states, optionally the receiver's error (its decay is constant in
        F); no sensor-error columns in F, no compass or gyro Gauss-Markov states (which change the
        estimates between updates)."""
        return not self.dynamics.optional and self.lay.mag is None and self.lay.GM is None

    def corrections(self) -> tuple:
        """(b̂_g, ŝ_g, ŝ_a, f̂_corr) as lists of floats, f̂_corr = b̂_a + k_T (T̂_a − T_ref) the
        accelerometers' bias correction, recomputed only when ``version`` has changed."""
        if self._corrections[0] != self.version:
            f_corr = self.ba + self.dynamics.kT * (self.Ta - self.cfg.reference_temperature_K)
            self._corrections = (self.version, (self.bg.tolist(), self.sg.tolist(), self.sa.tolist(), f_corr.tolist()))
        return self._corrections[1]

    def inject(self, dx: np.ndarray) -> None:
        """Correct x̂ and the sensor-error estimates by the error estimate ``dx`` (n,) (estimate minus
        truth), and reset the attitude block of P (P ← G P Gᵀ)."""
        c, lay, x = self.cfg, self.lay, self.x
        d = dx[:9].tolist()
        *_, R_N, R_E = nm.rates(x.lat_rad, x.h_m, 0.0, 0.0)
        lat = x.lat_rad - d[0] / (R_N + x.h_m)
        lon = x.lon_rad - d[1] / ((R_E + x.h_m) * math.cos(x.lat_rad))
        h = x.h_m + d[2]
        v = x.v_N - dx[V]
        q = nm.qnormalised(nm.qmul(nm.qrot(d[6:9]), x.q_NB.tolist()))
        self.x = ins.NavState(lat, lon, h, v, np.array(q))
        Gr = attitude_reset_jacobian(d[6:9])
        self.P[A, :] = np.dot(Gr, self.P[A, :])
        self.P[:, A] = np.dot(self.P[:, A], Gr.T)
        self.ba = self.ba - dx[BA]
        self.bg = self.bg - dx[BG]
        if lay.GM is not None:
            self.bg = self.bg - dx[lay.GM]
            self.bgm = self.bgm - dx[lay.GM]
        self.Ta = self.Ta - dx[TA]
        if c.estimate_scale_factors:
            self.sa = self.sa - dx[SA]
            self.sg = self.sg - dx[SG]
        if c.estimate_misalignments:
            self.Ma = self.Ma.copy()
            self.Mg = self.Mg.copy()
            self.Ma[lay.mis_i, lay.mis_j] -= dx[lay.MA]
            self.Mg[lay.mis_i, lay.mis_j] -= dx[lay.MG]
        if c.estimate_nonlinearity:
            self.k2 = self.k2 - dx[lay.K2]
        if c.estimate_thermal_terms:
            self.th = self.th - dx[lay.TH]
        if lay.G is not None:
            self.bgps = self.bgps - dx[lay.G]
        if lay.mag is not None:
            self.emag = self.emag - dx[lay.mag]
        if lay.MI is not None:
            self.theta_m = self.theta_m - dx[lay.MI]
        self.version += 1

    def record(self, kind: str, tk: float, nis: float, dof: int, z: np.ndarray) -> None:
        u = self.updates[kind]
        u["time_s"].append(tk)
        u["nis"].append(nis)
        u["dof"].append(dof)
        u["innovation"].append(z.copy())

    def kalman_update(self, kind: str, tk: float, z: np.ndarray, H: np.ndarray, R: np.ndarray) -> None:
        """Linear update with innovation ``z`` = predicted − measured = H δx + noise (module doc)."""
        P, dot = self.P, np.dot          # (np.dot: less call overhead than @ at these sizes)
        PHt = dot(P, H.T)
        Sinv = nm.inv_small(dot(H, PHt) + R)
        Kg = dot(PHt, Sinv)
        dx = dot(Kg, z)
        IKH = self.I_n - dot(Kg, H)
        np.add(dot(dot(IKH, P), IKH.T), dot(dot(Kg, R), Kg.T), out=P)
        self.record(kind, tk, float(dot(z, dot(Sinv, z))), int(z.size), z)
        self.inject(dx)

    def update_record(self) -> dict:
        """kind -> {time_s, nis, dof (arrays), innovation (list)} of every update so far."""
        return {k: {"time_s": np.asarray(u["time_s"]), "nis": np.asarray(u["nis"]), "dof": np.asarray(u["dof"]),
                    "innovation": u["innovation"]} for k, u in self.updates.items()}


class SolutionRecord:
    """The filtered solution at the epochs 0..M, filled as the run goes (the GPS update reads the
    INS history at a fix's time from it)."""

    def __init__(self, M: int, n: int):
        # [lat, lon, h, v_N (3), q_NB (4)] per epoch in one array (the compiled span writes its rows);
        # lat, lon, h, v, q are views of it until :meth:`finish` makes them contiguous
        self.nav = np.empty((M + 1, 10))
        self.lat, self.lon, self.h = self.nav[:, 0], self.nav[:, 1], self.nav[:, 2]
        self.v, self.q = self.nav[:, 3:6], self.nav[:, 6:10]
        self.ba = np.empty((M + 1, 3))
        self.bg = np.empty((M + 1, 3))
        self.T = np.empty((M + 1, 3))
        self.sa = np.empty((M + 1, 3))
        self.sg = np.empty((M + 1, 3))
        self.P_diag = np.empty((M + 1, n))
        self.P_nav = np.empty((M + 1, 9, 9))
        self._sensor = []      # (epoch, b̂_a, b̂_g, T̂_a, ŝ_a, ŝ_g) from each change on (see finish)
        self._version = None

    def store(self, k: int, st: FilterState) -> None:
        x = st.x
        self.lat[k], self.lon[k], self.h[k], self.v[k], self.q[k] = x.lat_rad, x.lon_rad, x.h_m, x.v_N, x.q_NB
        if st.version != self._version:         # the sensor-error estimates: only when they changed
            self._sensor.append((k, st.ba, st.bg, st.Ta, st.sa, st.sg))
            self._version = st.version
        self.P_diag[k] = st.P_diag
        self.P_nav[k] = st.P_nav

    def finish(self) -> SolutionRecord:
        """Fill the sensor-error estimates' records (``ba``, ``bg``, ``T``, ``sa``, ``sg``) from the
        values stored at each change, each held until the next; returns self."""
        ends = [e[0] for e in self._sensor[1:]] + [self.lat.size]
        for (k0, *vals), k1 in zip(self._sensor, ends):
            for arr, v in zip((self.ba, self.bg, self.T, self.sa, self.sg), vals):
                arr[k0:k1] = v
        self.lat, self.lon, self.h, self.v, self.q = (np.ascontiguousarray(a) for a in
                                                      (self.lat, self.lon, self.h, self.v, self.q))
        return self

    def history(self, k: int, s: float, x: ins.NavState):
        """(lat, lon, h, v_N) of the INS at fractional epoch ``s`` (≤ k) by linear interpolation between
        stored epochs, the current state ``x`` standing for epoch k."""
        j = min(math.floor(s), k)
        a = s - j
        j1 = min(j + 1, k)
        lat_t = (1 - a) * self.lat[j] + a * (self.lat[j1] if j1 < k else x.lat_rad)
        lon_t = (1 - a) * self.lon[j] + a * (self.lon[j1] if j1 < k else x.lon_rad)
        h_t = (1 - a) * self.h[j] + a * (self.h[j1] if j1 < k else x.h_m)
        v_t = (1 - a) * self.v[j] + a * (self.v[j1] if j1 < k else x.v_N)
        if j == k:
            lat_t, lon_t, h_t, v_t = x.lat_rad, x.lon_rad, x.h_m, x.v_N
        return lat_t, lon_t, h_t, v_t
