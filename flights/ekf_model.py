"""The error-state model of the GPS/INS filter: F, Q, the initial and the alignment covariance, the
attitude reset, and the propagation from one navigation epoch to the next.

Sensor model used by the filter (per axis, SI):

    f_in = (1 + s_a) f_B + b_a + k_T (T_a − T_ref) + n_a       [m/s²]   n_a: VRW
    w_in = (1 + s_g) w_IB_B + b_g + n_g                         [rad/s]  n_g: ARW
    b_g: first-order Gauss-Markov (σ, τ) on top of a turn-on bias; b_a: random walk; T_a: random walk

Linearised error dynamics (ω_in = ω_IE + ω_EN), :func:`error_dynamics`:

    δṙ = δv
    δv̇ = [f_N×] ψ − C δb_a − C diag(k_T) δT_a − C diag(f_B) δs_a − (2ω_IE + ω_EN) × δv
         − (2 δω_IE + δω_EN) × v + [0, 0, 2γ/R δr_d]
    ψ̇ = −ω_in × ψ + δω_in + C δb_g + C diag(w_B) δs_g

The covariance is propagated with Φ = I + F T + ½ (F T)² and Q_d = ½(Φ Q Φᵀ + Q) T (:func:`propagate`).
"""
from __future__ import annotations

import math

import numpy as np
from imurig.flights import earth as E
from imurig.flights import ins
from imurig.flights import navmath as nm
from imurig.flights.compass import mag_heading_jacobian, mag_iron_hessian, mag_iron_jacobian
from imurig.flights.filter_config import BA, BG, MIS_PAIRS, SA, SG, TA, A, FilterConfig, ImuNoise, P, V


def error_dynamics(cfg: FilterConfig, noise: ImuNoise, x: ins.NavState, f_B, w_B, C, thermal=None) -> np.ndarray:
    """F (n, n) of the linearised error dynamics ẋ = F x + noise at the navigation state ``x`` with the
    corrected specific force ``f_B`` (3,) m/s², rate ``w_B`` (3,) rad/s, C = C_NB and, with the
    thermal-term states, ``thermal`` = (ΔT, Δh) of the step (equations in the module doc)."""
    return ErrorDynamics(cfg, noise).at(x, f_B, w_B, C, thermal)


class ErrorDynamics:
    """F (n, n) kept between epochs: the constant entries (δṙ = δv, the Gauss-Markov decays) are
    written once, and :meth:`at` rewrites the rows of δv̇ and ψ̇ (one block assignment for the
    18 base states, :func:`_base_rows`) and the optional sensor-error columns."""

    def __init__(self, cfg: FilterConfig, noise: ImuNoise):
        self.cfg, self.noise = cfg, noise
        self.F = np.zeros((cfg.n_states, cfg.n_states))
        self.F[P, V] = np.eye(3)
        _sensor_error_decays(self.F, cfg, noise)
        self.kT = np.broadcast_to(np.asarray(cfg.thermal_slope_m_s2_per_K, float), (3,)).copy()   # m/s²/K
        self._kT = self.kT.tolist()
        self.optional = (cfg.gyro_bias_gm_states or cfg.estimate_scale_factors or cfg.estimate_misalignments
                         or cfg.estimate_nonlinearity or cfg.estimate_thermal_terms)

    def at(self, x: ins.NavState, f_B, w_B, C, thermal=None, rates=None) -> np.ndarray:
        """F at ``x`` (see :func:`error_dynamics`; C a (3, 3) array or a row-major 9-tuple, ``rates``
        :func:`imurig.flights.navmath.rates` at ``x`` if known); the returned array is overwritten by
        the next call."""
        C9 = C.ravel().tolist() if isinstance(C, np.ndarray) else C
        v = x.v_N.tolist()
        if rates is None:
            rates = nm.rates(x.lat_rad, x.h_m, v[0], v[1])
        self.F[3:9, :18] = _base_rows(x.lat_rad, x.h_m, v, ins._floats(f_B), C9, self._kT, rates)
        if self.optional:
            _sensor_error_columns(self.F, self.cfg, np.asarray(f_B, float), np.asarray(w_B, float),
                                  np.asarray(C9).reshape(3, 3), thermal)
        return self.F


def _base_rows(lat: float, h: float, v, f_B, C, kT, rates) -> tuple:
    """Rows δv̇ and ψ̇ of F over the 18 base states (δr, δv, ψ, δb_a, δb_g, δT_a), in floats:

        F[δv, δr] = [v×] (2 ∂ω_IE/∂r + ∂ω_EN/∂r) (+ 2γ/R on δr_d → δv̇_d)   (only the δr_n column)
        F[δv, δv] = −[(2ω_IE + ω_EN)×] + [v×] ∂ω_EN/∂v,   F[δv, ψ] = [f_N×],  F[δv, δb_a] = −C,
        F[δv, δT_a] = −C diag(k_T)
        F[ψ, δr] = ∂ω_IN/∂r,  F[ψ, δv] = ∂ω_EN/∂v,  F[ψ, ψ] = −[ω_IN×],  F[ψ, δb_g] = C

    with ∂ω_IE/∂r_n = −Ω (sin φ, 0, cos φ)/(R_N+h),
    ∂ω_IN/∂r_n = that − (0, 0, v_e/((R_E+h) cos²φ))/(R_N+h); ``rates`` = :func:`imurig.flights.navmath.rates`
    at (lat, h, v)."""
    w_ie, w_en, g, R_N, R_E = rates
    v_n, v_e, v_d = v
    sl, cl, tl = math.sin(lat), math.cos(lat), math.tan(lat)
    iN, iE = 1.0 / (R_N + h), 1.0 / (R_E + h)
    # ∂ω/∂δr_n (the other position columns are zero)
    din0, din2 = -E.OMEGA_E_RAD_S * sl / (R_N + h), (-E.OMEGA_E_RAD_S * cl - v_e / (R_E + h) / cl ** 2) / (R_N + h)
    die0, die2 = -E.OMEGA_E_RAD_S * sl / (R_N + h), -E.OMEGA_E_RAD_S * cl / (R_N + h)
    d0, d2 = 2 * die0 + (din0 - die0), 2 * die2 + (din2 - die2)     # 2 ∂ω_IE + ∂ω_EN
    u_n, u_e, u_d = 2 * w_ie[0] + w_en[0], 2 * w_ie[1] + w_en[1], 2 * w_ie[2] + w_en[2]
    wn, we, wd = w_ie[0] + w_en[0], w_ie[1] + w_en[1], w_ie[2] + w_en[2]
    fn, fe, fd = nm.mat_vec(C, f_B)
    gz = 2.0 * g / (math.sqrt(R_N * R_E) + h)
    c0, c1, c2, c3, c4, c5, c6, c7, c8 = C
    k0, k1, k2 = kT
    return (  # δr                          δv                                        ψ
        (v_e * d2, 0.0, 0.0, v_d * iN, u_d - v_e * tl * iE, -u_e, 0.0, -fd, fe,
         -c0, -c1, -c2, 0.0, 0.0, 0.0, -c0 * k0, -c1 * k1, -c2 * k2),             # δb_a, δb_g, δT_a
        (v_d * d0 - v_n * d2, 0.0, 0.0, -u_d, v_d * iE + v_n * tl * iE, u_n, fd, 0.0, -fn,
         -c3, -c4, -c5, 0.0, 0.0, 0.0, -c3 * k0, -c4 * k1, -c5 * k2),
        (-v_e * d0, 0.0, gz, u_e - v_n * iN, -u_n - v_e * iE, 0.0, -fe, fn, 0.0,
         -c6, -c7, -c8, 0.0, 0.0, 0.0, -c6 * k0, -c7 * k1, -c8 * k2),
        (din0, 0.0, 0.0, 0.0, iE, 0.0, 0.0, wd, -we, 0.0, 0.0, 0.0, c0, c1, c2, 0.0, 0.0, 0.0),
        (0.0, 0.0, 0.0, -iN, 0.0, 0.0, -wd, 0.0, wn, 0.0, 0.0, 0.0, c3, c4, c5, 0.0, 0.0, 0.0),
        (din2, 0.0, 0.0, 0.0, -tl * iE, 0.0, we, -wn, 0.0, 0.0, 0.0, 0.0, c6, c7, c8, 0.0, 0.0, 0.0))


def _sensor_error_decays(F: np.ndarray, cfg: FilterConfig, noise: ImuNoise) -> None:
    """The constant entries of F: the Gauss-Markov decay of the gyro bias (or of its instability
    part, which then drives ψ through C, written by :meth:`ErrorDynamics.at`) and of the receiver's error."""
    if cfg.gyro_bias_gm_states:
        GM = cfg.gyro_gm_slice()
        F[GM, GM] = -np.eye(3) / noise.gyro_bias_tau_s
    else:
        F[BG, BG] = -np.eye(3) / noise.gyro_bias_tau_s
    if cfg.augment_gps:
        G = cfg.gps_slice()
        F[G, G] = -np.eye(3) / cfg.gps_pos_tau_s


def _sensor_error_columns(F: np.ndarray, cfg: FilterConfig, f_B, w_B, C, thermal) -> None:
    """The columns of F that couple the optional sensor-error states into δv and ψ."""
    if cfg.gyro_bias_gm_states:
        F[A, cfg.gyro_gm_slice()] = C
    if cfg.estimate_scale_factors:
        F[V, SA] = -C * f_B
        F[A, SG] = C * w_B
    if cfg.estimate_misalignments:
        MA, MG = cfg.mis_slices()
        for p_, (i, j) in enumerate(MIS_PAIRS):
            F[V, MA.start + p_] = -C[:, i] * f_B[j]
            F[A, MG.start + p_] = C[:, i] * w_B[j]
    if cfg.estimate_nonlinearity:
        F[V, cfg.k2_slice()] = -C * f_B ** 2
    if cfg.estimate_thermal_terms and thermal is not None:
        dT, dh = thermal
        TH = cfg.thermal_slice()
        for p_, reg in enumerate((dT, f_B * dT, dh, f_B * dh)):
            F[V, TH.start + 3 * p_: TH.start + 3 * p_ + 3] = -C * reg


def process_noise(cfg: FilterConfig, noise: ImuNoise, gps_gm_var) -> np.ndarray:
    """Diagonal (n,) of the continuous process-noise intensity Q: white noise of the sensors, the
    random walks and Gauss-Markov drives; ``gps_gm_var`` (3,) m² the receiver's correlated error."""
    nz = noise
    q = np.zeros(cfg.n_states)
    q[V] = nz.vrw ** 2
    q[A] = nz.arw ** 2
    q[BA] = nz.acc_bias_rw ** 2
    if cfg.gyro_bias_gm_states:
        q[cfg.gyro_gm_slice()] = 2 * nz.gyro_bias_sigma ** 2 / nz.gyro_bias_tau_s
    else:
        q[BG] = 2 * nz.gyro_bias_sigma ** 2 / nz.gyro_bias_tau_s
    q[TA] = nz.temp_rw ** 2
    if cfg.estimate_scale_factors:
        q[SA] = q[SG] = nz.scale_rw ** 2
    if cfg.estimate_misalignments:
        MA, MG = cfg.mis_slices()
        q[MA] = q[MG] = nz.scale_rw ** 2
    if cfg.estimate_nonlinearity:
        q[cfg.k2_slice()] = 0.0
    if cfg.estimate_thermal_terms:
        q[cfg.thermal_slice()] = 0.0
    if cfg.augment_gps:
        q[cfg.gps_slice()] = 2.0 * gps_gm_var / cfg.gps_pos_tau_s
    return q



def initial_covariance(cfg: FilterConfig, noise: ImuNoise, gps_gm_var=None) -> np.ndarray:
    """P0 (n, n) from the configured initial 1σ (diagonal; the iron states' correlated prior);
    ``gps_gm_var`` (3,) m² the variance of the receiver's Gauss-Markov error (zero if None)."""
    gps_gm_var = np.zeros(3) if gps_gm_var is None else np.asarray(gps_gm_var, float)
    c = cfg
    s = np.zeros(c.n_states)
    s[P] = c.sigma0_pos_m
    s[V] = c.sigma0_vel_m_s
    s[A] = [c.sigma0_tilt_rad, c.sigma0_tilt_rad, c.sigma0_heading_rad]
    s[BA] = c.sigma0_acc_bias_m_s2
    s[BG] = c.sigma0_gyro_bias_rad_s
    s[TA] = c.sigma0_temp_K
    if c.estimate_scale_factors:
        s[SA] = c.sigma0_acc_scale
        s[SG] = c.sigma0_gyro_scale
    if c.estimate_misalignments:
        MA, MG = c.mis_slices()
        s[MA] = c.sigma0_acc_misalignment_rad
        s[MG] = c.sigma0_gyro_misalignment_rad
    if c.estimate_nonlinearity:
        s[c.k2_slice()] = c.sigma0_acc_nonlinearity_s2_m
    if c.estimate_thermal_terms:
        s[c.thermal_slice()] = np.repeat(np.asarray(c.sigma0_acc_thermal, float), 3)
    if c.augment_gps:
        s[c.gps_slice()] = np.sqrt(gps_gm_var)
    if c.gyro_bias_gm_states:
        s[c.gyro_gm_slice()] = noise.gyro_bias_sigma
    if c.mag_error_state:
        s[c.mag_index()] = c.mag_error_sigma_rad
    P0 = np.diag(s ** 2)
    if c.mag_iron_states:
        MI = c.mag_iron_slice()
        P0[MI, MI] = np.asarray(c.mag_iron_prior_cov, float)
    return P0



def alignment_covariance(cfg: FilterConfig, noise: ImuNoise, lever_gps_B, x0: ins.NavState, f_B, B_B, gps, *,
                         window_s: float, sigma_mag_rad: float, sigma_level_f_m_s2: float | None = None) -> np.ndarray:
    """P0 (n, n) of a static alignment, by propagating the alignment's own errors.

    The alignment (:func:`imurig.flights.report.align`) levels with the mean specific force
    ``f_B`` (3,) m/s² over ``window_s`` s, takes the heading of the mean field ``B_B`` (3,)
    levelled with that roll and pitch, and position/velocity from the first valid fix (antenna
    minus the lever arm). Sources, independent, with the filter's own priors: the sensor-error
    states x_s (biases, scale factors, misalignments, temperatures, the receiver's Gauss-Markov
    error), the white noise of the levelling mean (σ_f = ``sigma_level_f_m_s2``, default
    VRW/√window), the compass's heading error e_m (σ ``sigma_mag_rad``), the fix's white error
    e_r and velocity error e_v. The filter's specific-force error is δf_B = J_f x_s (J_f = −I on
    δb_a, −diag(f) on δs_a, −e_i f_j on the misalignments, −diag(k_T) on δT_a), and levelling
    makes the horizontal part of Ĉ f̂ vanish, [f_N×]ψ = −C δf_B on the north and east rows:

        ψ_n = (C δf_B)_e / g,   ψ_e = −(C δf_B)_n / g          (tilt = −bias/g)
        ψ_d = h_n ψ_n + h_e ψ_e − e_m                           (z_mag = 0 at the alignment)
        δr = e_r − δb_gps − [(C l)×] ψ,   δv = e_v

    with h the magnetic-heading Jacobian (:func:`mag_heading_jacobian`, h_n = tan I cos D).
    P0 = A Σ Aᵀ: the tilt is fully correlated with the accelerometer errors, so the filter knows
    that a static IMU cannot tell them apart (see docs/flights-navigation.md)."""
    c = cfg
    n = c.n_states
    f_B = np.asarray(f_B, float)
    g = float(np.linalg.norm(f_B))
    C = E.C_from_q(x0.q_NB)
    valid = np.asarray(gps.valid, bool)
    i0 = int(np.flatnonzero(valid)[0])
    s_pos2 = np.asarray(gps.sigma_pos_N[i0], float) ** 2
    s_vel2 = np.asarray(gps.sigma_vel_N[i0], float) ** 2
    gps_gm_var = None
    if c.augment_gps:
        s_w2 = np.minimum(np.asarray(c.gps_pos_sigma_white_N_m, float) ** 2, s_pos2)
        gps_gm_var = np.maximum(s_pos2 - s_w2, 0.0)
    else:
        s_w2 = s_pos2
    P_prior = initial_covariance(cfg, noise, gps_gm_var)
    var = np.diag(P_prior).copy()
    if sigma_level_f_m_s2 is None:
        sigma_level_f_m_s2 = noise.vrw / math.sqrt(window_s)
    var[P] = s_w2
    var[V] = s_vel2
    var[A] = [(sigma_level_f_m_s2 / g) ** 2] * 2 + [sigma_mag_rad ** 2]
    Cf = C @ _specific_force_jacobian(c, f_B)
    Amap = np.eye(n)
    Amap[6] += Cf[1] / g
    Amap[7] -= Cf[0] / g
    h = mag_heading_jacobian(C, B_B)
    Amap[8] = h[0] * Amap[6] + h[1] * Amap[7] - np.eye(n)[8]
    if c.mag_error_state:           # ψ_m = ψ + e_m: z = hᵀψ + δe_m = 0, δe_m = ê_m − e_m = −e_m
        Amap[8, c.mag_index()] = 1.0
    if c.mag_iron_states:           # z = hᵀψ + H_θ δθ = 0 (θ̂ = 0 at the alignment)
        roll, pitch, _ = E.euler_from_C(C)
        MI = c.mag_iron_slice()
        Amap[8, MI] = mag_iron_jacobian(B_B, np.zeros(12), roll, pitch)
        # the heading is quadratic in θ at the priors' size: the part of the alignment's heading
        # error that is not H_θ δθ has variance ½ tr(Hs P Hs P) (as in the compass update)
        HP = mag_iron_hessian(B_B, np.zeros(12), roll, pitch) @ P_prior[MI, MI]
        var[8] += 0.5 * float(np.sum(HP * HP.T))
    Cl = C @ np.asarray(lever_gps_B, float)
    Amap[P] -= ins._skew(Cl) @ Amap[A]
    if c.augment_gps:
        Amap[P, c.gps_slice()] -= np.eye(3)
    Sig = np.diag(var)
    if c.mag_iron_states:     # the iron states' prior is correlated (symmetric soft iron)
        MI = c.mag_iron_slice()
        Sig[MI, MI] = P_prior[MI, MI]
    P0 = Amap @ Sig @ Amap.T
    # second order: the levelling fixes the tilt in the body frame; mapped to NED with the
    # compass's heading (error ψ_d) the linear map above carries an extra −½ ψ_d e_z × ψ_tilt
    # (BCH of the heading and tilt rotations). Its variance (Isserlis, zero-mean Gaussians),
    # uncorrelated with the linear terms: ¼ J (σ_d² Σ_tt + 2 c cᵀ) Jᵀ, J = [[0, −1], [1, 0]],
    # c = cov(ψ_tilt, ψ_d)
    Jz = np.array([[0.0, -1.0], [1.0, 0.0]])
    cz = P0[6:8, 8]
    P0[6:8, 6:8] += 0.25 * Jz @ (P0[8, 8] * P0[6:8, 6:8] + 2.0 * np.outer(cz, cz)) @ Jz.T
    return P0


def _specific_force_jacobian(c: FilterConfig, f_B: np.ndarray) -> np.ndarray:
    """J_f (3, n): the filter's specific-force error δf_B = J_f x_s at the specific force ``f_B``
    (−I on δb_a, −diag(k_T) on δT_a, −diag(f) on δs_a, −e_i f_j on the misalignments, −diag(f²) on δk2)."""
    Jf = np.zeros((3, c.n_states))
    Jf[:, BA] = -np.eye(3)
    Jf[:, TA] = -np.diag(np.asarray(c.thermal_slope_m_s2_per_K, float) * np.ones(3))
    if c.estimate_scale_factors:
        Jf[:, SA] = -np.diag(f_B)
    if c.estimate_misalignments:
        MA, _ = c.mis_slices()
        for p_, (i, j) in enumerate(MIS_PAIRS):
            Jf[i, MA.start + p_] = -f_B[j]
    if c.estimate_nonlinearity:
        Jf[:, c.k2_slice()] = -np.diag(f_B ** 2)
    return Jf


def attitude_reset_jacobian(psi_hat) -> np.ndarray:
    """G (3, 3) of the attitude error's reset when the estimate ``psi_hat`` (3,) rad is injected,
    C_new = exp([ψ̂×]) Ĉ. With the error defined by Ĉ = exp(−[ψ×]) C, BCH gives the error after the
    injection ψ' = ψ − ψ̂ + ½ ψ̂ × ψ + O(|ψ|³), so the covariance becomes G P Gᵀ with

        G = I + ½ [ψ̂×]

    Without it a large heading correction (the uncalibrated compass's ~4 deg, resolved by the
    first GPS velocities) leaves the tilt's correlation with the accelerometer biases rotated by
    the heading error: the biases' tilt then leaks into the final attitude (1.5 mrad on one IMU)."""
    x, y, z = (0.5 * float(p) for p in psi_hat)
    return np.array([[1.0, -z, y], [z, 1.0, -x], [-y, x, 1.0]])


def propagate(st, ep, k: int, C: np.ndarray, noise: ImuNoise) -> None:
    """Advance the filter state ``st`` (:class:`imurig.flights.ekf_state.FilterState`) from epoch k to
    k+1 on the corrected increments of ``ep`` (:class:`imurig.flights.ekf_state.EpochData`), C = C_NB
    at epoch k ((3, 3) or a row-major 9-tuple): the INS step (:func:`imurig.flights.ins.nav_step`) with

        Δθ = (Δθ_in − b̂_g T)(1 − ŝ_g),   Δv = (Δv_in − (b̂_a + k_T (T̂_a − T_ref)) T)(1 − ŝ_a) − ...

    (misalignments, nonlinearity and thermal terms removed likewise), and the covariance
    P ← Φ P Φᵀ + Q_d, Φ = I + F T + ½ (F T)², Q_d = ½(Φ Q Φᵀ + Q) T, computed in place as
    P ← Φ (P + ½ Q T) Φᵀ + ½ Q T (Q diagonal)."""
    c, lay, T = st.cfg, st.lay, ep.T
    dth, dv, f_in, w_in, thermal = _corrected_increments(st, ep, k)
    x = st.x
    r0 = nm.rates(x.lat_rad, x.h_m, *x.v_N.tolist()[:2])       # shared by F and the INS step
    F = st.dynamics.at(x, f_in, w_in, C, thermal, rates=r0)
    st.x = ins.nav_step(x, dth, dv, T, rates0=r0)      # (C is before the temperature update: not x's)
    if lay.G is not None:
        st.bgps = st.bgps * math.exp(-T / c.gps_pos_tau_s)
    if lay.GM is not None:          # the expected Gauss-Markov part decays with τ
        phi_bgm = math.exp(-T / noise.gyro_bias_tau_s)
        st.bg = st.bg - st.bgm * (1.0 - phi_bgm)
        st.bgm = st.bgm * phi_bgm
        st.version += 1
    FT, Phi, tmp = st.work              # (np.dot: less call overhead than matmul at this size)
    np.multiply(F, T, out=FT)
    np.dot(FT, FT, out=Phi)
    Phi *= 0.5
    Phi += FT
    st.work_diag += 1.0                 # the diagonal of Φ
    if lay.mag is not None:
        _propagate_with_mag_state(st, Phi, np.asarray(dth), np.asarray(C, float).reshape(3, 3), T)
        return
    qh = st.qc * (0.5 * T)
    st.P_diag += qh
    np.dot(Phi, st.P, out=tmp)
    np.dot(tmp, Phi.T, out=st.P)
    st.P_diag += qh


def _corrected_increments(st, ep, k: int):
    """(Δθ, Δv, f, ω, thermal) of step k corrected by the sensor-error estimates (:func:`propagate`):
    the increments for the INS and the specific force and rate at epoch k for F."""
    c, T = st.cfg, ep.T
    bg, sg, sa, f_corr = st.corrections()
    i = 3 * k
    th_in, v_in, f_B, w_B = ep.dtheta_l[i:i + 3], ep.dv_l[i:i + 3], ep.f_l[i:i + 3], ep.w_l[i:i + 3]
    dth = [(a - b * T) * (1.0 - s) for a, b, s in zip(th_in, bg, sg)]
    dv = [(a - b * T) * (1.0 - s) for a, b, s in zip(v_in, f_corr, sa)]
    f_in = [(a - b) * (1 - s) for a, b, s in zip(f_B, f_corr, sa)]
    w_in = [(a - b) * (1 - s) for a, b, s in zip(w_B, bg, sg)]
    thermal = None
    if c.estimate_nonlinearity or c.estimate_thermal_terms or c.estimate_misalignments:
        dth, dv = np.array(dth), np.array(dv)
        if c.estimate_nonlinearity:
            dv = dv - st.k2 * ep.f2_B[k] * T
        if c.estimate_thermal_terms:
            f_st = ep.dv_B[k] / T
            thermal = (ep.dT[k], ep.dh[k])
            th = st.th
            dv = dv - (th[0:3] * ep.dT[k] + th[3:6] * f_st * ep.dT[k] + th[6:9] * ep.dh[k]
                       + th[9:12] * f_st * ep.dh[k]) * T
        if c.estimate_misalignments:
            dth = dth - st.Mg @ dth
            dv = dv - st.Ma @ dv
    return dth, dv, f_in, w_in, thermal


def _propagate_with_mag_state(st, Phi: np.ndarray, dth: np.ndarray, C: np.ndarray, T: float) -> None:
    """P ← Φ P Φᵀ + Q_d with the compass's heading-error state e_m, a Gauss-Markov process in the
    body's rotation angle relative to NED over the step (its row of Φ and Q_d replaced)."""
    c, im = st.cfg, st.lay.mag
    Qd = 0.5 * (Phi * st.qc) @ Phi.T * T + 0.5 * np.diag(st.qc) * T
    w_ie_, w_en_, *_ = ins._rates(st.x.lat_rad, st.x.h_m, st.x.v_N)
    dang = float(np.linalg.norm(dth - C.T @ (w_ie_ + w_en_) * T))
    phm = math.exp(-dang / c.mag_error_corr_rad)
    Phi[im, :] = 0.0
    Phi[im, im] = phm
    Qd[im, :] = 0.0
    Qd[:, im] = 0.0
    Qd[im, im] = c.mag_error_sigma_rad ** 2 * (1.0 - phm ** 2)
    st.emag *= phm
    st.P[...] = Phi @ st.P @ Phi.T + Qd
