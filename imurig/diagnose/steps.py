"""The fit step by step: the nominal model, then each accepted effect in turn (for the report).

The selection engine (:func:`imurig.diagnose.engine.select_effects`) returns the accepted effects;
:func:`effect_steps` refits the observable y (m,) on the nominal design X0 (m, p0) and then on
[X0, C_1(theta_1), ..., C_k(theta_k)], each effect's columns at its final scan value, in the
engine's whitened space, so that every step's statistics are the engine's.
"""
from __future__ import annotations

import numpy as np
import scipy.linalg

from imurig.calibration.regression import fit_ols


def effect_steps(y: np.ndarray, X0: np.ndarray, names0: list, candidates: list, diag, cov: np.ndarray | None = None,
                 weights: np.ndarray | None = None) -> dict:
    """The fit before and after each accepted effect, for the report.

    Rebuilds the engine's final model (:func:`imurig.diagnose.engine.select_effects`) step by
    step: the nominal design X0 (m, p0), then each accepted effect's columns C_k(theta_k) in the
    order accepted, each at its final scan value. Every fit is made in the space the engine
    tests in (whitened by the Cholesky factor of ``cov`` and by sqrt(``weights``), as the engine
    does), so sigma_res, R^2adj, BIC and AIC are the engine's. Per step: those statistics, the
    residual RMS in the observable's own units (unwhitened, y - X b), the sequential share of
    the nominal residual SS the effect removes, (SS_{k-1} - SS_k) / SS_0 (the shares sum to
    1 - SS_after / SS_0), and its unique share in the final model, (SS_without_k - SS_final) / SS_0.

    Returns {"steps": [...], "resid_before": (m,), "resid_after": (m,) unwhitened,
    "columns": {effect: C_k (m, k)}, "coef": {term: estimate} of the final fit}.
    """
    y = np.asarray(y, float)
    L = np.linalg.cholesky(0.5 * (cov + cov.T)) if cov is not None else None
    sw = np.sqrt(np.asarray(weights, float)) if weights is not None else None

    def W(A):
        A = np.asarray(A, float)
        if L is not None:
            A = scipy.linalg.solve_triangular(L, A, lower=True)
        if sw is not None:
            A = A * (sw if A.ndim == 1 else sw[:, None])
        return A

    lookup = {c.name: c for c in candidates}
    yw = W(y)
    X, names = np.asarray(X0, float), list(names0)
    blocks, cols = [X], {}
    for f in diag.findings:
        C = lookup[f.name].design(f.theta)
        cols[f.name] = C
        blocks.append(C)
        names += [f"{f.name}:{p}" for p in lookup[f.name].param_names][: C.shape[1]]
    fits, designs = [], []
    for k in range(len(blocks)):
        Xk = np.column_stack(blocks[:k + 1])
        fits.append(fit_ols(W(Xk), yw, names[:Xk.shape[1]]))
        designs.append(Xk)
    ss0, ssf = fits[0].ss_res, fits[-1].ss_res
    steps = []
    for k, (fr, Xk) in enumerate(zip(fits, designs)):
        r = y - Xk @ fr.coef_
        st = {"after_effect": None if k == 0 else diag.findings[k - 1].name, "sigma_res": fr.sigma_res,
              "r2_adj": fr.r2_adj, "bic": fr.bic, "aic": fr.aic, "n": fr.n, "p": fr.p, "ss_res": fr.ss_res,
              "residual_rms": float(np.sqrt(np.mean(r**2))),
              "variance_share": 0.0 if k == 0 else float((fits[k - 1].ss_res - fr.ss_res) / ss0)}
        if k:
            keep = [b for i, b in enumerate(blocks) if i != k]
            Xo = np.column_stack(keep)
            ro = W(y) - W(Xo) @ np.linalg.lstsq(W(Xo), yw, rcond=None)[0]
            st["unique_variance_share"] = float((ro @ ro - ssf) / ss0)
        steps.append(st)
    return {"steps": steps, "resid_before": y - designs[0] @ fits[0].coef_,
            "resid_after": y - designs[-1] @ fits[-1].coef_, "columns": cols,
            "coef": dict(zip(fits[-1].names, map(float, fits[-1].coef_)))}
