"""Linear least squares done stably (seed sections 4.1-4.2).

``fit_ols`` solves ``min ||W^(1/2) (y - X b)||`` with a Householder QR of the
column-scaled design (never forming or inverting ``X'X``) and reports the
regression statistics of seed section 4.2:

* ``ss_res = sum w_i e_i^2``                      (eq. 4.25)
* ``ms_res = ss_res / (n - p)``                    (eq. 4.27)
* ``ss_t = sum w_i (y_i - ybar_w)^2``              (eq. 4.28, = y'y - (sum y)^2/n unweighted)
* ``r2 = 1 - ss_res / ss_t``                       (eq. 4.29, "coefficient of determination")
* ``r2_adj = 1 - (ss_res/(n-p)) / (ss_t/(n-1))``   (eq. 4.30)
* ``R = sqrt(r2)``, ``R_adj = sqrt(r2_adj)``        (what the seed's MATLAB code, appendix C, prints
  as "R" and "Radj"; NaN when the value under the root is negative)
* ``sigma_res = std(residuals, ddof=1)``            (MATLAB ``std``, the seed's sigma_res)

The centred ``ss_t`` is used whether or not the model has a constant term.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from imurig.calibration.identifiability import (RELATIVE_SUPPORT_TOL, as_float_array, check_identifiable,
                                              unidentifiable_error)

__all__ = ["RegressionResult", "fit_ols", "check_identifiable", "RELATIVE_SUPPORT_TOL"]



def _json_float(v: float) -> float | None:
    v = float(v)
    return v if math.isfinite(v) else None


@dataclass
class RegressionResult:
    """Result of :func:`fit_ols`. Arrays: ``coef_`` (p,), ``cov_`` (p, p),
    ``residuals_``/``fitted_`` (n,) in the units of ``y`` (unweighted).

    Information criteria (Gaussian likelihood with the ML variance
    ``ss_res / n``, ``k = p`` estimated coefficients, the statsmodels
    convention)::

        loglik = -n/2 * (log(2*pi*ss_res/n) + 1) + 1/2 * sum(log w)
        aic = -2*loglik + 2*p
        bic = -2*loglik + p*log(n)

    ``condition_number`` is the 2-norm condition number of the weighted,
    column-scaled (unit-norm columns) design: the quantity that governs
    identifiability and the accuracy of the solution.
    """

    names: list[str]
    coef_: np.ndarray
    cov_: np.ndarray
    std_error_: np.ndarray
    t_value_: np.ndarray
    residuals_: np.ndarray
    fitted_: np.ndarray
    n: int
    p: int
    ss_res: float
    ms_res: float
    ss_t: float
    r2: float
    r2_adj: float
    R: float
    R_adj: float
    sigma_res: float
    loglik: float
    aic: float
    bic: float
    condition_number: float
    weights_: np.ndarray | None = field(default=None, repr=False)

    @property
    def dof(self) -> int:
        """Residual degrees of freedom ``n - p``."""
        return self.n - self.p

    def _index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"no term {name!r} in the model; terms are {self.names}") from None

    def coef(self, name: str) -> float:
        """Estimated coefficient of term ``name``."""
        return float(self.coef_[self._index(name)])

    def std_error(self, name: str) -> float:
        """Standard error of the coefficient of term ``name``."""
        return float(self.std_error_[self._index(name)])

    def predict(self, X: np.ndarray) -> np.ndarray:
        """``X @ coef_`` for a design ``X`` of shape ``(m, p)`` (or ``(p,)``)."""
        X = np.asarray(X, dtype=np.float64)
        if X.shape[-1] != self.p or X.ndim not in (1, 2):
            raise ValueError(f"predict expects a design of shape (m, {self.p}) with columns {self.names}, got {X.shape}")
        return X @ self.coef_

    def table(self) -> list[dict]:
        """Coefficient table: rows ``{name, estimate, std_error, t}``."""
        return [
            {"name": n, "estimate": float(b), "std_error": float(s), "t": _json_float(t)}
            for n, b, s, t in zip(self.names, self.coef_, self.std_error_, self.t_value_)
        ]

    def to_dict(self, include_residuals: bool = False) -> dict:
        """JSON-serialisable summary (plain floats/lists; non-finite values -> None)."""
        d = {
            "names": list(self.names),
            "coef": [float(v) for v in self.coef_],
            "std_error": [float(v) for v in self.std_error_],
            "t_value": [_json_float(v) for v in self.t_value_],
            "cov": [[float(v) for v in row] for row in self.cov_],
            "n": int(self.n),
            "p": int(self.p),
            "weighted": self.weights_ is not None,
        }
        for k in ("ss_res", "ms_res", "ss_t", "r2", "r2_adj", "R", "R_adj", "sigma_res",
                  "loglik", "aic", "bic", "condition_number"):
            d[k] = _json_float(getattr(self, k))
        if include_residuals:
            d["residuals"] = [float(v) for v in self.residuals_]
            d["fitted"] = [float(v) for v in self.fitted_]
        return d


# ---------------------------------------------------------------------------
# validation helpers


def _validate(X, y, names, weights):
    X = as_float_array(X, "X")
    if X.ndim != 2:
        raise ValueError(f"X must be a 2-D (n, p) design matrix, got shape {X.shape}")
    n, p = X.shape
    y = as_float_array(y, "y")
    if y.ndim != 1:
        raise ValueError(f"y must be a 1-D array of length n={n}, got shape {y.shape} (use y.ravel() for a column vector)")
    if y.shape[0] != n:
        raise ValueError(f"y has {y.shape[0]} observations but X has {n} rows")
    names = [str(s) for s in names] if not isinstance(names, str) else [names]
    if len(names) != p:
        raise ValueError(f"got {len(names)} names for {p} design columns; pass one name per column of X")
    if len(set(names)) != p:
        dup = sorted({s for s in names if names.count(s) > 1})
        raise ValueError(f"duplicate term names {dup}; every column needs a distinct name")
    if p == 0:
        raise ValueError("X has no columns: the model needs at least one term")
    problems = []
    for label, bad in (("X", ~np.isfinite(X).all(axis=1)), ("y", ~np.isfinite(y))):
        if bad.any():
            rows = np.flatnonzero(bad)
            arr = X[rows] if label == "X" else y[rows]
            kinds = " and ".join(k for k, m in (("NaN", np.isnan(arr).any()), ("inf", np.isinf(arr).any())) if m)
            problems.append(f"{label} contains {kinds} in {rows.size} of {n} rows (first rows: {rows[:5].tolist()})")
    if weights is not None:
        weights = as_float_array(weights, "weights")
        if weights.shape != (n,):
            raise ValueError(f"weights must have shape ({n},) like y, got {weights.shape}")
        bad = ~np.isfinite(weights) | (weights <= 0)
        if bad.any():
            problems.append(
                f"weights must be finite and > 0 (inverse variances); {int(bad.sum())} rows violate this "
                f"(first rows: {np.flatnonzero(bad)[:5].tolist()}); drop those observations instead"
            )
    if problems:
        raise ValueError("; ".join(problems) + ". Remove or repair these observations before fitting.")
    if n <= p:
        raise ValueError(
            f"{n} observations for {p} terms: least squares needs n > p, so at least {p + 1 - n} more "
            f"observation(s) are needed (more for meaningful statistics), or drop terms"
        )
    return X, y, names, weights


# ---------------------------------------------------------------------------


def fit_ols(
    X: np.ndarray,
    y: np.ndarray,
    names: Sequence[str],
    weights: np.ndarray | None = None,
) -> RegressionResult:
    """Least-squares fit of ``y ≈ X @ b``.

    Parameters
    ----------
    X : (n, p) design matrix, finite, n > p.
    y : (n,) response, finite.
    names : p term names (one per column).
    weights : optional (n,) positive weights = inverse variances (relative:
        only their ratios matter, because the covariance is scaled by the
        weighted ``ms_res``). Minimises ``sum w_i (y_i - x_i b)^2``.

    Method: columns of ``W^(1/2) X`` are scaled to unit norm, a Householder
    QR gives ``R`` (p, p); an SVD of ``R`` gives the singular values for the
    rank test (tolerance ``max(n, p) * eps * s_max``) and the null space for
    the error message. ``cov_ = ms_res * D^-1 R^-1 R^-T D^-1``.

    Raises
    ------
    ValueError : bad shapes, NaN/inf, non-positive weights, n <= p.
    UnidentifiableTermsError : rank-deficient design; ``.terms`` names the
        dependent terms.
    """
    X, y, names, weights = _validate(X, y, names, weights)
    n, p = X.shape
    if weights is not None:
        sw = np.sqrt(weights)
        Xw, yw = X * sw[:, None], y * sw
    else:
        Xw, yw = X, y
    scale = np.linalg.norm(Xw, axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    Xs = Xw / scale
    Q, R = scipy.linalg.qr(Xs, mode="economic", check_finite=False)
    _, sv, Vt = np.linalg.svd(R)
    tol = max(n, p) * np.finfo(np.float64).eps * sv[0]
    if sv[-1] <= tol:
        raise unidentifiable_error(names, Vt, sv, tol, scale)
    qty = Q.T @ yw
    coef_s = scipy.linalg.solve_triangular(R, qty, check_finite=False)
    coef = coef_s / scale
    Rinv = scipy.linalg.solve_triangular(R, np.eye(p), check_finite=False)
    cov_unscaled = (Rinv @ Rinv.T) / np.outer(scale, scale)  # (X'WX)^-1
    return _ols_result(X, y, names, weights, coef, cov_unscaled, float(sv[0] / sv[-1]))


def _ols_result(X, y, names, weights, coef, cov_unscaled, condition_number: float) -> RegressionResult:
    """The statistics of a (weighted) least-squares fit with coefficients ``coef`` and (X'WX)^-1 (module doc)."""
    n, p = X.shape
    fitted = X @ coef
    resid = y - fitted
    wres = resid if weights is None else resid * np.sqrt(weights)
    ss_res = float(wres @ wres)
    dof = n - p
    ms_res = ss_res / dof
    if weights is None:
        ybar = float(np.mean(y))
        dev = y - ybar
        ss_t = float(dev @ dev)
    else:
        ybar = float(np.sum(weights * y) / np.sum(weights))
        dev = y - ybar
        ss_t = float(np.sum(weights * dev * dev))
    cov = ms_res * cov_unscaled
    cov = 0.5 * (cov + cov.T)
    std_err = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    with np.errstate(divide="ignore", invalid="ignore"):
        t_val = coef / std_err
        r2 = 1.0 - ss_res / ss_t if ss_t > 0 else float("nan")
        r2_adj = 1.0 - (ss_res / dof) / (ss_t / (n - 1)) if ss_t > 0 else float("nan")
    sum_log_w = 0.0 if weights is None else float(np.sum(np.log(weights)))
    if ss_res > 0:
        loglik = -0.5 * n * (math.log(2.0 * math.pi * ss_res / n) + 1.0) + 0.5 * sum_log_w
    else:
        loglik = float("inf")
    return RegressionResult(
        names=list(names), coef_=coef, cov_=cov, std_error_=std_err, t_value_=t_val, residuals_=resid,
        fitted_=fitted, n=n, p=p, ss_res=ss_res, ms_res=ms_res, ss_t=ss_t, r2=float(r2), r2_adj=float(r2_adj),
        R=math.sqrt(r2) if r2 >= 0 else float("nan"), R_adj=math.sqrt(r2_adj) if r2_adj >= 0 else float("nan"),
        sigma_res=float(np.std(resid, ddof=1)), loglik=loglik, aic=-2.0 * loglik + 2.0 * p,
        bic=-2.0 * loglik + p * math.log(n), condition_number=condition_number,
        weights_=None if weights is None else weights.copy(),
    )


def fit_gls(X: np.ndarray, y: np.ndarray, names: Sequence[str], cov: np.ndarray,
            known_cov: bool = False) -> RegressionResult:
    """Generalised least squares for correlated errors with covariance ``cov`` (n, n).

    The problem is whitened with the Cholesky factor L of ``cov`` (cov = L L'), solved by
    :func:`fit_ols` on (L^-1 X, L^-1 y), so the coefficients are the efficient (BLUE)
    estimates and ``cov_ = s^2 (X' cov^-1 X)^-1`` with the data-based scale
    s^2 = ms_res of the whitened fit (about 1 when ``cov`` is right); with ``known_cov``
    ``cov`` is taken as the errors' absolute covariance and ``cov_ = (X' cov^-1 X)^-1``.

    The goodness-of-fit statistics (residuals_, fitted_, ss_res, ms_res, r2, R, sigma_res)
    describe the *unwhitened* residuals y - X b, so they compare with OLS fits; aic/bic and
    the rank test come from the whitened problem.
    """
    X, y, names, _ = _validate(X, y, names, None)
    cov = np.asarray(cov, dtype=np.float64)
    n = X.shape[0]
    if cov.shape != (n, n) or not np.all(np.isfinite(cov)):
        raise ValueError(f"cov must be a finite ({n}, {n}) matrix, got {cov.shape}")
    try:
        L = np.linalg.cholesky(0.5 * (cov + cov.T))
    except np.linalg.LinAlgError:
        raise ValueError("cov is not positive definite; check the noise model") from None
    Xw = scipy.linalg.solve_triangular(L, X, lower=True)
    yw = scipy.linalg.solve_triangular(L, y, lower=True)
    w = fit_ols(Xw, yw, names)
    if known_cov:
        cov_b = w.cov_ / w.ms_res
        se = np.sqrt(np.diag(cov_b))
        w = dataclasses.replace(w, cov_=cov_b, std_error_=se, t_value_=w.coef_ / se)
    fitted = X @ w.coef_
    resid = y - fitted
    ss_res = float(resid @ resid)
    dof = n - w.p
    dev = y - y.mean()
    ss_t = float(dev @ dev)
    r2 = 1.0 - ss_res / ss_t if ss_t > 0 else float("nan")
    r2_adj = 1.0 - (ss_res / dof) / (ss_t / (n - 1)) if ss_t > 0 else float("nan")
    return RegressionResult(
        names=list(names), coef_=w.coef_, cov_=w.cov_, std_error_=w.std_error_, t_value_=w.t_value_,
        residuals_=resid, fitted_=fitted, n=n, p=w.p, ss_res=ss_res, ms_res=ss_res / dof, ss_t=ss_t,
        r2=float(r2), r2_adj=float(r2_adj), R=math.sqrt(r2) if r2 >= 0 else float("nan"),
        R_adj=math.sqrt(r2_adj) if r2_adj >= 0 else float("nan"), sigma_res=float(np.std(resid, ddof=1)),
        loglik=w.loglik, aic=w.aic, bic=w.bic, condition_number=w.condition_number, weights_=None)
