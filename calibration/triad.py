"""Inverse-model calibration of a sensor triad (seed sections 4.1.5, 4.3.5, 4.4.4).

Indicated quantity u (SI, (m,3)) is the measured voltage over the nominal sensitivity,
u_i = V_i / s_nom,i. Each axis is fitted as the inverse model

    ref_i = sum_k beta_ik phi_k(u)        (seed Tables 4.4-4.6, eq. 4.39-4.41)

with phi_k a polynomial term library, by least squares on per-segment statistics (seed
C.1.1) or on all samples. The physical parameters of the forward model

    u = G (I + M) q + G b + G k2 (I + M) q ** 2 ...     (q: true quantity in the case frame)

follow from the linear part B and the constant c of the three inverse models:
K = B^-1 = G (I + M) / (1 + 2 k2 b), so scale G_i = K_ii (1 + 2 k2_i b_i), misalignment
M_ij = K_ij / K_ii, bias b = -(I + M) c - k2 b^2, nonlinearity
k2_i = -beta_i(u_i^2) K_ii^2 (1 + 2 k2_i b_i)^2 / [(I + M)^-1]_ii (first order in k2: the
inverse of u = G (q + b + k2 q^2) is q = u/G (1 + 2 k2 b) - k2 u^2/G^2 - b - k2 b^2),
with standard errors by the delta method from the joint covariance of the betas (which
includes the reference's own uncertainty when a reference Jacobian is given).

A triad is described by a :class:`TriadSpec` (channel names, input names, units);
:mod:`imurig.calibration.accelerometer` and :mod:`imurig.calibration.gyro` define theirs.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Callable, ClassVar

import numpy as np
import scipy.linalg

from imurig.calibration.preprocess import segment_samples, segment_statistic, segment_statistic_variance
from imurig.calibration.regression import fit_gls, fit_ols
from imurig.calibration.stepwise import backward_elimination, forward_selection
from imurig.calibration.terms import TermLibrary, polynomial
from imurig.kernel.errors import RecordingError
from imurig.kernel.recording import Recording


@dataclass(frozen=True)
class TriadSpec:
    """What distinguishes one triad from another for the calibration."""

    kind: str                       # "accelerometer", "gyro"
    axes: tuple[str, ...]           # ("x", "y", "z") or ("p", "q", "r")
    channels: tuple[str, ...]       # volt channels, e.g. ("acc_x", "acc_y", "acc_z")
    inputs: tuple[str, ...]         # term-library input names, e.g. ("ax", "ay", "az")
    sensitivity_key: str            # recording metadata: nominal volts per SI unit, per axis
    quantity_unit: str              # "m/s^2", "rad/s"
    cal_prefix: str                 # calibrated channel prefix, e.g. "acc_cal_"
    models: dict[str, Callable[[str], TermLibrary]] = field(default_factory=dict)
    sensitivity_hint: str = ""

    @property
    def json_kind(self) -> str:
        return f"imurig.{self.kind}_inverse_model"

    def linear(self) -> TermLibrary:
        return TermLibrary.from_names(["1", *self.inputs])

    def physical(self, axis: str) -> TermLibrary:
        """Linear in all three inputs plus the axis' own square."""
        return TermLibrary.from_names(["1", *self.inputs, f"{self.inputs[self.axes.index(axis)]}^2"])


def indicated(rec: Recording, spec: TriadSpec, statistic: str = "median", sensitivity=None):
    """Indicated quantity u (SI) per segment (statistic='median'/'mean') or per sample ('raw').

    Returns (u (m,3), segment index (m,)).
    """
    rec.require({c: "V" for c in spec.channels})
    s = sensitivity if sensitivity is not None else rec.meta.get(spec.sensitivity_key)
    if s is None:
        raise RecordingError(f"the recording has no '{spec.sensitivity_key}' metadata (volts per "
                             f"{spec.quantity_unit} of each {spec.kind}{spec.sensitivity_hint}); add it as "
                             f"'# {spec.sensitivity_key}: [s_1, s_2, s_3]' or pass it")
    s = np.broadcast_to(np.asarray(s, float), (3,))
    if statistic == "raw":
        v, seg = segment_samples(rec, spec.channels)
    else:
        v = segment_statistic(rec, spec.channels, statistic)
        seg = np.arange(v.shape[0])
    return v / s, seg


@dataclass
class TriadCalibration:
    """Inverse-model calibration of a sensor triad (sklearn-like: settings in __init__,
    ``fit`` returns self, fitted attributes end in ``_``). Subclasses set ``SPEC``.

    model: 'linear', 'cross', 'seed_final', 'physical', 'stepwise' (forward selection from the linear
    model over the degree-2 library), 'backward' (backward elimination), or {axis: TermLibrary}.
    statistic: 'median' (per position, seed), 'mean', or 'raw' (every sample in the windows).
    """

    SPEC: ClassVar[TriadSpec]

    model: str | dict = "physical"
    statistic: str = "median"
    stepwise_criterion: str = "bic"
    stepwise_library_degree: int = 2
    results_: dict = field(default_factory=dict, init=False)
    selection_: dict = field(default_factory=dict, init=False)
    sensitivity_: np.ndarray | None = field(default=None, init=False)
    reference_cov_: np.ndarray | None = field(default=None, init=False)

    def __post_init__(self):
        self.loaded_ = None
        self.projection_: dict = {}       # axis -> (p_a, n) matrix P_a with beta_a = P_a y_a
        self.cross_cov_ = None            # cross-axis blocks of the betas' covariance (segment_cov)

    def _library(self, axis: str) -> TermLibrary:
        if isinstance(self.model, dict):
            lib = self.model[axis]
            return lib if isinstance(lib, TermLibrary) else TermLibrary.from_names(lib)
        models = self.SPEC.models
        if self.model not in models:
            raise ValueError(f"unknown model {self.model!r}; choose from {sorted(models) + ['stepwise', 'backward']}")
        return models[self.model](axis)

    def fit(self, rec: Recording, reference: np.ndarray, reference_jacobian: np.ndarray | None = None,
            reference_sigma: np.ndarray | None = None, response_cov: np.ndarray | None = None,
            segment_cov: np.ndarray | None = None) -> "TriadCalibration":
        """Fit the three inverse models.

        reference : (n_seg, 3) reference quantity per segment, in SI (e.g. m/s^2 or rad/s, in C).
        reference_jacobian : optional (n_seg, 3, q) d reference / d survey parameters, and
        reference_sigma (q,) their 1-sigma uncertainty; adds the reference's uncertainty
        to the coefficient covariance (beta = P f_ref is linear in f_ref).
        response_cov : optional (n_seg, n_seg) covariance of the per-segment errors (e.g. a
        gyro's correlated bias instability plus white noise); the fit is then generalised
        least squares (:func:`imurig.calibration.regression.fit_gls`), for fixed models only.
        segment_cov : optional (n_seg, 3, 3) covariance of each segment's reference error across
        the three axes, independent between segments (e.g. the tilt table's angle-setting
        error, :func:`imurig.rigs.tilt_table.setting_error_covariance`). The reference error of
        axis a then has the known covariance

            K_a = diag(Sigma_k,aa) + J_a diag(sigma^2) J_a'      (setting + survey)  [(n, n)]

        and axis a is fitted by generalised least squares with V_a = K_a + (w_a + s_a^2) I:
        w_a the noise of a segment's statistic from the samples inside the windows (batch means,
        pooled over segments), s_a^2 >= 0 any further white part (drift between segments, model
        misfit) estimated by REML. (REML alone is too noisy where K_a dominates: an s^2 drawn low
        puts too much weight on the few segments the setting error does not reach.) The coefficients'
        covariance is then absolute, (X' V_a^-1 X)^-1, with cross-axis blocks
        P_a (diag(Sigma_k,ab) + J_a diag(sigma^2) J_b') P_b' (P_a the GLS projection).
        The three axes are then refitted jointly with the full (3n, 3n) covariance (seemingly
        unrelated regressions, :meth:`_fit_jointly`): the setting and survey errors reach all
        axes at once, and using that puts the estimator on the Cramér-Rao bound (Monte-Carlo:
        RMS/CRLB 0.96-1.22 with the window mean, x sqrt(pi/2) with the median).
        Fixed models and per-segment statistics only. Without it, ordinary least squares
        with the survey's covariance added (which counts the survey twice where it also
        inflates the residual).
        """
        spec = self.SPEC
        s = rec.meta.get(spec.sensitivity_key)
        self.sensitivity_ = None if s is None else np.broadcast_to(np.asarray(s, float), (3,)).copy()
        u, seg = indicated(rec, spec, self.statistic)
        reference = np.asarray(reference, float)
        if reference.shape != (rec.n_segments, 3):
            raise ValueError(f"reference must be (n_segments, 3) = ({rec.n_segments}, 3), got {reference.shape}")
        y_all = reference[seg]
        inputs = {n: u[:, j] for j, n in enumerate(spec.inputs)}
        linear = ("1",) + spec.inputs
        survey = None
        if reference_jacobian is not None and reference_sigma is not None:
            survey = np.asarray(reference_jacobian, float)[seg] * np.asarray(reference_sigma, float)  # (n, 3, q)
        if segment_cov is not None:
            segment_cov = np.asarray(segment_cov, float)
            if segment_cov.shape != (rec.n_segments, 3, 3) or not np.isfinite(segment_cov).all():
                raise ValueError(f"segment_cov must be a finite (n_segments, 3, 3) = ({rec.n_segments}, 3, 3) "
                                 f"array, got {segment_cov.shape}")
            if self.model in ("stepwise", "backward") or self.statistic == "raw" or response_cov is not None:
                raise ValueError("segment_cov needs a fixed model, per-segment statistics and no response_cov")
            segment_cov = segment_cov[seg]
            sens = np.broadcast_to(np.asarray(rec.meta[spec.sensitivity_key], float), (3,))
            within = np.nanmean(segment_statistic_variance(rec, spec.channels, self.statistic), axis=0) / sens**2
            within = np.nan_to_num(within)
        self.results_, self.selection_, self.projection_ = {}, {}, {}
        white = np.zeros(3)
        for j, a in enumerate(spec.axes):
            if self.model in ("stepwise", "backward"):
                lib = polynomial(spec.inputs, self.stepwise_library_degree)
                if self.model == "stepwise":
                    sel = forward_selection(lib, inputs, y_all[:, j], start=linear,
                                            criterion=self.stepwise_criterion)
                else:
                    sel = backward_elimination(lib, inputs, y_all[:, j], keep=linear,
                                               criterion=self.stepwise_criterion)
                self.selection_[a] = sel
                self.results_[a] = sel.result
                self.projection_[a] = np.linalg.pinv(TermLibrary.from_names(sel.result.names).design(inputs))
                continue
            lib = self._library(a)
            X = lib.design(inputs)
            if response_cov is not None:
                V = response_cov
            elif segment_cov is not None:
                K = _reference_error_cov(segment_cov, survey, j, j) + within[j] * np.eye(len(y_all))
                V = K + white_variance_reml(X, y_all[:, j], K) * np.eye(len(K))
            else:
                self.results_[a] = fit_ols(X, y_all[:, j], lib.names)
                self.projection_[a] = np.linalg.pinv(X)
                continue
            self.results_[a] = fit_gls(X, y_all[:, j], lib.names, V, known_cov=segment_cov is not None)
            self.projection_[a] = _gls_projection(X, V)
            white[j] = V[0, 0] - K[0, 0] + within[j] if segment_cov is not None else 0.0
        self.cross_cov_ = self.reference_cov_ = None
        if segment_cov is not None:
            self._fit_jointly(inputs, y_all, segment_cov, survey, white)
        elif survey is not None:
            S = np.concatenate([self.projection_[a] @ survey[:, j, :] for j, a in enumerate(spec.axes)])
            self.reference_cov_ = S @ S.T
        return self

    def _fit_jointly(self, inputs, y_all, segment_cov, survey, white) -> None:
        """Refit the three axes as one generalised least-squares problem (seemingly unrelated
        regressions): a position's setting error and the survey errors reach all three axes at
        once, so the other axes' readings tell each axis how far its reference is off.

            y = blockdiag(X_x, X_y, X_z) beta + e,  cov(e)_(a,b) = K_ab + delta_ab w_a I   [(3n, 3n)]

        with w_a the white part found by the per-axis fit. beta = (X' V^-1 X)^-1 X' V^-1 y; its
        covariance (X' V^-1 X)^-1 holds the cross-axis blocks (``cross_cov_``).
        """
        axes = self.SPEC.axes
        n = y_all.shape[0]
        Xs = [TermLibrary.from_names(self.results_[a].names).design(inputs) for a in axes]
        off = np.concatenate([[0], np.cumsum([X.shape[1] for X in Xs])])
        V = np.zeros((3 * n, 3 * n))
        Xf = np.zeros((3 * n, off[-1]))
        for i in range(3):
            Xf[i * n:(i + 1) * n, off[i]:off[i + 1]] = Xs[i]
            for j in range(3):
                V[i * n:(i + 1) * n, j * n:(j + 1) * n] = (_reference_error_cov(segment_cov, survey, i, j)
                                                           + (white[i] * np.eye(n) if i == j else 0.0))
        L = np.linalg.cholesky(V)
        Xw = scipy.linalg.solve_triangular(L, Xf, lower=True)
        yw = scipy.linalg.solve_triangular(L, y_all.T.reshape(-1), lower=True)
        Q, R = np.linalg.qr(Xw)
        beta = scipy.linalg.solve_triangular(R, Q.T @ yw)
        Rinv = scipy.linalg.solve_triangular(R, np.eye(R.shape[0]))
        cov = Rinv @ Rinv.T
        self.cross_cov_ = cov.copy()
        for i, a in enumerate(axes):
            sl = slice(off[i], off[i + 1])
            self.cross_cov_[sl, sl] = 0.0  # the diagonal blocks live in results_
            self.results_[a] = _with_coefficients(self.results_[a], Xs[i], y_all[:, i], beta[sl], cov[sl, sl])

    # ------------------------------------------------------------ results
    def coefficient_vector(self):
        axes = self.SPEC.axes
        names = [(a, n) for a in axes for n in self.results_[a].names]
        beta = np.concatenate([self.results_[a].coef_ for a in axes])
        cov = np.zeros((beta.size, beta.size))
        i = 0
        for a in axes:
            p = self.results_[a].p
            cov[i:i + p, i:i + p] = self.results_[a].cov_
            i += p
        if self.reference_cov_ is not None:
            cov = cov + self.reference_cov_
        if self.cross_cov_ is not None:
            cov = cov + self.cross_cov_
        return names, beta, cov

    def physical_parameters(self) -> list[dict]:
        """Forward-model parameters with delta-method standard errors (see module doc)."""
        spec = self.SPEC
        axes, inp = spec.axes, spec.inputs
        names, beta, cov = self.coefficient_vector()
        index = {k: i for i, k in enumerate(names)}
        for a in axes:
            for t in ("1",) + inp:
                if (a, t) not in index:
                    raise ValueError(f"model for axis {a} lacks term '{t}'; physical parameters need the full "
                                     "linear part")
        sens = self.sensitivity_ if self.sensitivity_ is not None else np.ones(3)

        def h(b):
            B = np.array([[b[index[(a, c)]] for c in inp] for a in axes])
            c0 = np.array([b[index[(a, "1")]] for a in axes])
            K = np.linalg.inv(B)
            G = np.diag(K).copy()
            M = K / G[:, None]
            Minv = np.linalg.inv(M)
            bias = -(M @ c0)
            k2 = np.array([-b[index[(a, f"{inp[i]}^2")]] * G[i] ** 2 / Minv[i, i]
                           if (a, f"{inp[i]}^2") in index else np.nan for i, a in enumerate(axes)])
            # the inverse of u = G (q + b + k2 q^2) has slope (1 + 2 k2 b) / G and constant -(b + k2 b^2)
            # (first order in k2): without this the bias leaks 2 k2 b into the scale factor
            corr = np.where(np.isfinite(k2), 1 + 2 * np.nan_to_num(k2) * bias, 1.0)
            bias = bias - np.nan_to_num(k2) * bias ** 2
            out = list(G * corr * sens)
            out += [M[i, j] for i in range(3) for j in range(3) if i != j]
            out += list(bias)
            out += list(k2 * corr ** 2)
            return np.array(out)

        q = spec.quantity_unit
        labels = ([(f"sensitivity_{a}", f"V/({q})") for a in axes]
                  + [(f"misalignment_{axes[i]}{axes[j]}", "rad") for i in range(3) for j in range(3) if i != j]
                  + [(f"bias_{a}", q) for a in axes]
                  + [(f"nonlinearity_{a}", f"1/({q})") for a in axes])
        est = h(beta)
        se = np.sqrt(np.clip(np.diag(delta_cov(h, beta, cov)), 0, None))
        return [{"name": n, "unit": u, "estimate": float(e), "std_error": float(s)}
                for (n, u), e, s in zip(labels, est, se) if np.isfinite(e)]

    def models(self) -> dict:
        """{axis: (term names, coefficients)} of the fitted (or loaded) inverse models."""
        if self.results_:
            return {a: (list(r.names), np.asarray(r.coef_)) for a, r in self.results_.items()}
        if getattr(self, "loaded_", None):
            return self.loaded_
        raise ValueError("the calibration is not fitted; call fit() or load one with from_dict()")

    def predict(self, u: np.ndarray) -> np.ndarray:
        """Calibrated quantity (m,3) for indicated quantity u (m,3), SI."""
        inputs = {n: u[:, j] for j, n in enumerate(self.SPEC.inputs)}
        return np.stack([TermLibrary.from_names(names).design(inputs) @ coef
                         for names, coef in (self.models()[a] for a in self.SPEC.axes)], axis=1)

    def to_dict(self) -> dict:
        """What is needed to apply the calibration elsewhere (JSON-ready)."""
        spec = self.SPEC
        return {"kind": spec.json_kind, "version": 1, "model": str(self.model),
                "statistic": self.statistic,
                "nominal_sensitivity": None if self.sensitivity_ is None else self.sensitivity_.tolist(),
                "nominal_sensitivity_unit": f"V/({spec.quantity_unit})",
                "equation": f"ref_i [{spec.quantity_unit}] = sum_k coef_ik * term_k(u), u = volts / "
                            "nominal_sensitivity",
                "axes": {a: {"terms": n, "coef": c.tolist()} for a, (n, c) in self.models().items()}}

    @classmethod
    def from_dict(cls, d: dict) -> "TriadCalibration":
        kind = cls.SPEC.json_kind
        if d.get("kind") != kind:
            raise ValueError(f"not an imurig {cls.SPEC.kind} calibration (kind must be '{kind}', got "
                             f"{d.get('kind')!r}); use the calibration.json of a report folder")
        cal = cls(model=d.get("model", "loaded"), statistic=d.get("statistic", "median"))
        s = d.get("nominal_sensitivity")
        cal.sensitivity_ = None if s is None else np.asarray(s, float)
        cal.loaded_ = {a: (list(v["terms"]), np.asarray(v["coef"], float)) for a, v in d["axes"].items()}
        return cal

    def apply(self, rec: Recording) -> Recording:
        """Add calibrated channels ``<prefix><axis>`` (SI) to a copy of ``rec``."""
        spec = self.SPEC
        rec.require({c: "V" for c in spec.channels})
        s = self.sensitivity_ if self.sensitivity_ is not None else rec.meta.get(spec.sensitivity_key)
        if s is None:
            raise RecordingError("no nominal sensitivity in the calibration or the recording's metadata")
        u = rec.stack(spec.channels) / np.asarray(s, float)
        f = self.predict(u)
        channels, units = dict(rec.channels), dict(rec.units)
        for j, a in enumerate(spec.axes):
            channels[f"{spec.cal_prefix}{a}"] = f[:, j]
            units[f"{spec.cal_prefix}{a}"] = spec.quantity_unit
        return rec.replace(channels=channels, units=units)

    def table(self) -> dict:
        """Seed-style table: coefficients per axis and sigma_res, MS_res, R, R_adj."""
        return {a: self.results_[a].to_dict() for a in self.SPEC.axes}


def _with_coefficients(res, X: np.ndarray, y: np.ndarray, coef: np.ndarray, cov: np.ndarray):
    """``res`` with new coefficients and covariance, its residual statistics recomputed (the
    unweighted ones, as :func:`fit_gls` reports them)."""
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


def _gls_projection(X: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """P = (X' C^-1 X)^-1 X' C^-1 (p, n) for C (n, n): the GLS estimate is beta = P y."""
    CiX = np.linalg.solve(cov, X)
    return np.linalg.solve(X.T @ CiX, CiX.T)


def _reference_error_cov(segment_cov: np.ndarray, survey: np.ndarray | None, i: int, j: int) -> np.ndarray:
    """Covariance (n, n) between the reference errors of axes i and j: the segments' own
    (diagonal, segment_cov[:, i, j]) plus the survey's, J_i diag(sigma^2) J_j' (survey = J sigma)."""
    K = np.diag(segment_cov[:, i, j])
    return K if survey is None else K + survey[:, i, :] @ survey[:, j, :].T


def white_variance_reml(X: np.ndarray, y: np.ndarray, K: np.ndarray) -> float:
    """REML estimate of s^2 in y = X b + e, cov(e) = K + s^2 I, K (n, n) known.

    Minimises  1/2 [log det V + log det(X' V^-1 X) + r' V^-1 r],  V = K + s^2 I, r the GLS
    residual, over log s^2 (bounded scalar search between 1e-12 and 1 times 10 x the data's
    OLS residual variance). One eigendecomposition K = U diag(lam) U' makes each evaluation
    O(n p^2): V^-1 = U diag(1 / (lam + s^2)) U'.
    """
    import scipy.optimize

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

    lo, hi = np.log(top * 1e-12), np.log(top)
    res = scipy.optimize.minimize_scalar(nll, bounds=(lo, hi), method="bounded", options={"xatol": 1e-3})
    return float(np.exp(res.x))


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




def forward_parameters(axes, sensitivity, bias, k2, misalignment) -> dict:
    """Forward-model parameters named as :meth:`TriadCalibration.physical_parameters` names them
    (sensitivity_<a>, bias_<a>, nonlinearity_<a>, misalignment_<a><b>), from injected values."""
    M = np.asarray(misalignment, float)
    out = {}
    for i, a in enumerate(axes):
        out[f"sensitivity_{a}"] = sensitivity[i]
        out[f"bias_{a}"] = bias[i]
        out[f"nonlinearity_{a}"] = k2[i]
        for j, c in enumerate(axes):
            if i != j:
                out[f"misalignment_{a}{c}"] = M[i, j]
    return out
