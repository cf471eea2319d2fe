"""Observability of the filter's error states over a manoeuvre (paper section 4.1, eq. 4).

    G = Σ_k Φᵀ(k+1|0) Hᵀ(k) H(k) Φ(k+1|0)                                   (eq. 4)

Φ(k+1|0) is the error-state transition from the start of the manoeuvre, built from the
filter's linearised error model (:class:`imurig.flights.ekf.LooseEKF`) along the true
trajectory; H(k) the GPS position (+ velocity) and magnetic-heading rows at the fixes. The
state is scaled by its prior σ (so G is dimensionless) and each measurement row by 1/σ_meas.
The analysis can add states the filter leaves out (paper Table 1): accelerometer and gyro
scale factors and the six off-diagonal misalignments of each triad,

    δf_B = diag(f_B) s_a + M_a f_B,    δw_B = diag(w_B) s_g + M_g w_B.

It reports the normalised singular values of G (all > 0 ⇔ observable) and, per state, the
posterior-to-prior σ ratio of the information form (P0⁻¹ + G)⁻¹ (1 = nothing learnt,
→ 0 = well observed) — a process-noise-free bound.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from imurig.flights import ekf, ins

MIS_PAIRS = ((0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1))


@dataclass
class ObservabilityReport:
    state_names: tuple
    singular_values: np.ndarray      # normalised by the largest, descending
    sigma_ratio: np.ndarray          # per state: posterior σ / prior σ
    gramian: np.ndarray

    def table(self, threshold: float = 0.5) -> list[dict]:
        return [{"state": n, "sigma_ratio": float(r), "observable": bool(r < threshold)}
                for n, r in zip(self.state_names, self.sigma_ratio)]


def gramian(truth, *, scale_factors=True, misalignments=True, nav_rate_hz=10.0, gps_every_s=1.0,
            use_velocity=True, use_mag=True, use_temp=True, sigma_temp_K=0.05, config: ekf.FilterConfig | None = None,
            sigma_pos_m=0.5, sigma_vel_m_s=0.05, sigma_heading_rad=0.017453292519943295,
            sigma0_scale=0.01, sigma0_mis_rad=2e-3, lever_gps_B=(0.0, 0.0, 0.0)) -> ObservabilityReport:
    """Eq. 4 along ``truth`` (FlightTruth-like: time_s, rate_hz, lat/lon/h, v_N, q_NB, f_B, w_IB_B)."""
    cfg = config or ekf.FilterConfig()
    base = ekf.FilterConfig(**{**cfg.__dict__, "estimate_scale_factors": False, "estimate_misalignments": False,
                               "gps_pos_states": False})
    filt = ekf.LooseEKF(base)
    names = list(ekf.BASE_STATES)
    if scale_factors:
        names += list(ekf.SCALE_STATES)
    if misalignments:
        names += list(ekf.MIS_STATES)
    n = len(names)
    sig0 = np.zeros(n)
    sig0[:18] = np.sqrt(np.diag(filt.initial_covariance()))
    sig0[18:] = sigma0_scale
    if misalignments:
        sig0[-12:] = sigma0_mis_rad
    D = np.diag(sig0)
    step = max(1, round(truth.rate_hz / nav_rate_hz))
    T = step / truth.rate_hz
    idx = np.arange(0, truth.time_s.size, step)
    meas_every = max(1, round(gps_every_s / T))
    l = np.asarray(lever_gps_B, float)
    Phi0 = np.eye(n)
    G = np.zeros((n, n))
    for m, i in enumerate(idx):
        x = ins.state_at(truth, i)
        C = ins._dcm(x.q_NB)
        f_B, w_B = truth.f_B[i], truth.w_IB_B[i]
        if m % meas_every == 0 and m > 0:
            rows = []
            Hp = np.zeros((3, n))
            Hp[:, 0:3] = np.eye(3)
            Hp[:, 6:9] = ins._skew(C @ l)
            rows.append(Hp / sigma_pos_m)
            if use_velocity:
                Hv = np.zeros((3, n))
                Hv[:, 3:6] = np.eye(3)
                Hv[:, 12:15] = C @ ins._skew(l)
                rows.append(Hv / sigma_vel_m_s)
            if use_mag:
                d = C[0, 0] ** 2 + C[1, 0] ** 2
                Hm = np.zeros((1, n))
                Hm[0, 6:9] = [C[2, 0] * C[0, 0] / d, C[2, 0] * C[1, 0] / d, -1.0]
                rows.append(Hm / sigma_heading_rad)
            if use_temp:
                Ht = np.zeros((3, n))
                Ht[:, 15:18] = np.eye(3)
                rows.append(Ht / sigma_temp_K)
            H = np.vstack(rows) @ Phi0 @ D
            G += H.T @ H
        F = np.zeros((n, n))
        F[:18, :18] = filt.error_dynamics(x, f_B, w_B, C)
        k = 18
        if scale_factors:
            F[3:6, 18:21] = -C * f_B
            F[6:9, 21:24] = C * w_B
            k = 24
        if misalignments:
            for p, (a, b) in enumerate(MIS_PAIRS):
                F[3:6, k + p] = -C[:, a] * f_B[b]
                F[6:9, k + 6 + p] = C[:, a] * w_B[b]
        FT = F * T
        Phi0 = (np.eye(n) + FT + 0.5 * FT @ FT) @ Phi0
    s = np.linalg.svd(G, compute_uv=False)
    post = np.linalg.inv(np.eye(n) + G)          # in prior-σ units: prior = I
    return ObservabilityReport(tuple(names), s / s[0], np.sqrt(np.diag(post)), G)
