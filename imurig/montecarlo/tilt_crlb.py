"""The Cramér-Rao bound of the Monte-Carlo tilt-table campaign (:mod:`imurig.montecarlo.tilt`).

Observations: the window means of the three accelerometer voltages at every position, with
the noise of the sensor chain (:func:`window_noise_cov`) and of the table's angle setting,
and the survey's readings of the table errors. Parameters: the 15 physical accelerometer
parameters (:data:`PARAM_NAMES`) and the table errors as nuisance.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy import signal

from imurig.calibration.accelerometer import AXES
from imurig.kernel.recording import Recording
from imurig.kernel.site import Site
from imurig.kernel.units import ARCSEC
from imurig.montecarlo.crlb import (
    crlb_covariance,
    fisher_information,
    numerical_jacobian,
)
from imurig.montecarlo.tilt_rig import layout_key, window_layout
from imurig.rigs.tilt_table import specific_force_C
from imurig.sensors.accelerometer import QFlexTriad
from imurig.sensors.adc import DAQ6036E
from imurig.sensors.chain import ImuLab

PARAM_NAMES = ([f"sensitivity_{a}" for a in AXES]
               + [f"misalignment_{AXES[i]}{AXES[j]}" for i in range(3) for j in range(3) if i != j]
               + [f"bias_{a}" for a in AXES] + [f"nonlinearity_{a}" for a in AXES])


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
    q = adc.lsb_V
    cov += np.eye(3) * (q**2 / 12 + (adc.input_noise_lsb_rms * q) ** 2) / max(adc.averaging, 1) / n_window
    if adc.grounding != "DIFF":
        cov += adc.common_mode_noise_V_rms**2 / n_window
    return cov


@lru_cache(maxsize=32)
def _power_gain(fs: float, hi: float) -> float:
    """Mean power gain of band_noise's low-pass shaping filter (unit DC gain)."""
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
    lay = window_layout(layout_key(p))
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
    lab_stub = ImuLab(accelerometers=triad_from_truth(acc),
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


def triad_from_truth(acc: dict) -> QFlexTriad:
    """The Q-Flex triad with the injected values of a recording's truth (``truth["sensors"]["accelerometers"]``)."""
    fields = {k: acc[k] for k in QFlexTriad.__dataclass_fields__ if k in acc}
    fields["noise_bands"] = tuple(tuple(b) for b in fields.get("noise_bands", ()))
    return QFlexTriad(**fields)
