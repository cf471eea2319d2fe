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

from dataclasses import dataclass, field
from typing import Callable, ClassVar, Self

import numpy as np

from imurig.calibration.gls import delta_cov, fit_jointly, gls_projection, reference_error_cov, white_variance_reml
from imurig.calibration.preprocess import segment_samples, segment_statistic, segment_statistic_covariance
from imurig.calibration.regression import fit_gls, fit_ols
from imurig.calibration.stepwise import backward_elimination, forward_selection
from imurig.calibration.sensitivity import nominal_sensitivity
from imurig.calibration.terms import TermLibrary, polynomial
from imurig.calibration.triad_file import read_triad_dict, triad_dict, unit_word
from imurig.kernel.errors import NotFittedError, RecordingError, UnidentifiableTermsError
from imurig.kernel.estimator import Estimator
from imurig.kernel.recording import Recording

#: significance level of the REML extra white variance (:func:`imurig.calibration.gls.white_variance_reml`)
WHITE_LEVEL = 0.01


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
    """Indicated quantity u = x / s_nom (SI) per segment (statistic='median'/'mean') or per sample ('raw'),
    with s_nom from :func:`nominal_sensitivity` (volts, counts or SI channels) unless given.

    Returns (u (m,3), segment index (m,)).
    """
    s_meta, _ = nominal_sensitivity(rec, spec)
    s = np.broadcast_to(np.asarray(sensitivity if sensitivity is not None else s_meta, float), (3,))
    if statistic == "raw":
        v, seg = segment_samples(rec, spec.channels)
    else:
        v = segment_statistic(rec, spec.channels, statistic)
        seg = np.arange(v.shape[0])
    return v / s, seg


class TriadCalibration(Estimator):
    """Inverse-model calibration of a sensor triad (the bench's estimator contract: settings in
    ``__init__``, ``fit`` returns self, fitted attributes end in ``_``). Subclasses set ``SPEC``.

    model: 'linear', 'cross', 'seed_final', 'physical', 'stepwise' (forward selection from the linear
    model over the degree-2 library), 'backward' (backward elimination), or {axis: TermLibrary}.
    statistic: 'median' (per position, seed), 'mean', or 'raw' (every sample in the windows).

    Fitted: ``results_`` {axis: RegressionResult}; ``models_`` {axis: (term names, coefficients)}
    (also set by :meth:`from_dict`); ``selection_`` {axis: stepwise selection} (stepwise models);
    ``projection_`` {axis: (p_a, n) matrix P_a with beta_a = P_a y_a}; ``cross_cov_`` the cross-axis
    blocks of the coefficients' covariance (with ``segment_cov``) or None; ``reference_cov_`` the
    coefficients' covariance from the survey (with a reference Jacobian, without ``segment_cov``) or
    None; ``sensitivity_`` (3,) the nominal sensitivity used (V per SI unit).
    """

    SPEC: ClassVar[TriadSpec]

    def __init__(self, model: str | dict = "physical", statistic: str = "median", stepwise_criterion: str = "bic",
                 stepwise_library_degree: int = 2):
        self.model = model
        self.statistic = statistic
        self.stepwise_criterion = stepwise_criterion
        self.stepwise_library_degree = stepwise_library_degree

    def _library(self, axis: str) -> TermLibrary:
        if isinstance(self.model, dict):
            lib = self.model[axis]
            return lib if isinstance(lib, TermLibrary) else TermLibrary.from_names(lib)
        models = self.SPEC.models
        if self.model not in models:
            raise ValueError(f"unknown model {self.model!r}; choose from {sorted(models) + ['stepwise', 'backward']}")
        return models[self.model](axis)

    def fit(self, rec: Recording, reference: np.ndarray | None = None, reference_jacobian: np.ndarray | None = None,
            reference_sigma: np.ndarray | None = None, response_cov: np.ndarray | None = None,
            segment_cov: np.ndarray | None = None) -> Self:
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
        misfit) by REML, kept where significant (LR test at ``WHITE_LEVEL``; a free s^2 is positive
        in half of the data sets without any, and cost the Monte-Carlo ~10-18 % on the standard
        errors). (REML alone is too noisy where K_a dominates.) The coefficients' covariance is
        then absolute, (X' V_a^-1 X)^-1, with cross-axis blocks P_a (diag(Sigma_k,ab) + J_a
        diag(sigma^2) J_b') P_b' (P_a the GLS projection). The three axes are then refitted jointly
        with the full (3n, 3n) covariance (seemingly unrelated regressions,
        :func:`imurig.calibration.gls.fit_jointly`): the setting and survey errors reach all axes at
        once, and so does the window noise the channels share (the converter's common mode, batch
        means across axes). Monte-Carlo, 100 runs: RMS/CRLB median 1.03 with the Huber M-estimate,
        1.29 with the median (its sqrt(pi/2) on the window noise), RMS/SE 1.00.
        Fixed models and per-segment statistics only. Without it, ordinary least squares
        with the survey's covariance added (which counts the survey twice where it also
        inflates the residual).
        """
        self._clear_fitted()
        spec = self.SPEC
        if reference is None:
            raise ValueError(f"{type(self).__name__}.fit needs the reference quantity per segment (n_segments, 3)")
        self.sensitivity_, self.channel_unit_ = nominal_sensitivity(rec, spec)
        u, seg = indicated(rec, spec, self.statistic)
        reference = np.asarray(reference, float)
        if reference.shape != (rec.n_segments, 3):
            raise ValueError(f"reference must be (n_segments, 3) = ({rec.n_segments}, 3), got {reference.shape}")
        y_all = reference[seg]
        inputs = {n: u[:, j] for j, n in enumerate(spec.inputs)}
        survey = None
        if reference_jacobian is not None and reference_sigma is not None:
            survey = np.asarray(reference_jacobian, float)[seg] * np.asarray(reference_sigma, float)  # (n, 3, q)
        within = None
        if segment_cov is not None:
            segment_cov, within = self._segment_cov(rec, segment_cov, seg, response_cov)
        results, selection, projection, white = {}, {}, {}, np.zeros(3)
        for j, a in enumerate(spec.axes):
            results[a], projection[a], sel, white[j] = self._fit_axis(a, j, inputs, y_all[:, j], response_cov,
                                                                      segment_cov, survey, within)
            if sel is not None:
                selection[a] = sel
        cross_cov = reference_cov = None
        if segment_cov is not None:
            # each axis' own white part (window noise + REML extra) on the diagonal, the shared window noise off it
            white = within - np.diag(np.diag(within)) + np.diag(white)
            results, cross_cov = fit_jointly(results, spec.axes, inputs, y_all, segment_cov, survey, white)
        elif survey is not None:
            S = np.concatenate([projection[a] @ survey[:, j, :] for j, a in enumerate(spec.axes)])
            reference_cov = S @ S.T
        self.results_, self.selection_, self.projection_ = results, selection, projection
        self.cross_cov_, self.reference_cov_ = cross_cov, reference_cov
        self.models_ = {a: (list(r.names), np.asarray(r.coef_)) for a, r in results.items()}
        return self

    def _segment_cov(self, rec: Recording, segment_cov, seg: np.ndarray, response_cov):
        """The per-sample reference-error covariance (n, 3, 3) and the within-window noise covariance
        (3, 3) of a segment's statistic across the three axes (batch means pooled over segments, SI^2)."""
        spec = self.SPEC
        segment_cov = np.asarray(segment_cov, float)
        if segment_cov.shape != (rec.n_segments, 3, 3) or not np.isfinite(segment_cov).all():
            raise ValueError(f"segment_cov must be a finite (n_segments, 3, 3) = ({rec.n_segments}, 3, 3) "
                             f"array, got {segment_cov.shape}")
        if self.model in ("stepwise", "backward") or self.statistic == "raw" or response_cov is not None:
            raise ValueError("segment_cov needs a fixed model, per-segment statistics and no response_cov")
        sens = nominal_sensitivity(rec, spec)[0]
        within = np.nanmean(segment_statistic_covariance(rec, spec.channels, self.statistic), axis=0)
        return segment_cov[seg], np.nan_to_num(within / np.outer(sens, sens))

    def _fit_axis(self, a: str, j: int, inputs: dict, y: np.ndarray, response_cov, segment_cov, survey, within):
        """One axis: stepwise selection, OLS, or GLS with ``response_cov`` or the reference-error covariance
        K_a + (w_a + s_a^2) I (s_a^2 by REML). Returns (result, projection P_a, selection or None, white part)."""
        spec = self.SPEC
        if self.model in ("stepwise", "backward"):
            lib = polynomial(spec.inputs, self.stepwise_library_degree)
            linear = ("1",) + spec.inputs
            if self.model == "stepwise":
                sel = forward_selection(lib, inputs, y, start=linear, criterion=self.stepwise_criterion)
            else:
                sel = backward_elimination(lib, inputs, y, keep=linear, criterion=self.stepwise_criterion)
            return sel.result, np.linalg.pinv(TermLibrary.from_names(sel.result.names).design(inputs)), sel, 0.0
        lib = self._library(a)
        if len(lib) >= len(y):
            raise UnidentifiableTermsError(
                f"{len(y)} observations cannot fit the {len(lib)} terms of the '{self.model}' model of "
                f"{spec.kind} axis {a} ({lib.names}): least squares needs more observations than terms. Add "
                "positions or choose a smaller model", list(lib.names))
        X = lib.design(inputs)
        if response_cov is not None:
            V = response_cov
        elif segment_cov is not None:
            K = reference_error_cov(segment_cov, survey, j, j) + within[j, j] * np.eye(len(y))
            V = K + white_variance_reml(X, y, K, level=WHITE_LEVEL) * np.eye(len(K))
        else:
            return fit_ols(X, y, lib.names), np.linalg.pinv(X), None, 0.0
        res = fit_gls(X, y, lib.names, V, known_cov=segment_cov is not None)
        white = V[0, 0] - K[0, 0] + within[j, j] if segment_cov is not None else 0.0
        return res, gls_projection(X, V), None, white

    # ------------------------------------------------------------ results
    def _require_results(self, what: str) -> None:
        self.check_fitted(what)
        if not hasattr(self, "results_"):
            raise NotFittedError(f"{what}() needs the fit's statistics: this {type(self).__name__} was loaded "
                                 "from a saved calibration (coefficients only); fit it to get them")

    def coefficient_vector(self):
        """((axis, term) names, coefficients beta, their full covariance) of the three inverse models."""
        self._require_results("coefficient_vector")
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
        self._require_results("physical_parameters")
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
        cu = getattr(self, "channel_unit_", "V")
        labels = ([(f"sensitivity_{a}", f"{unit_word(cu)}/({q})") for a in axes]
                  + [(f"misalignment_{axes[i]}{axes[j]}", "rad") for i in range(3) for j in range(3) if i != j]
                  + [(f"bias_{a}", q) for a in axes]
                  + [(f"nonlinearity_{a}", f"1/({q})") for a in axes])
        est = h(beta)
        se = np.sqrt(np.clip(np.diag(delta_cov(h, beta, cov)), 0, None))
        return [{"name": n, "unit": u, "estimate": float(e), "std_error": float(s)}
                for (n, u), e, s in zip(labels, est, se) if np.isfinite(e)]

    def models(self) -> dict:
        """{axis: (term names, coefficients)} of the fitted (or loaded) inverse models (``models_``)."""
        self.check_fitted("models")
        return self.models_

    def predict(self, u: np.ndarray) -> np.ndarray:
        """Calibrated quantity (m,3) for indicated quantity u (m,3), SI."""
        inputs = {n: u[:, j] for j, n in enumerate(self.SPEC.inputs)}
        models = self.models()
        return np.stack([TermLibrary.from_names(names).design(inputs) @ coef
                         for names, coef in (models[a] for a in self.SPEC.axes)], axis=1)

    def to_dict(self) -> dict:
        """What is needed to apply the calibration elsewhere (JSON-ready; :mod:`imurig.calibration.triad_file`)."""
        return triad_dict(self.SPEC, str(self.model), self.statistic, self.sensitivity_,
                          getattr(self, "channel_unit_", "V"), self.models())

    @classmethod
    def from_dict(cls, d: dict) -> "TriadCalibration":
        """The calibration a :meth:`to_dict` wrote, every part checked (a ValueError says which)."""
        models, model, statistic, sensitivity = read_triad_dict(d, cls.SPEC)
        cal = cls(model=model, statistic=statistic)
        cal.sensitivity_, cal.models_ = sensitivity, models
        return cal

    def apply(self, rec: Recording) -> Recording:
        """Add calibrated channels ``<prefix><axis>`` (SI) to a copy of ``rec``."""
        self.check_fitted()
        spec = self.SPEC
        missing = [c for c in spec.channels if c not in rec.channels]
        bad = {rec.units[c] for c in spec.channels if c in rec.channels} - {"V", "1", spec.quantity_unit}
        if missing or bad:
            raise RecordingError(f"applying the {spec.kind} calibration needs channels {list(spec.channels)} in V, "
                                 f"counts or {spec.quantity_unit}; the recording lacks {missing} or has units {bad}")
        s = self.sensitivity_ if self.sensitivity_ is not None else nominal_sensitivity(rec, spec)[0]
        u = rec.stack(spec.channels) / np.asarray(s, float)
        f = self.predict(u)
        channels, units = dict(rec.channels), dict(rec.units)
        for j, a in enumerate(spec.axes):
            channels[f"{spec.cal_prefix}{a}"] = f[:, j]
            units[f"{spec.cal_prefix}{a}"] = spec.quantity_unit
        return rec.replace(channels=channels, units=units)

    def table(self) -> dict:
        """Seed-style table: coefficients per axis and sigma_res, MS_res, R, R_adj."""
        self._require_results("table")
        return {a: self.results_[a].to_dict() for a in self.SPEC.axes}


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
