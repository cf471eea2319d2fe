"""The rate-table rows' round-time error (the stopwatch's resolution): the timer test.

The twin takes the round times as exact. A timer of resolution q adds to each round time T_i an
error of variance sigma_T^2 (q^2/12 for one rounded reading), so the relative rate mismatch
d_i = T_true / T_i - 1 gets variance sigma_T^2 / T_i^2, which grows with the rate squared
(:func:`timer_quantisation_test`; the diagnosis of the rows: :mod:`imurig.diagnose.rate_table`).
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import minimize_scalar


def timer_quantisation_test(e: np.ndarray, X: np.ndarray, T_s: np.ndarray, rng: np.random.Generator,
                            alpha: float = 0.01, n_sim: int = 1000, folds: int = 4) -> dict:
    """Is there a round-time error in the rate residuals? (see the module doc, item 2)

    ``e`` (n,): residuals of the relative rate mismatch d (1) after the mean model ``X`` (n, p);
    ``T_s`` (n,): the measured round times (s). Noise models, Gaussian, with h_i the leverage of
    row i in X and z_i = 1 / T_i^2 (1/s^2)::

        H0: var(e_i) = (1 - h_i) a                         (table setting error, relative)
        H1: var(e_i) = (1 - h_i) (a + sigma_T^2 z_i)       (plus the timer's round-time error)

    The statistic is the likelihood ratio LR = 2 (nll0 - min over rho of nll1), rho = sigma_T^2 / a
    scanned on a log grid (a profiled out). Its threshold is the (1 - alpha) quantile of the same
    statistic, scan included, on ``n_sim`` residuals simulated under H0 (LR does not depend on a).
    Accepted when LR beats it, BIC is lower (LR > log n) and blocked cross-validation
    (``folds``) gives a higher held-out log-likelihood. sigma_T (s) and the resolution
    q = sqrt(12) sigma_T of a rounded reading come with standard errors from the expected
    Fisher information of (a, sigma_T^2) (delta method for the square root).
    """
    e = np.asarray(e, float)
    T_s = np.asarray(T_s, float)
    n = e.size
    Q, _ = np.linalg.qr(np.asarray(X, float))
    lev = np.clip(1.0 - np.sum(Q**2, axis=1), 1e-6, None)      # 1 - h_i
    z = 1.0 / T_s**2
    rhos = np.concatenate([[0.0], np.logspace(-3, 4, 141) / z.max()])

    nll = _timer_nll(lev, z)

    def lr(E2):
        L, _ = nll(E2, rhos)
        return 2.0 * (L[:, 0] - L.min(axis=1))

    E2 = (e**2)[None, :]
    stat = float(lr(E2)[0])
    N = rng.standard_normal((n_sim, n))
    Es = N - (N @ Q) @ Q.T
    thr = float(np.quantile(lr(Es**2), 1 - alpha))
    # the estimate: refine the best grid point
    L, _ = nll(E2, rhos)
    j = int(np.argmin(L[0]))
    rho = rhos[j]
    if j > 0:
        lo, hi = np.log(rhos[max(j - 1, 1)]), np.log(rhos[min(j + 1, rhos.size - 1)])
        res = minimize_scalar(lambda lr_: float(nll(E2, np.array([np.exp(lr_)]))[0][0, 0]), bounds=(lo, hi),
                              method="bounded")
        rho = float(np.exp(res.x))
    a = float(nll(E2, np.array([rho]))[1][0, 0])
    s2 = rho * a                                                  # sigma_T^2, s^2
    v = lev * (a + s2 * z)
    G = np.column_stack([lev, lev * z])
    info = 0.5 * (G / v[:, None] ** 2).T @ G
    se_s2 = float(np.sqrt(np.linalg.inv(info)[1, 1]))
    sig = float(np.sqrt(s2))
    se_sig = se_s2 / (2 * sig) if sig > 0 else float(np.sqrt(se_s2))
    cv0, cv1 = _timer_cv(nll, e, lev, z, rhos, folds)
    accepted = bool(stat > thr and stat > np.log(n) and cv1 > cv0)
    share = float(np.sum(lev * s2 * z) / np.sum(lev * (a + s2 * z)))
    return {"statistic": stat, "threshold": thr, "alpha": alpha, "bic_improvement": stat - float(np.log(n)),
            "cv_loglik_without": cv0, "cv_loglik_with": cv1, "accepted": accepted,
            "sigma_T_s": sig, "sigma_T_se_s": float(se_sig), "sigma_T2_s2": s2, "sigma_T2_se_s2": se_s2,
            "resolution_s": float(np.sqrt(12) * sig), "resolution_se_s": float(np.sqrt(12) * se_sig),
            "setting_sigma": float(np.sqrt(a)), "variance_share": share,
            "rate_sigma_rel_at_max_rate": float(sig * np.sqrt(z.max()))}


def _timer_nll(lev: np.ndarray, z: np.ndarray):
    """nll(E2, rho, rows): the (s, g) profiled negative log-likelihoods and the ML a of squared
    residuals E2 (s, n) under var_i = (1 - h_i) a (1 + rho z_i), ``lev`` = 1 - h_i, for each of the
    g values ``rho`` = sigma_T^2 / a, over ``rows``."""
    def nll(E2, rh, rows=slice(None)):
        """(s, g) profiled negative log-likelihoods and ML a of squared residuals E2 (s, n)."""
        W = lev[rows][None, :] * (1.0 + rh[:, None] * z[rows][None, :])
        m = W.shape[1]
        a = E2[:, rows] @ (1.0 / W).T / m
        return 0.5 * m * (np.log(a) + 1.0) + 0.5 * np.sum(np.log(W), axis=1)[None, :], a
    return nll


def _timer_cv(nll, e: np.ndarray, lev: np.ndarray, z: np.ndarray, rhos: np.ndarray, folds: int) -> tuple[float, float]:
    """Blocked cross-validation of the held-out Gaussian log-likelihood of the residuals ``e``
    without and with the timer term (rows dealt round-robin in blocks): (cv0, cv1)."""
    n = e.size
    E2 = (e**2)[None, :]
    # blocked cross-validation of the held-out log-likelihood (rows dealt round-robin in blocks)
    L_blk = max(1, n // (4 * folds))
    fold = (np.arange(n) // L_blk) % folds
    cv0 = cv1 = 0.0
    for f in range(folds):
        tr, te = fold != f, fold == f
        Ltr, Atr = nll(E2, rhos, tr)
        k = int(np.argmin(Ltr[0]))
        for rh, a_, acc in ((0.0, Atr[0, 0], 0), (rhos[k], Atr[0, k], 1)):
            vt = lev[te] * a_ * (1.0 + rh * z[te])
            ll = float(-0.5 * np.sum(np.log(2 * np.pi * vt) + e[te] ** 2 / vt))
            if acc:
                cv1 += ll
            else:
                cv0 += ll
    return cv0, cv1
