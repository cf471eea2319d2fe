"""Generalised least squares for the triad calibration: the joint (seemingly unrelated regressions)
fit of three axes whose reference errors are correlated, the REML estimate of an extra white
variance, and the delta-method covariance of a function of the coefficients.

Model of one axis a (n segments, p terms)::

    y_a = X_a beta_a + e_a,   cov(e_a) = V_a = K_a + s_a^2 I        (K_a known, (n, n); s_a^2 >= 0)

and of the three axes together::

    y = blockdiag(X_x, X_y, X_z) beta + e,   cov(e)_(a,b) = K_ab + W_ab I     [(3n, 3n)]

W: the white covariance between the axes (each axis' own w_a on the diagonal; noise the channels
share, e.g. the converter's common mode, off it), with beta = (X' V^-1 X)^-1 X' V^-1 y and
cov(beta) = (X' V^-1 X)^-1.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import scipy.linalg
import scipy.special

from imurig.calibration.regression import RegressionResult
from imurig.calibration.terms import TermLibrary


def with_coefficients(res: RegressionResult, X: np.ndarray, y: np.ndarray, coef: np.ndarray,
                      cov: np.ndarray) -> RegressionResult:
    """``res`` with new coefficients and covariance, its residual statistics recomputed (the
    unweighted ones, as :func:`imurig.calibration.regression.fit_gls` reports them)."""
    fitted = X @ coef
    resid = y - fitted
    ss_res = float(resid @ resid)
    dof = res.n - res.p
    r2 = 1.0 - ss_res / res.ss_t if res.ss_t > 0 else float("nan")
    r2_adj = 1.0 - (ss_res / dof) / (res.ss_t / (res.n - 1)) if res.ss_t > 0 else float("nan")
    se = np.sqrt(np.diag(cov))
    return dataclasses.replace(res, coef_=coef, cov_=cov, std_error_=se, t_value_=coef / se, residuals_=resid,
                               fitted_=fitted, ss_res=ss_res, ms_res=ss_res / dof, r2=r2, r2_adj=r2_adj,
                               R=np.sqrt(r2) if r2 >= 0 else float("nan"),
                               R_adj=np.sqrt(r2_adj) if r2_adj >= 0 else float("nan"),
                               sigma_res=float(np.std(resid, ddof=1)))


def gls_projection(X: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """P = (X' C^-1 X)^-1 X' C^-1 (p, n) for C (n, n): the GLS estimate is beta = P y."""
    CiX = np.linalg.solve(cov, X)
    return np.linalg.solve(X.T @ CiX, CiX.T)


def reference_error_cov(segment_cov: np.ndarray, survey: np.ndarray | None, i: int, j: int) -> np.ndarray:
    """Covariance (n, n) between the reference errors of axes i and j: the segments' own
    (diagonal, segment_cov[:, i, j]) plus the survey's, J_i diag(sigma^2) J_j' (survey = J sigma)."""
    K = np.diag(segment_cov[:, i, j])
    return K if survey is None else K + survey[:, i, :] @ survey[:, j, :].T


def fit_jointly(results: dict, axes, inputs: dict, y_all: np.ndarray, segment_cov: np.ndarray,
                survey: np.ndarray | None, white: np.ndarray) -> tuple[dict, np.ndarray]:
    """Refit the three axes as one generalised least-squares problem (seemingly unrelated
    regressions, module doc): a position's setting error and the survey errors reach all three axes
    at once, so the other axes' readings tell each axis how far its reference is off. ``white`` (3,)
    the white part w_a of each axis from its own fit, or (3, 3) with the white covariance between
    axes (noise the channels share, e.g. the converter's common mode) off the diagonal. Returns
    ({axis: RegressionResult} with the joint coefficients and the diagonal blocks of their
    covariance, the covariance's cross-axis blocks (its diagonal blocks zero))."""
    n = y_all.shape[0]
    white = np.asarray(white, float)
    white = np.diag(white) if white.ndim == 1 else white
    Xs = [TermLibrary.from_names(results[a].names).design(inputs) for a in axes]
    off = np.concatenate([[0], np.cumsum([X.shape[1] for X in Xs])])
    V = np.zeros((3 * n, 3 * n))
    Xf = np.zeros((3 * n, off[-1]))
    for i in range(3):
        Xf[i * n:(i + 1) * n, off[i]:off[i + 1]] = Xs[i]
        for j in range(3):
            V[i * n:(i + 1) * n, j * n:(j + 1) * n] = (reference_error_cov(segment_cov, survey, i, j)
                                                       + white[i, j] * np.eye(n))
    L = np.linalg.cholesky(V)
    Xw = scipy.linalg.solve_triangular(L, Xf, lower=True)
    yw = scipy.linalg.solve_triangular(L, y_all.T.reshape(-1), lower=True)
    Q, R = np.linalg.qr(Xw)
    beta = scipy.linalg.solve_triangular(R, Q.T @ yw)
    Rinv = scipy.linalg.solve_triangular(R, np.eye(R.shape[0]))
    cov = Rinv @ Rinv.T
    cross = cov.copy()
    out = dict(results)
    for i, a in enumerate(axes):
        sl = slice(off[i], off[i + 1])
        cross[sl, sl] = 0.0  # the diagonal blocks live in the per-axis results
        out[a] = with_coefficients(results[a], Xs[i], y_all[:, i], beta[sl], cov[sl, sl])
    return out, cross


def white_variance_reml(X: np.ndarray, y: np.ndarray, K: np.ndarray, level: float | None = None) -> float:
    """REML estimate of s^2 in y = X b + e, cov(e) = K + s^2 I, K (n, n) known.

    Minimises  1/2 [log det V + log det(X' V^-1 X) + r' V^-1 r],  V = K + s^2 I, r the GLS
    residual, over log s^2 (bounded scalar search between 1e-12 and 1 times 10 x the data's
    OLS residual variance). One eigendecomposition K = U diag(lam) U' makes each evaluation
    O(n p^2): V^-1 = U diag(1 / (lam + s^2)) U'.

    With ``level``, s^2 is kept only where the data show it: the restricted likelihood ratio
    LR = 2 (nll(0) - nll(s^2)) against s^2 = 0 must exceed the chi2_1 quantile at 2 level (s^2 = 0
    lies on the boundary, where LR is the 50:50 mixture of 0 and chi2_1; Self & Liang 1987),
    else 0 is returned. Where K holds all the noise, a free s^2 is positive in half of the data
    sets and then only adds its own estimation noise to the weights and standard errors.
    """
    ols = np.linalg.lstsq(X, y, rcond=None)[0]
    top = max(float(np.var(y - X @ ols)), 1e-300) * 10
    lam, U = np.linalg.eigh(0.5 * (K + K.T))
    lam = np.clip(lam, 0.0, None)
    Xu, yu = U.T @ X, U.T @ y

    def nll(log_s2):
        v = np.exp(log_s2) + lam
        Xw = Xu / v[:, None]
        A = Xu.T @ Xw
        b = np.linalg.solve(A, Xw.T @ yu)
        r = yu - Xu @ b
        return 0.5 * (np.sum(np.log(v)) + np.linalg.slogdet(A)[1] + np.sum(r * r / v))

    import scipy.optimize   # here: the module costs 0.17 s to import, and only this search needs it

    lo, hi = np.log(top * 1e-12), np.log(top)
    res = scipy.optimize.minimize_scalar(nll, bounds=(lo, hi), method="bounded", options={"xatol": 1e-3})
    if level is not None and 2 * (nll(lo) - res.fun) < _chi2_1_isf(2 * level):
        return 0.0
    return float(np.exp(res.x))


def _chi2_1_isf(q: float) -> float:
    """The chi2_1 quantile with upper tail q (the function scipy.stats.chi2.isf(q, 1) calls, without
    importing scipy.stats: 0.44 s)."""
    return float(scipy.special.chdtri(1, q))


def delta_cov(h, x, cov) -> np.ndarray:
    """Covariance of h(x) by linearisation with a central-difference Jacobian."""
    x = np.asarray(x, float)
    step = np.maximum(np.sqrt(np.clip(np.diag(cov), 0, None)) * 1e-2, 1e-10 * np.maximum(1, np.abs(x)))
    cols = []
    for i in range(x.size):
        e = np.zeros_like(x)
        e[i] = step[i]
        cols.append((h(x + e) - h(x - e)) / (2 * step[i]))
    J = np.stack(cols, axis=1)
    J = np.where(np.isfinite(J), J, 0.0)
    return J @ cov @ J.T
