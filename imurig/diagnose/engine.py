"""Honest selection of candidate effects that explain a residual (the mismatch engine).

Given an observable y (m,) and the nominal model's design X0 (m, p0), each candidate effect
contributes columns C(theta) (m, k) for every value theta of its scanned nonlinear
parameter (a change-point index, an exponent, a lag). For one candidate and theta the
partial F statistic of adding C(theta) to the current model is

    F = ((SS_0 - SS_1) / k) / (SS_1 / (m - p - k))

and a candidate's statistic is the largest over its scan. An effect is accepted only if

1. its statistic beats a **max-statistic threshold**: the (1 - alpha) critical value of the
   largest statistic over the *whole library and all scans*, simulated under the current model
   with the noise model (Gaussian, sigma from the current fit, or a caller's noise generator) --
   so scanning many effects and parameters does not inflate false discoveries. The critical
   value is the Monte Carlo test's (:func:`mc_threshold`): the k-th largest of n simulated
   maxima, k = floor(alpha (n + 1)), whose level is k / (n + 1) <= alpha exactly, where an
   interpolated sample quantile's is not (at n = 300, alpha = 0.01: 0.013); and
2. it improves the prediction of **held-out blocks** (blocked cross-validation: short
   contiguous blocks dealt round-robin to the folds), and lowers BIC.

Effects are added greedily until none passes. A runner-up whose statistic lies within 10 %
of the winner's is reported as indistinguishable from it rather than silently dropped.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from imurig.calibration.regression import RegressionResult, fit_ols
from imurig.diagnose.whiteness import residual_whiteness
from imurig.kernel.errors import UnidentifiableTermsError
from imurig.sensors.effects.base import Candidate  # noqa: F401  (the engine's candidates are the effect library's)


@dataclass
class Finding:
    name: str
    physics: str
    theta: object
    scan_name: str | None
    statistic: float
    threshold: float
    params: dict = field(default_factory=dict)       # name -> (estimate, std_error)
    variance_share: float = 0.0                      # fraction of the residual SS it explains
    cv_before: float = 0.0
    cv_after: float = 0.0
    bic_before: float = 0.0
    bic_after: float = 0.0
    runner_up: str | None = None
    rms_before: float | None = None                  # residual RMS before / after the effect joined the
    rms_after: float | None = None                   # model, in the engine's (possibly whitened) space
    whitened: bool = False
    std_error_model: str = "OLS"                     # what the parameters' standard errors assume

    def to_dict(self) -> dict:
        return {"effect": self.name, "physics": self.physics, "scan": None if self.scan_name is None else
                {self.scan_name: _jsonable(self.theta)}, "statistic": self.statistic, "threshold": self.threshold,
                "parameters": [{"name": k, "estimate": v[0], "std_error": v[1]} for k, v in self.params.items()],
                "variance_share": self.variance_share, "cv_rms_before": self.cv_before, "cv_rms_after": self.cv_after,
                "bic_before": self.bic_before, "bic_after": self.bic_after, "indistinguishable_from": self.runner_up,
                "rms_before": self.rms_before, "rms_after": self.rms_after,
                "rms_unit": "whitened" if self.whitened else "observable", "std_error_model": self.std_error_model}


def _jsonable(v):
    return v.item() if isinstance(v, np.generic) else v


def _fit(X, y, names):
    return fit_ols(X, y, names)


def mc_threshold(sims: np.ndarray, alpha: float) -> float:
    """The critical value of a Monte Carlo test (Barnard 1963; Davison & Hinkley 1997, 4.2.5):
    with n statistics simulated under the null, reject the observed one t when t exceeds the k-th
    largest of them, k = floor(alpha (n + 1)). t and the n simulations are exchangeable under the
    null, so t's rank among the n + 1 is uniform and the level is k / (n + 1) <= alpha, for any n
    (the p-value (1 + #{sim >= t}) / (n + 1) <= alpha is the same rule). An interpolated sample
    quantile of the simulations lies below that order statistic and gives a level above alpha
    (0.013 for alpha = 0.01 and n = 300). +inf (nothing rejected) when n is too small, k < 1."""
    s = np.sort(np.asarray(sims, float))
    k = int(np.floor(alpha * (s.size + 1) + 1e-9))
    return float(s[s.size - k]) if k >= 1 else float("inf")


class _Scanner:
    """Partial F statistics of every candidate (and scan value) against one current design X.

    With Q0 an orthonormal basis of X (m, p) and, per candidate and scan value, Qc an
    orthonormal basis of C projected off X (m, k), the sum of squares a candidate removes from
    a residual r (already orthogonal to X) is ||Qc^T r||^2, so one design's bases serve the
    observed residual and every simulated one. A candidate whose columns are (numerically)
    dependent on X or on each other gets -inf, as a rank-deficient fit would.
    """

    def __init__(self, X: np.ndarray, candidates):
        X = np.asarray(X, float)
        self.m, self.p = X.shape
        self.Q0, _ = np.linalg.qr(X)
        self.bases = []
        for c in candidates:
            per = []
            for th in c.scan:
                C = c.design(th)
                Cp = C - self.Q0 @ (self.Q0.T @ C)
                Qc, Rc = np.linalg.qr(Cp)
                d = np.abs(np.diag(Rc))
                ok = Cp.shape[1] <= self.m - self.p - 1 and np.all(d > 1e-9 * np.maximum(np.linalg.norm(C, axis=0), 1e-300))
                per.append((th, Qc if ok else None))
            self.bases.append(per)

    def residual(self, y: np.ndarray) -> np.ndarray:
        return y - self.Q0 @ (self.Q0.T @ y)

    def best(self, i: int, r: np.ndarray, ss0: float):
        """(F, theta) of candidate i for the residual r (orthogonal to X) with ss0 = r.r."""
        best = (-np.inf, None)
        for th, Qc in self.bases[i]:
            if Qc is None:
                continue
            k = Qc.shape[1]
            red = float(np.sum((Qc.T @ r) ** 2))
            ss1 = ss0 - red
            if not ss1 > 0:
                continue
            F = (red / k) / (ss1 / (self.m - self.p - k))
            if F > best[0]:
                best = (F, th)
        return best


def _scan_stats(y, X, ss0, cand: Candidate):
    """Best (F, theta) of one candidate over its scan."""
    sc = _Scanner(X, [cand])
    r = sc.residual(np.asarray(y, float))
    return sc.best(0, r, float(r @ r))


def _cv_rms(X, y, folds: int) -> float:
    """Blocked cross-validation: the record is cut into short contiguous blocks, dealt
    round-robin to ``folds`` folds, so every fold spans the whole record (an effect confined
    to one stretch, like a range change, is then seen when training); returns the RMS error
    of the held-out predictions."""
    m = y.size
    L = max(1, m // (4 * folds))
    fold = (np.arange(m) // L) % folds
    e = np.empty(m)
    for f in range(folds):
        test = fold == f
        coef, *_ = np.linalg.lstsq(X[~test], y[~test], rcond=None)
        e[test] = y[test] - X[test] @ coef
    return float(np.sqrt(np.mean(e**2)))


@dataclass
class Diagnosis:
    base_names: list
    findings: list
    before: RegressionResult
    after: RegressionResult
    unexplained: dict

    def to_dict(self) -> dict:
        def stats(r):
            return {"sigma_res": r.sigma_res, "r2_adj": r.r2_adj, "bic": r.bic, "n": r.n, "p": r.p}

        return {"nominal_terms": self.base_names, "findings": [f.to_dict() for f in self.findings],
                "fit_before": stats(self.before), "fit_after": stats(self.after), "unexplained": self.unexplained}


def select_effects(y: np.ndarray, X0: np.ndarray, names0: list[str], candidates: list[Candidate],
                   rng: np.random.Generator, alpha: float = 0.05, n_sim: int = 300, cv_blocks: int = 5,
                   max_effects: int = 4, noise: Callable[[np.random.Generator, int], np.ndarray] | None = None,
                   weights: np.ndarray | None = None, cov: np.ndarray | None = None) -> Diagnosis:
    """Greedy selection with a simulated max-statistic threshold (see module doc).

    ``noise(rng, m)`` draws one unit-variance noise vector of the residual's colour (default
    white); it is scaled by the current fit's residual sigma. ``weights`` (inverse variances,
    relative) whiten a heteroscedastic noise model first: y, X0 and every candidate's columns
    are multiplied by sqrt(weights), and all statistics are computed in that whitened space.
    ``cov`` (m, m), relative, does the same for correlated errors (whitening by its Cholesky factor).
    A ``noise`` with a ``covariance`` (m, m) leaves the estimates OLS but gives their standard
    errors from that covariance (:func:`_model_std_errors`).
    """
    y, X0, candidates = _whitened(y, X0, candidates, weights, cov)
    before = _fit(X0, y, list(names0))
    noise = noise or (lambda r, m: r.standard_normal(m))
    findings, X, names = _greedy(y, X0, list(names0), candidates, before, rng, alpha, n_sim, cv_blocks, max_effects,
                                 noise)
    for f in findings:
        f.whitened = weights is not None or cov is not None
    if len(findings) > 1:
        findings, X, names = _recheck_jointly(findings, y, X0, names0, candidates, rng, alpha, n_sim, noise)
    after = _fit(X, y, names)
    S = getattr(noise, "covariance", None)
    if S is not None and weights is None and cov is None and findings:
        # correlated errors (positions sharing a rounding error): OLS SEs would count them as independent
        se = dict(zip(names, _model_std_errors(X, y, S)))
        for f in findings:
            f.params = {c: (v[0], se[c]) for c, v in f.params.items()}
            f.std_error_model = "noise model's covariance"
    # what is left: is the remaining residual white and at the noise floor?
    lag1, white = residual_whiteness(after.residuals_)
    unexplained = {"sigma_res": after.sigma_res, "lag1_autocorrelation": lag1, "white": white}
    return Diagnosis(names0, findings, before, after, unexplained)


def _model_std_errors(X: np.ndarray, y: np.ndarray, S: np.ndarray) -> np.ndarray:
    """Standard errors of the OLS coefficients b = P y (P = X^+) when the errors' covariance is
    s^2 S (S known up to the scale, e.g. the position noise model's shared rounding errors):

        cov(b) = s^2 P S P^T,    s^2 = r^T r / tr(M S),    M = I - X P,

    s^2 unbiased since E(r^T r) = s^2 tr(M S). With S = I this is the OLS standard error."""
    X, y, S = np.asarray(X, float), np.asarray(y, float), np.asarray(S, float)
    P = np.linalg.pinv(X)
    r = y - X @ (P @ y)
    M = np.eye(y.size) - X @ P
    s2 = float(r @ r) / float(np.sum(M * S.T))
    return np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", P, S, P) * s2, 0.0))


def _whitened(y, X0, candidates, weights, cov):
    """(y, X0, candidates) in the space whitened by the Cholesky factor L of ``cov`` (L^-1 A) and
    then by sqrt(``weights``) (rows scaled), as :func:`select_effects` tests in."""
    if cov is not None:
        L = np.linalg.cholesky(0.5 * (cov + cov.T))
        wt = lambda A: scipy.linalg.solve_triangular(L, A, lower=True)
        candidates = [Candidate(c.name, c.physics, c.param_names,
                                (lambda th, f=c.columns: wt(np.asarray(f(th), float).reshape(L.shape[0], -1))),
                                c.scan, c.scan_name) for c in candidates]
        y, X0 = wt(np.asarray(y, float)), wt(np.asarray(X0, float))
    if weights is not None:
        sw = np.sqrt(np.asarray(weights, float))
        candidates = [Candidate(c.name, c.physics, c.param_names,
                                (lambda th, f=c.columns: sw[:, None] * np.asarray(f(th), float).reshape(sw.size, -1)),
                                c.scan, c.scan_name) for c in candidates]
        y, X0 = np.asarray(y, float) * sw, np.asarray(X0, float) * sw[:, None]
    return np.asarray(y, float), np.asarray(X0, float), candidates


def _greedy(y, X, names, candidates, before, rng, alpha, n_sim, cv_blocks, max_effects, noise):
    """Add the best candidate while it beats the simulated max-statistic threshold of the whole
    remaining library, improves blocked cross-validation and lowers BIC; (findings, X, names)."""
    findings: list[Finding] = []
    remaining = list(candidates)
    for _ in range(max_effects):
        cur = _fit(X, y, names)
        scanner = _Scanner(X, remaining)
        r0 = scanner.residual(y)
        ss0 = float(r0 @ r0)
        stats = [(c, *scanner.best(i, r0, ss0)) for i, c in enumerate(remaining)]
        stats = [s for s in stats if np.isfinite(s[1])]
        if not stats:
            break
        stats.sort(key=lambda s: -s[1])
        best_c, best_F, best_th = stats[0]
        # threshold: the max statistic over the whole remaining library, under the current model
        # (the fitted part lies in X's span, so only the simulated noise's residual matters)
        sim_max = np.empty(n_sim)
        sigma = cur.sigma_res
        for i in range(n_sim):
            rs = scanner.residual(sigma * noise(rng, y.size))
            ss0s = float(rs @ rs)
            sim_max[i] = max(scanner.best(j, rs, ss0s)[0] for j in range(len(remaining)))
        thr = mc_threshold(sim_max, alpha)
        if best_F <= thr:
            break
        C = best_c.design(best_th)
        cols = [f"{best_c.name}:{p}" for p in best_c.param_names][: C.shape[1]]
        X1 = np.column_stack([X, C])
        try:
            new = _fit(X1, y, names + cols)
        except UnidentifiableTermsError:
            remaining.remove(best_c)
            continue
        cv0, cv1 = _cv_rms(X, y, cv_blocks), _cv_rms(X1, y, cv_blocks)
        if not (cv1 < cv0 and new.bic < cur.bic):
            break
        runner = stats[1][0].name if len(stats) > 1 and stats[1][1] >= 0.9 * best_F else None
        findings.append(Finding(
            name=best_c.name, physics=best_c.physics, theta=best_th, scan_name=best_c.scan_name,
            statistic=float(best_F), threshold=thr,
            params={c: (new.coef(c), new.std_error(c)) for c in cols},
            variance_share=float((ss0 - new.ss_res) / before.ss_res) if before.ss_res > 0 else 0.0,
            cv_before=cv0, cv_after=cv1, bic_before=cur.bic, bic_after=new.bic, runner_up=runner,
            rms_before=float(np.sqrt(cur.ss_res / y.size)), rms_after=float(np.sqrt(new.ss_res / y.size))))
        X, names = X1, names + cols
        remaining.remove(best_c)
    return findings, X, names


def _recheck_jointly(findings, y, X0, names0, candidates, rng, alpha, n_sim, noise):
    """Interactions: re-optimise each accepted effect's scanned parameter given the others, then
    drop any effect that no longer beats, given the others, the max-statistic threshold it would
    face if it were the last one added: the (1 - alpha) critical value of the largest statistic
    over itself and every candidate not accepted (simulated under the model with the others). An
    effect that entered early by absorbing part of a later one's signal (a temperature drift,
    monotonic in time, takes most of a misalignment's column u_z on a table that runs theta by
    theta) must then stand against the whole library again, not against its own scan alone,
    which would let a candidate past the family-wise level; (findings, X, names)."""
    lookup = {c.name: c for c in candidates}
    for _ in range(2):
        for i, f in enumerate(findings):
            others = [lookup[g.name].design(g.theta) for j, g in enumerate(findings) if j != i]
            Xo = np.column_stack([X0, *others]) if others else X0
            F, th = _scan_stats(y, Xo, None, lookup[f.name])
            if np.isfinite(F):
                f.theta, f.statistic = th, float(F)
    kept = []
    accepted = {g.name for g in findings}
    rest = [c for c in candidates if c.name not in accepted]
    for i, f in enumerate(findings):
        others = [lookup[g.name].design(g.theta) for j, g in enumerate(findings) if j != i]
        Xo = np.column_stack([X0, *others]) if others else X0
        fit_o = _fit(Xo, y, [f"c{k}" for k in range(Xo.shape[1])])
        family = [lookup[f.name], *rest]
        sc_o = _Scanner(Xo, family)
        sims = np.empty(n_sim)
        for k in range(n_sim):
            rs = sc_o.residual(fit_o.sigma_res * noise(rng, y.size))
            ss = float(rs @ rs)
            sims[k] = max(sc_o.best(j, rs, ss)[0] for j in range(len(family)))
        f.threshold = mc_threshold(sims, alpha)
        if f.statistic > f.threshold:
            kept.append(f)
    findings = kept
    X, names = X0, list(names0)
    for f in findings:
        C = lookup[f.name].design(f.theta)
        X = np.column_stack([X, C])
        names += [f"{f.name}:{p}" for p in lookup[f.name].param_names][: C.shape[1]]
    final = _fit(X, y, names)
    for f in findings:
        f.params = {c: (final.coef(c), final.std_error(c)) for c in names if c.startswith(f.name + ":")}
    return findings, X, names


def wild_bootstrap_noise(y: np.ndarray, X: np.ndarray, weights: np.ndarray | None = None,
                         cov: np.ndarray | None = None,
                         clusters: np.ndarray | None = None) -> Callable[[np.random.Generator, int], np.ndarray]:
    """A ``noise`` generator for :func:`select_effects` that keeps each row's own residual size.

    The nominal fit's residuals, in the space whitened by ``weights`` / ``cov`` exactly as
    :func:`select_effects` whitens, are leverage-corrected, u_i = r_i / sqrt(1 - h_i), scaled to
    unit RMS, and multiplied by independent random signs (Rademacher wild bootstrap): draw =
    u * s, s_i = +-1. A max-statistic threshold simulated from it stays at its level when the
    noise model misses how the variance changes from row to row (the weights or covariance are
    estimated from few rows, a display resolution changes mid-series), at some cost in power
    where an effect inflates the residual. It does not keep correlation between rows, except
    within ``clusters`` (m,) labels: rows of one cluster (e.g. the readings of one table row by
    several gyros, which share the reference error) get one sign, applied to the residuals before
    the whitening, so that a correlation the covariance model misses is kept too.
    """
    y_, X_ = np.asarray(y, float), np.asarray(X, float)
    if cov is not None:
        L = np.linalg.cholesky(0.5 * (cov + cov.T))
        y_, X_ = scipy.linalg.solve_triangular(L, y_, lower=True), scipy.linalg.solve_triangular(L, X_, lower=True)
    if weights is not None:
        sw = np.sqrt(np.asarray(weights, float))
        y_, X_ = y_ * sw, X_ * sw[:, None]
    Q, _ = np.linalg.qr(X_)
    r = y_ - Q @ (Q.T @ y_)
    if clusters is not None:
        r0 = np.asarray(y, float) - np.asarray(X, float) @ np.linalg.lstsq(np.asarray(X, float), np.asarray(y, float),
                                                                           rcond=None)[0]
        _, inv = np.unique(np.asarray(clusters), return_inverse=True)
        scale = np.sqrt(np.mean(r**2))

        def draw(rng, m):
            e = r0 * rng.choice(np.array([-1.0, 1.0]), inv.max() + 1)[inv]
            if cov is not None:
                e = scipy.linalg.solve_triangular(L, e, lower=True)
            if weights is not None:
                e = e * sw
            return e / scale
        return draw
    u = r / np.sqrt(np.clip(1.0 - np.sum(Q**2, axis=1), 1e-6, None))
    u = u / np.sqrt(np.mean(u**2))
    return lambda rng, m: u * rng.choice(np.array([-1.0, 1.0]), m)


def ar1_covariance(y: np.ndarray, X: np.ndarray, max_phi: float = 0.9) -> np.ndarray:
    """A relative AR(1) covariance C_ij = phi^|i - j| for :func:`select_effects(cov=...)`, with phi
    the lag-1 correlation of the nominal fit's residuals (rows in time order), clipped to
    [0, ``max_phi``]. For series whose errors are correlated from one row to the next (the biases
    of successive temperature steps share the thermal lag): the statistics and the simulated
    threshold are then computed on whitened residuals. An effect that is slow in row order raises
    phi too, which costs power but not the level.
    """
    y_, X_ = np.asarray(y, float), np.asarray(X, float)
    r = y_ - X_ @ np.linalg.lstsq(X_, y_, rcond=None)[0]
    phi = float(np.clip(np.sum(r[1:] * r[:-1]) / max(float(r @ r), 1e-300), 0.0, max_phi))
    k = np.arange(y_.size)
    return phi ** np.abs(np.subtract.outer(k, k)).astype(float)
