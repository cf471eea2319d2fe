"""The Cramér-Rao bound of the Monte-Carlo turn-table campaign (:mod:`imurig.montecarlo.turn`).

Observations: the whole-round mean voltages of the three gyros at every step, with the noise
of the FOG, the DAQ and the slip rings (:func:`whole_round_noise`), and the timer's table rate
per step. Parameters: the 15 physical gyro parameters (:data:`PARAM_NAMES`) and the true
table rates as nuisance.
"""
from __future__ import annotations

import math

import numpy as np

from imurig.calibration.gyro import (
    AXIS_OF_MOUNT,
    injected_parameters,
    segment_covariance,
    timer_difference_sigma,
)
from imurig.kernel.recording import Recording
from imurig.kernel.site import EARTH_RATE_RAD_S, Site
from imurig.montecarlo.crlb import crlb_covariance, numerical_jacobian
from imurig.sensors.disturbances import SlipRingNoise
from imurig.sensors.effects.adc_quantisation import variance_V2

AXES = ("p", "q", "r")
PARAM_NAMES = ([f"sensitivity_{a}" for a in AXES]
               + [f"misalignment_{AXES[i]}{AXES[j]}" for i in range(3) for j in range(3) if i != j]
               + [f"bias_{a}" for a in AXES] + [f"nonlinearity_{a}" for a in AXES])


def forward_volts(theta: np.ndarray, omega: np.ndarray, axis_sign: np.ndarray, omega_v: float) -> np.ndarray:
    """Noise-free whole-round mean gyro voltages per step, (n_steps, 3) V.

    theta (15,): scale SF (V/(rad/s)), misalignment M_pq, M_pr, M_qp, M_qr, M_rp, M_rq (rad),
    bias b (rad/s), nonlinearity k2 (1/(rad/s)); omega (n,): the table's whole-round mean
    rate (rad/s, signed by direction); axis_sign (n, 3): +-1 at the IMU axis on the table.
    w_C = axis_sign (Omega + Omega_E sin(lat)),  w_S = (I + M) w_C,
    V = SF (w_S + b + k2 w_S^2)  (FOGTriad.ideal_voltage at its reference temperature; the
    Earth's horizontal rate and the ripple average out over whole rounds).
    """
    S, m, b, k2 = theta[0:3], theta[3:9], theta[9:12], theta[12:15]
    M = np.array([[0, m[0], m[1]], [m[2], 0, m[3]], [m[4], m[5], 0]])
    w_C = axis_sign * (omega + omega_v)[:, None]
    w_S = w_C + w_C @ M.T
    return S * (w_S + b + k2 * w_S**2)


def whole_round_noise(rec: Recording, rw: Recording, rate: np.ndarray, p: dict) -> np.ndarray:
    """Covariance (3n, 3n) V^2 of the whole-round mean voltages of the three gyros, step-major
    (index 3 i + k for step i, gyro k), from the chain's noise model:

    - the FOG's angle random walk and Gauss-Markov bias instability: the segment covariance of
      :func:`imurig.calibration.gyro.segment_covariance` (the one the calibration's GLS and the
      diagnosis use; timer term off here), times SF_k^2, independent between gyros;
    - the DAQ: quantisation and input noise (q^2/12 + (e q)^2) / n_i per channel, and its
      common-mode noise sigma_cm^2 / n_i on every channel pair of step i (not with DIFF wiring);
    - the slip rings: rms^2 <p(theta)^2> / n_i per line, p averaged over whole rounds.
    n_i: logged samples in window i. The timer's error enters as its own observation (see crlb).
    """
    g = rec.truth["sensors"]["gyros"]
    SF = np.asarray(g["scale_V_per_rad_s"], float)
    noise = rec.meta["gyro_noise_model"]
    K = segment_covariance(rw, rate, noise, 0.0)                           # (n, n) (rad/s)^2
    n = rw.n_segments
    C = np.einsum("ij,k,kl->ikjl", K, SF**2, np.eye(3))                     # (n, 3, n, 3)
    adc = rec.meta["adc"]
    q = float(adc["lsb_V"])
    white = variance_V2(q, adc["input_noise_lsb_rms"], adc.get("averaging", 1))
    cm = adc["common_mode_noise_V_rms"] ** 2 if adc["grounding"] != "DIFF" else 0.0
    slip = 0.0
    sr = (rec.truth.get("chain") or {}).get("slip_rings")
    if sr and sr.get("enabled"):
        prof = SlipRingNoise(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in sr.items()
                                if k in SlipRingNoise.__dataclass_fields__})
        slip = prof.round_average_variance_V2()
    counts = np.array([s.stop - s.start for s in rw.segment_slices()], float)
    for i in range(n):
        C[i, :, i, :] += (np.eye(3) * (white + slip) + cm) / counts[i]
    return C.reshape(3 * n, 3 * n)


def crlb(p: dict, rec: Recording, rw: Recording, rate: np.ndarray) -> dict[str, float]:
    """Cramér-Rao bound (1 sigma) of the 15 physical gyro parameters for this run: {name: bound}.

    Observations: the whole-round mean voltages of the three gyros at every step (covariance
    :func:`whole_round_noise`) and the timer's table rate per step, Omega_hat_i = Omega_i + e_i,
    e_i ~ N(0, (Omega_i sigma_dT / T_i)^2) (the timer term of segment_covariance). Parameters:
    the 15 gyro parameters (at their effective injected values: the misalignment includes the
    table's wobble as each mounting sees it) and the n true table rates (nuisance).
    F = J' C^-1 J + diag(0, 1/sigma_Omega^2); bound = sqrt(diag((F^-1)[:15, :15])).
    """
    mounts = [str(m) for m in rw.segments["mount"]]
    inj = injected_parameters(rec.truth, mounts)
    theta = np.array([inj[nm] for nm in PARAM_NAMES], float)
    n = rw.n_segments
    E = np.zeros((n, 3))
    for i, m in enumerate(mounts):
        j, s = AXIS_OF_MOUNT[m]
        E[i, j] = s
    site = Site.from_dict(rec.meta.get("site", {}))
    omega_v = EARTH_RATE_RAD_S * math.sin(site.latitude_rad)
    omega = np.asarray(rate, float)

    def h(x):
        return forward_volts(x[:15], x[15:], E, omega_v).reshape(-1)

    x0 = np.concatenate([theta, omega])
    step = np.concatenate([np.abs(theta[:3]) * 1e-6, np.full(6, 1e-6), np.full(3, 1e-7), np.full(3, 1e-5),
                           np.full(n, 1e-6)])
    J = numerical_jacobian(h, x0, step)                                      # (3n, 15 + n)
    C = whole_round_noise(rec, rw, rate, p)
    L = np.linalg.cholesky(C)
    W = np.linalg.solve(L, J)
    F = W.T @ W
    T = rw.segments["stop_s"] - rw.segments["start_s"]
    s_omega = np.abs(omega) * timer_difference_sigma(rec, p["timer"]) / T
    F[15:, 15:] += np.diag(1.0 / s_omega**2)
    cov = crlb_covariance(F, 15, PARAM_NAMES + [f"Omega_{i}" for i in range(n)])
    return dict(zip(PARAM_NAMES, np.sqrt(np.diag(cov)).tolist()))
