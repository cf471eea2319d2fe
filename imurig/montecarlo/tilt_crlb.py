"""The Cramér-Rao bound of the Monte-Carlo tilt-table campaign (:mod:`imurig.montecarlo.tilt`).

Observations: the window means of the three accelerometer voltages at every position, with
the noise of the sensor chain (:func:`window_noise_cov`) and of the table's angle setting,
and the survey's readings of the table errors. Parameters: the 15 physical accelerometer
parameters (:data:`PARAM_NAMES`) and the table errors as nuisance.
"""
from __future__ import annotations


import numpy as np

from imurig.calibration.accelerometer import AXES
from imurig.kernel.recording import Recording
from imurig.kernel.site import Site, parse_time
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
from imurig.sensors.disturbances import PeopleTransients, PumpVibration
from imurig.sensors.effects import AdcQuantisation, ChainContext

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


def window_noise_cov(p: dict, lab: ImuLab, n_window: int, hour_of_day: np.ndarray | None = None) -> np.ndarray:
    """Covariance (3, 3) V^2 of the mean of one window of ``n_window`` logged samples of the
    three accelerometer channels, asking the chain's noise models:

    - the Q-Flex current noise x R_L (:meth:`QFlexTriad.window_mean_variance_A2`: its bands as
      sampled, the long-window limit);
    - the converter: rounding and input noise :meth:`DAQ6036E.sample_variance_V2` / N, and the
      common-mode noise sigma_cm^2 / N (same on every channel, off the diagonal too; not with
      DIFF wiring);
    - the lab's Gaussian disturbance effects (specific-force stage: the pump ...): each one's
      ``noise_variance`` of a window mean (m/s^2)^2 times the true sensitivity squared, at the
      schedule's hours ``hour_of_day`` (default: the start time's). Impulsive effects (people
      transients, a loose cable: rare, non-Gaussian; the per-position Huber M-estimate, or the
      seed's median, rejects most) are left out.
    """
    acc, adc = lab.accelerometers, lab.adc
    fs = float(p["sample_rate_hz"])
    if hour_of_day is None:
        start = parse_time(p["start_time"])
        hour_of_day = np.array([start.hour + start.minute / 60 + start.second / 3600])
    ctx = ChainContext(time_s=np.zeros(1), sample_rate_hz=fs, hour_of_day=hour_of_day, adc=adc,
                       window_samples=n_window)
    cov = np.diag(acc.current_noise(p["logging"] == "averaged").noise_variance(ctx))
    cov += np.eye(3) * AdcQuantisation().noise_variance(ctx) / n_window
    cov += adc.common_mode.noise_variance(ctx)          # common to the three channels
    s_true = acc.k1_A_per_m_s2 * acc.load_resistor_ohm
    for eff in lab.stage_effects("specific_force"):
        if not eff.impulsive:
            cov += np.diag(eff.noise_variance(ctx) * s_true**2)
    return cov


def crlb(p: dict, rec: Recording) -> dict[str, float]:
    """Cramér-Rao bound (1 sigma) of the 15 physical parameters for this run's true sensor,
    table, schedule and noise: {parameter name: bound}.

    Observations: the window means of the three accelerometer voltages at every position
    (covariance :func:`window_noise_cov` plus the per-position angle-setting error, uniform
    within +-res/2 so variance res^2/12 in theta and phi, propagated through the forward
    model), and the survey's readings of the table errors (variance survey_accuracy^2).
    Parameters: the 15 sensor parameters and the 2 + n_mounts table errors (nuisance).
    F = sum_k J_k' C_k^-1 J_k + diag(0, 1/s_survey^2); bound = sqrt(diag((F^-1)[:15, :15])).

    The bound is the data's, for any unbiased estimator whatever its per-position statistic. A
    statistic of Gaussian efficiency eff (:func:`imurig.calibration.preprocess.statistic_efficiency`:
    mean 1, Huber 0.950, median 2/pi) multiplies the window-noise part of C by 1/eff, so an
    estimator built on it sits up to 1/sqrt(eff) above the bound where the window noise dominates
    (Huber 1.026, median 1.25); its standard errors follow its statistic (batch means of that
    statistic, :func:`imurig.calibration.preprocess.segment_statistic_covariance`).
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
                                   scan_list=tuple(rec.meta["adc"]["scan_list"])),
                      pump=PumpVibration(enabled=bool(p["pump"])), people=PeopleTransients(enabled=bool(p["people"])))
    n_window = round(p["dwell_s"] * p["sample_rate_hz"])
    start = parse_time(rec.meta.get("start_time", p["start_time"]))
    hours = (start.hour + start.minute / 60 + start.second / 3600 + (rec.time_s - rec.time_s[0]) / 3600.0) % 24.0
    Sv = window_noise_cov(p, lab_stub, n_window, hours)
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
