"""Accelerometer triad calibration with the inverse estimator (seed sections 4.1.5, 4.3.5).

Indicated specific force u (m/s^2, (m,3)) is the measured voltage over the nominal
sensitivity, u_i = V_i / s_nom,i. Each axis is fitted as the inverse model

    f_ref,i = sum_k beta_ik phi_k(u)        (seed Tables 4.4-4.6, "A|x = beta0 + beta1 ax + ...")

with phi_k a polynomial term library, by least squares on per-position medians (seed C.1.1)
or on all samples. The physical parameters of the forward model of
:class:`imurig.sensors.accelerometer.QFlexTriad` follow from the linear part B and the
constant c of the three inverse models: K = B^-1 = G (I + M), so
    scale G_i = K_ii, misalignment M_ij = K_ij / K_ii, bias b = -(I + M) c,
    nonlinearity k2_i = -beta_i(u_i^2) G_i^2 / [(I + M)^-1]_ii,
with standard errors by the delta method from the joint covariance of the betas (which
includes the reference's own uncertainty when a reference Jacobian is given).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from imurig.calibration.preprocess import segment_samples, segment_statistic
from imurig.calibration.regression import RegressionResult, fit_ols
from imurig.calibration.stepwise import backward_elimination, forward_selection
from imurig.calibration.terms import TermLibrary, polynomial, seed_accelerometer_terms
from imurig.errors import RecordingError
from imurig.recording import Recording

AXES = ("x", "y", "z")
ACC = tuple(f"acc_{a}" for a in AXES)
INPUTS = ("ax", "ay", "az")


def linear_terms() -> TermLibrary:
    return TermLibrary.from_names(["1", "ax", "ay", "az"])


def physical_terms(axis: str) -> TermLibrary:
    """Linear in all three axes plus the axis' own square: identifiable on a tilt table."""
    return TermLibrary.from_names(["1", "ax", "ay", "az", f"a{axis}^2"])


MODELS = {
    "linear": lambda a: linear_terms(),                                          # seed Table 4.4
    "cross": lambda a: TermLibrary.from_names(["1", "ax", "ay", "az", "ax*ay", "ax*az", "ay*az"]),  # Table 4.5
    "seed_final": seed_accelerometer_terms,                                      # seed Table 4.6
    "physical": physical_terms,
}


def indicated(rec: Recording, statistic: str = "median", sensitivity=None):
    """Indicated specific force u (m/s^2) per segment (statistic='median'/'mean') or per sample ('raw').

    Returns (u (m,3), segment index (m,)).
    """
    rec.require({c: "V" for c in ACC})
    s = sensitivity if sensitivity is not None else rec.meta.get("acc_nominal_sensitivity_V_per_m_s2")
    if s is None:
        raise RecordingError("the recording has no 'acc_nominal_sensitivity_V_per_m_s2' metadata (volts per "
                             "m/s^2 of each accelerometer, e.g. 1.33 mA/g x 750 ohm = 0.1017); add it as "
                             "'# acc_nominal_sensitivity_V_per_m_s2: [0.1017, 0.1017, 0.1017]' or pass it")
    s = np.broadcast_to(np.asarray(s, float), (3,))
    if statistic == "raw":
        v, seg = segment_samples(rec, ACC)
    else:
        v = segment_statistic(rec, ACC, statistic)
        seg = np.arange(v.shape[0])
    return v / s, seg


@dataclass
class AccelerometerCalibration:
    """Inverse-model calibration of an accelerometer triad (sklearn-like: settings in __init__,
    ``fit`` returns self, fitted attributes end in ``_``).

    model: 'linear', 'cross', 'seed_final', 'physical', 'stepwise' (forward selection from the linear
    model over the degree-2 library), 'backward' (backward elimination), or {axis: TermLibrary}.
    statistic: 'median' (per position, seed), 'mean', or 'raw' (every sample in the windows).
    """

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

    def _library(self, axis: str) -> TermLibrary:
        if isinstance(self.model, dict):
            lib = self.model[axis]
            return lib if isinstance(lib, TermLibrary) else TermLibrary.from_names(lib)
        if self.model not in MODELS:
            raise ValueError(f"unknown model {self.model!r}; choose from {sorted(MODELS) + ['stepwise', 'backward']}")
        return MODELS[self.model](axis)

    def fit(self, rec: Recording, reference: np.ndarray, reference_jacobian: np.ndarray | None = None,
            reference_sigma: np.ndarray | None = None) -> "AccelerometerCalibration":
        """Fit the three inverse models.

        reference : (n_seg, 3) reference specific force per segment, m/s^2 (in C).
        reference_jacobian : optional (n_seg, 3, q) d reference / d survey parameters, and
        reference_sigma (q,) their 1-sigma uncertainty; adds the reference's uncertainty
        to the coefficient covariance (beta = X^+ f_ref is linear in f_ref).
        """
        s = rec.meta.get("acc_nominal_sensitivity_V_per_m_s2")
        self.sensitivity_ = None if s is None else np.broadcast_to(np.asarray(s, float), (3,)).copy()
        u, seg = indicated(rec, self.statistic)
        reference = np.asarray(reference, float)
        if reference.shape != (rec.n_segments, 3):
            raise ValueError(f"reference must be (n_segments, 3) = ({rec.n_segments}, 3), got {reference.shape}")
        y_all = reference[seg]
        inputs = {n: u[:, j] for j, n in enumerate(INPUTS)}
        self.results_, self.selection_ = {}, {}
        for j, a in enumerate(AXES):
            if self.model in ("stepwise", "backward"):
                lib = polynomial(INPUTS, self.stepwise_library_degree)
                if self.model == "stepwise":
                    sel = forward_selection(lib, inputs, y_all[:, j], start=("1", "ax", "ay", "az"),
                                            criterion=self.stepwise_criterion)
                else:
                    sel = backward_elimination(lib, inputs, y_all[:, j], keep=("1", "ax", "ay", "az"),
                                               criterion=self.stepwise_criterion)
                self.selection_[a] = sel
                self.results_[a] = sel.result
            else:
                lib = self._library(a)
                self.results_[a] = fit_ols(lib.design(inputs), y_all[:, j], lib.names)
        self.reference_cov_ = None
        if reference_jacobian is not None and reference_sigma is not None:
            self.reference_cov_ = self._reference_covariance(inputs, seg, np.asarray(reference_jacobian),
                                                             np.asarray(reference_sigma))
        return self

    def _reference_covariance(self, inputs, seg, J, sigma) -> np.ndarray:
        """Covariance of all betas (stacked x, y, z) caused by the reference's uncertainty."""
        blocks = []
        for j, a in enumerate(AXES):
            lib = TermLibrary.from_names(self.results_[a].names)
            X = lib.design(inputs)
            pinv = np.linalg.pinv(X)
            blocks.append(pinv @ (J[seg, j, :] * sigma))  # (p_a, q)
        S = np.concatenate(blocks, axis=0)
        return S @ S.T

    # ------------------------------------------------------------ results
    def coefficient_vector(self):
        names = [(a, n) for a in AXES for n in self.results_[a].names]
        beta = np.concatenate([self.results_[a].coef_ for a in AXES])
        cov = np.zeros((beta.size, beta.size))
        i = 0
        for a in AXES:
            p = self.results_[a].p
            cov[i:i + p, i:i + p] = self.results_[a].cov_
            i += p
        if self.reference_cov_ is not None:
            cov = cov + self.reference_cov_
        return names, beta, cov

    def physical_parameters(self) -> list[dict]:
        """Forward-model parameters with delta-method standard errors (see module doc)."""
        names, beta, cov = self.coefficient_vector()
        index = {k: i for i, k in enumerate(names)}
        for a in AXES:
            for t in ("1", "ax", "ay", "az"):
                if (a, t) not in index:
                    raise ValueError(f"model for axis {a} lacks term '{t}'; physical parameters need the full "
                                     "linear part")
        sens = self.sensitivity_ if self.sensitivity_ is not None else np.ones(3)

        def h(b):
            B = np.array([[b[index[(a, f"a{c}")]] for c in AXES] for a in AXES])
            c0 = np.array([b[index[(a, "1")]] for a in AXES])
            K = np.linalg.inv(B)
            G = np.diag(K).copy()
            M = K / G[:, None]
            out = list(G * sens)
            out += [M[i, j] for i in range(3) for j in range(3) if i != j]
            out += list(-(M @ c0))
            Minv = np.linalg.inv(M)
            for i, a in enumerate(AXES):
                key = (a, f"a{a}^2")
                out.append(-b[index[key]] * G[i] ** 2 / Minv[i, i] if key in index else np.nan)
            return np.array(out)

        labels = ([(f"sensitivity_{a}", "V/(m/s^2)") for a in AXES]
                  + [(f"misalignment_{AXES[i]}{AXES[j]}", "rad") for i in range(3) for j in range(3) if i != j]
                  + [(f"bias_{a}", "m/s^2") for a in AXES]
                  + [(f"nonlinearity_{a}", "1/(m/s^2)") for a in AXES])
        est = h(beta)
        se = np.sqrt(np.clip(np.diag(_delta_cov(h, beta, cov)), 0, None))
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
        """Calibrated specific force (m,3) for indicated specific force u (m,3)."""
        inputs = {n: u[:, j] for j, n in enumerate(INPUTS)}
        return np.stack([TermLibrary.from_names(names).design(inputs) @ coef
                         for names, coef in (self.models()[a] for a in AXES)], axis=1)

    def to_dict(self) -> dict:
        """What is needed to apply the calibration elsewhere (JSON-ready)."""
        return {"kind": "imurig.accelerometer_inverse_model", "version": 1, "model": str(self.model),
                "statistic": self.statistic,
                "nominal_sensitivity_V_per_m_s2": None if self.sensitivity_ is None else self.sensitivity_.tolist(),
                "equation": "f_ref,i [m/s^2] = sum_k coef_ik * term_k(u), u = volts / nominal_sensitivity",
                "axes": {a: {"terms": n, "coef": c.tolist()} for a, (n, c) in self.models().items()}}

    @classmethod
    def from_dict(cls, d: dict) -> "AccelerometerCalibration":
        if d.get("kind") != "imurig.accelerometer_inverse_model":
            raise ValueError("not an imurig accelerometer calibration (kind must be "
                             "'imurig.accelerometer_inverse_model'); use the calibration.json of a report folder")
        cal = cls(model=d.get("model", "loaded"), statistic=d.get("statistic", "median"))
        s = d.get("nominal_sensitivity_V_per_m_s2")
        cal.sensitivity_ = None if s is None else np.asarray(s, float)
        cal.loaded_ = {a: (list(v["terms"]), np.asarray(v["coef"], float)) for a, v in d["axes"].items()}
        return cal

    def apply(self, rec: Recording) -> Recording:
        """Add calibrated channels ``acc_cal_x/y/z`` (m/s^2) to a copy of ``rec``."""
        rec.require({c: "V" for c in ACC})
        s = self.sensitivity_ if self.sensitivity_ is not None else rec.meta.get("acc_nominal_sensitivity_V_per_m_s2")
        if s is None:
            raise RecordingError("no nominal sensitivity in the calibration or the recording's metadata")
        u = rec.stack(ACC) / np.asarray(s, float)
        f = self.predict(u)
        channels, units = dict(rec.channels), dict(rec.units)
        for j, a in enumerate(AXES):
            channels[f"acc_cal_{a}"] = f[:, j]
            units[f"acc_cal_{a}"] = "m/s^2"
        return rec.replace(channels=channels, units=units)

    def table(self) -> dict:
        """Seed-style table: coefficients per axis and sigma_res, MS_res, R, R_adj."""
        return {a: self.results_[a].to_dict() for a in AXES}


def _delta_cov(h, x, cov) -> np.ndarray:
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


def injected_parameters(truth: dict) -> dict:
    """The forward-model parameters the calibration estimates, from a simulation's truth (SI)."""
    acc = truth["sensors"]["accelerometers"]
    M = np.asarray(acc["misalignment_rad"])
    out = {}
    for i, a in enumerate(AXES):
        out[f"sensitivity_{a}"] = acc["sensitivity_V_per_m_s2"][i]
        out[f"bias_{a}"] = acc["bias_m_s2"][i]
        out[f"nonlinearity_{a}"] = acc["k2_per_m_s2"][i]
        for j, c in enumerate(AXES):
            if i != j:
                out[f"misalignment_{a}{c}"] = M[i, j]
    return out
