"""Allan deviation (IEEE Std 952) and the angle-random-walk coefficient.

For a rate record x (n,) sampled at fs, the overlapping Allan variance at tau = m / fs is

    sigma^2(tau) = 1 / (2 tau^2 (n - 2m)) * sum_k (theta_{k+2m} - 2 theta_{k+m} + theta_k)^2

with theta the integrated angle (cumulative sum / fs). White rate noise of coefficient N
(rad/s/sqrt(Hz), i.e. rad/sqrt(s)) gives sigma(tau) = N / sqrt(tau).
"""
from __future__ import annotations

import numpy as np


def allan_deviation(x: np.ndarray, fs: float, taus: np.ndarray) -> np.ndarray:
    """Overlapping Allan deviation of ``x`` (n,) at the cluster times ``taus`` (s), vectorised."""
    x = np.asarray(x, float)
    theta = np.concatenate(([0.0], np.cumsum(x))) / fs
    out = []
    for tau in np.asarray(taus, float):
        m = int(round(tau * fs))
        if m < 1 or 2 * m >= theta.size:
            raise ValueError(f"tau = {tau} s does not fit a record of {x.size / fs:.3g} s at {fs} Hz")
        d = theta[2 * m:] - 2 * theta[m:-m] + theta[:-2 * m]
        out.append(np.sqrt(np.mean(d * d) / (2 * (m / fs) ** 2)))
    return np.array(out)


def fit_arw(x: np.ndarray, fs: float, taus=None) -> tuple[float, np.ndarray, np.ndarray]:
    """Angle-random-walk coefficient N from the Allan deviation on its -1/2 slope.

    Least squares of log sigma = log N - 0.5 log tau over ``taus`` (default 0.1 ... 10 s).
    Returns (N, taus, sigma).
    """
    taus = np.logspace(-1, 1, 9) if taus is None else np.asarray(taus, float)
    sig = allan_deviation(x, fs, taus)
    logN = np.mean(np.log(sig) + 0.5 * np.log(taus))
    return float(np.exp(logN)), taus, sig
