"""The measurement updates of the GPS/INS filter at a navigation epoch.

Innovation = predicted − measured = H δx + noise, each with its normalised innovation squared
(NIS) recorded (:meth:`imurig.flights.ekf_state.FilterState.record`):

- GPS position of the antenna at ``r + C_NB l_B``: H = [I, −Δt I, [(C l)×], 0 …]; Δt ≥ 0 is the
  latency between the fix's time of validity and the epoch it is used at, so the stored INS
  history at that time gives the prediction and the error is carried forward by δv Δt; with the
  receiver's Gauss-Markov error as states, H gains I on them, otherwise R is inflated for the
  correlation (:class:`imurig.flights.filter_config.FilterConfig`);
- GPS velocity of the antenna, v + C (ω_NB × l): H = [0, I, [(C(ω×l))×], 0, C[l×], 0];
- magnetic heading from the magnetometer levelled with the INS roll and pitch, plus the IGRF
  declination: H = [tan I cos D, tan I sin D, −1] from the levelled field
  (:func:`imurig.flights.compass.mag_heading_jacobian`); with the installation-error states a
  Gaussian second-order, iterated update;
- accelerometer temperature channels: H = [0 … I] on δT_a.
"""
from __future__ import annotations

import math

import numpy as np
from imurig.flights import earth as E
from imurig.flights import ins
from imurig.flights import navmath as nm
from imurig.flights.compass import (mag_corrected_field, mag_heading, mag_heading_jacobian, mag_iron_hessian,
                                    mag_iron_jacobian)
from imurig.flights.filter_config import BG, TA, A, P, V


class GpsSchedule:
    """Which fixes are used at which epoch: a valid fix valid at t is used at the first epoch at
    or after t + ``gps_latency_s``; ``gm_inflation`` = (1+φ)/(1−φ), φ = e^{−Δt/τ}, the factor on
    the correlated part of R when the receiver's error is not a state."""

    def __init__(self, gps, cfg, t_s: np.ndarray, T: float):
        tg = np.asarray(gps.time_s, float)
        ok = np.asarray(gps.valid, bool) & (tg >= t_s[0]) & (tg + cfg.gps_latency_s <= t_s[-1])
        use_at = np.ceil((tg + cfg.gps_latency_s - t_s[0]) / T - 1e-9).astype(int)
        self.at = {int(e): [] for e in use_at[ok]}
        for i in np.flatnonzero(ok):
            self.at[int(use_at[i])].append(int(i))
        self.gm_inflation = 1.0
        if cfg.gps_pos_tau_s is not None and tg.size > 1:
            phi_g = math.exp(-float(np.median(np.diff(tg))) / cfg.gps_pos_tau_s)
            self.gm_inflation = (1.0 + phi_g) / (1.0 - phi_g)
        self.valid = np.asarray(gps.valid, bool)


def gps_updates(st, rec, ep, gps, sched: GpsSchedule, k: int, lever_gps_B: np.ndarray) -> None:
    """Every fix scheduled at epoch k: the position update, then (``use_gps_velocity``) the velocity's."""
    c = st.cfg
    tk = ep.t_s[k]
    for i in sched.at[k]:
        dv_hist = _gps_position_update(st, rec, ep, gps, sched, k, i, lever_gps_B)
        st.gps_used = True
        if c.use_gps_velocity:
            _gps_velocity_update(st, ep, gps, k, i, lever_gps_B, dv_hist, tk)


def _gps_position_update(st, rec, ep, gps, sched, k: int, i: int, lever_gps_B) -> np.ndarray:
    """The position update by fix i at epoch k (module doc); returns the INS history's velocity
    offset at the fix's time (v(t_fix) − v(t_k)), which the velocity update uses."""
    c, G = st.cfg, st.lay.G
    tk = ep.t_s[k]
    tg = float(gps.time_s[i])
    lag = tk - tg
    lat_t, lon_t, h_t, v_t = rec.history(k, (tg - ep.t_s[0]) / ep.T, st.x)
    dv_hist = v_t - st.x.v_N          # history offset, kept across the position update
    Cl = ins._dcm(st.x.q_NB) @ lever_gps_B
    r_ant = nm.ned_offset(float(lat_t), float(lon_t), float(h_t), float(gps.lat_rad[i]), float(gps.lon_rad[i]),
                          float(gps.h_m[i]))
    z = np.array(r_ant) + Cl
    H = np.zeros((3, st.lay.n))
    H[:, P] = np.eye(3)
    H[:, V] = -lag * np.eye(3)
    H[:, A] = ins._skew(Cl)
    s2 = np.asarray(gps.sigma_pos_N[i], float) ** 2
    s_w2 = np.asarray(c.gps_pos_sigma_white_N_m, float) ** 2
    if G is not None:
        # the correlated part is a state: re-started (receiver re-acquired) after a gap
        st.gps_gm_var = np.maximum(s2 - s_w2, 0.0)
        st.qc[G] = 2.0 * st.gps_gm_var / c.gps_pos_tau_s
        if st.gps_used and not sched.valid[i - 1]:
            st.bgps = np.zeros(3)
            st.P[G, :] = 0.0
            st.P[:, G] = 0.0
            st.P[G, G] = np.diag(st.gps_gm_var)
        z = z + st.bgps
        H[:, G] = np.eye(3)
        s2 = np.minimum(s_w2, s2)
    elif c.gps_pos_tau_s is not None:
        s2 = np.minimum(s_w2, s2) + np.maximum(s2 - s_w2, 0.0) * sched.gm_inflation
    R = np.diag(c.gps_sigma_scale ** 2 * s2)
    if c.gps_time_sigma_s > 0:
        vg = np.asarray(gps.v_N[i], float)
        R = R + c.gps_time_sigma_s ** 2 * np.outer(vg, vg)
    st.kalman_update("gps_pos", tk, z, H, R)
    return dv_hist


def _gps_velocity_update(st, ep, gps, k: int, i: int, lever_gps_B, dv_hist, tk: float) -> None:
    c, x, GM = st.cfg, st.x, st.lay.GM
    C = ins._dcm(x.q_NB)
    w_ie, w_en, *_ = ins._rates(x.lat_rad, x.h_m, x.v_N)
    w_nb = (ep.w_B[k] - st.bg) - C.T @ (w_ie + w_en)
    lv = C @ np.array(nm.cross(w_nb.tolist(), ins._floats(lever_gps_B)))
    z = x.v_N + dv_hist + lv - np.asarray(gps.v_N[i], float)
    H = np.zeros((3, st.lay.n))
    H[:, V] = np.eye(3)
    H[:, A] = ins._skew(lv)
    H[:, BG] = C @ ins._skew(lever_gps_B)
    if GM is not None:
        H[:, GM] = H[:, BG]
    R = np.diag((c.gps_sigma_scale * np.asarray(gps.sigma_vel_N[i], float)) ** 2)
    if c.gps_time_sigma_s > 0:
        # time-of-validity error δt: the fix's velocity is off by a_N δt
        w_ie_, w_en_, g_n, *_ = ins._rates(x.lat_rad, x.h_m, x.v_N)
        a_n = C @ ep.f_B[k] + g_n - np.array(nm.cross((2.0 * w_ie_ + w_en_).tolist(), x.v_N.tolist()))
        R = R + c.gps_time_sigma_s ** 2 * np.outer(a_n, a_n)
    st.kalman_update("gps_vel", tk, z, H, R)


def _mag_model(st, q, th, B_m, decl: float, P_prior: np.ndarray, emag: float):
    """Innovation z (1,), its H row (1, n) and R (1, 1) of the compass at attitude q and iron estimate th."""
    c, MI = st.cfg, st.lay.MI
    Cq = ins._dcm(q)
    roll, pitch, yaw = E.euler_from_C(Cq)
    B_c = B_m if MI is None else mag_corrected_field(B_m, th)
    z = np.array([E.wrap_pi(yaw - mag_heading(B_c, roll, pitch, decl))])
    H = np.zeros((1, st.lay.n))
    H[0, A] = mag_heading_jacobian(Cq, B_c)
    Rm = c.mag_heading_sigma_rad ** 2
    if MI is not None:
        H[0, MI] = mag_iron_jacobian(B_m, th, roll, pitch)
        # Gaussian second-order filter: the heading is quadratic in the iron errors at the size of
        # the priors (5 % and 2000 nT: ~0.5 deg, 30x the white part), so E[z] = −½ tr(Hs P) and
        # var += ½ tr(Hs P Hs P) (P: the iron block)
        Hs = mag_iron_hessian(B_m, th, roll, pitch)
        HP = Hs @ P_prior[MI, MI]
        z = z + 0.5 * np.trace(HP)
        Rm = Rm + 0.5 * float(np.sum(HP * HP.T))
    if c.mag_error_state:
        z = z + emag
        H[0, st.lay.mag] = 1.0
    return z, H, np.array([[Rm]])


def consider_mask(cfg, lay) -> np.ndarray | None:
    """(n,) True for the Schmidt "consider" states of the compass update (``mag_consider_states``):
    all but the heading ψ_d, the gyro biases and the iron states; None when not used."""
    if lay.MI is None or not cfg.mag_consider_states:
        return None
    upd = np.zeros(lay.n, bool)
    upd[A.start + 2] = True          # ψ_d, the heading
    upd[BG] = True
    upd[lay.MI] = True
    if lay.GM is not None:
        upd[lay.GM] = True
    return ~upd


def mag_update(st, ep, k: int, decl: float, consider: np.ndarray | None) -> None:
    """The compass update at epoch k: linear, or with the iron states an iterated EKF (Gauss-Newton to
    the MAP, relinearised at the corrected attitude and iron estimate, e_{i+1} = K_i (z(x_i) + H_i e_i))
    whose NIS is from the prior's linearisation; consider states get no gain (Joseph form)."""
    c, MI = st.cfg, st.lay.MI
    tk = ep.t_s[k]
    B_m = np.asarray(ep.B_B[ep.idx[k]], float)
    P_prior, emag = st.P, st.emag
    z, H, Rm = _mag_model(st, st.x.q_NB, st.theta_m, B_m, decl, P_prior, emag)
    if MI is None or (c.mag_iterations <= 1 and consider is None):
        st.kalman_update("mag", tk, z, H, Rm)
        return
    Pm = st.P
    S0 = float((H @ Pm @ H.T + Rm)[0, 0])
    nis0 = float(z[0] ** 2 / S0)
    e = np.zeros(st.lay.n)
    zi, Hi, Ri = z, H, Rm
    for it in range(c.mag_iterations):
        Kg = Pm @ Hi.T / float((Hi @ Pm @ Hi.T + Ri)[0, 0])
        if consider is not None:
            Kg[consider] = 0.0
        e = (Kg @ (zi + Hi @ e)).ravel()
        if it == c.mag_iterations - 1:
            break
        qi = ins._qmul(ins._qrot(e[A]), st.x.q_NB)
        qi = qi / math.sqrt(float(qi @ qi))
        zi, Hi, Ri = _mag_model(st, qi, st.theta_m - e[MI], B_m, decl, P_prior, emag)
    IKH = st.I_n - Kg @ Hi
    st.P[...] = IKH @ Pm @ IKH.T + Kg @ Ri @ Kg.T
    st.record("mag", tk, nis0, 1, z)
    st.inject(e)


def temp_update(st, ep, k: int) -> None:
    """The accelerometer temperature channels at epoch k: z = T̂_a − T_m, H = I on δT_a."""
    z = st.Ta - ep.T_acc_K[ep.idx[k]]
    H = np.zeros((3, st.lay.n))
    H[:, TA] = np.eye(3)
    st.kalman_update("temp", tk=ep.t_s[k], z=z, H=H, R=np.eye(3) * st.cfg.temp_sigma_K ** 2)
