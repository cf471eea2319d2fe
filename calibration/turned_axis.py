"""Gyros on a rate table that turned about one of their axes only (one mounting), as many labs with
a single-axis table record one file per axis.

Whole rounds between the index pulses give each step's table rate Ω_k (:func:`round_windows`), and
the reference along the turned axis a is w_k = Ω_k + Ω_E sin(latitude) (:func:`reference_rates`).
Each step's mean output (volts, counts or SI; one independent observation per step) obeys

    turned gyro a:   ȳ_a,k = b_a + S_a (w_k + k2_a w_k²) + e_k            (k2 only with ≥ 2 residual dof)
    the others j:    ȳ_j,k = b_j + S_j,nom M_ja w_k + e_k

fitted by ordinary least squares with the residual variance of each fit (standard errors count the
steps, not the samples). Reported in the forward model's terms: sensitivity S_a, bias b_a / S_a and
nonlinearity k2_a of the turned gyro; for the others the bias b_j / S_j,nom and the cross-axis
sensitivity M_ja to the turned axis, through their nominal sensitivities (a 1 % sensitivity error
scales these by 1 %). The other gyros' scale factors need steps with them on the table axis: then
:class:`imurig.calibration.gyro.GyroCalibration` fits the whole triad.
"""
from __future__ import annotations

import numpy as np

from imurig.calibration.gyro import AXES, GYRO, SPEC, reference_rates, round_windows, unexcited_axes
from imurig.calibration.sensitivity import nominal_sensitivity
from imurig.kernel.errors import RecordingError
from imurig.kernel.estimator import Estimator
from imurig.kernel.recording import Recording

KIND = "imurig.gyro_turned_axis"


def step_means(rw: Recording, channels) -> np.ndarray:
    """Mean of each channel over each segment [start, stop) of ``rw``: (n_seg, len(channels))."""
    t = rw.time_s
    out = np.empty((rw.n_segments, len(channels)))
    for k, (a, b) in enumerate(zip(rw.segments["start_s"], rw.segments["stop_s"])):
        i0, i1 = np.searchsorted(t, [a, b])
        if i1 <= i0:
            raise RecordingError(f"step {k} ({a:.2f}-{b:.2f} s) holds no sample")
        out[k] = [float(np.mean(rw.channels[c][i0:i1])) for c in channels]
    return out


def ols(X: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """(coefficients, their covariance from the residual variance, residual dof)."""
    n, p = X.shape
    dof = n - p
    if dof < 1:
        raise RecordingError(f"{n} steps cannot fit {p} coefficients with a residual left; record more rates")
    beta, *_ = np.linalg.lstsq(X, y, rcond=None)
    r = y - X @ beta
    s2 = float(r @ r) / dof
    return beta, s2 * np.linalg.inv(X.T @ X), dof


class TurnedAxisCalibration(Estimator):
    """Calibration of the gyro the table turned (module doc), with the others' biases and cross-axis
    sensitivities. Settings: ``timer`` of the index pulses ('adc', 'channel', 'hp6700', ...);
    ``nonlinearity`` ('auto': fitted when ≥ 2 residual dof remain, or True / False).

    Fitted: ``axis_`` (the turned axis), ``parameters_`` (list of {name, unit, estimate, std_error}),
    ``coef_`` {axis: (b, slope[, quadratic])} in the channels' unit, ``sensitivity_`` (3,) nominal,
    ``windows_``, ``table_rate_`` (n_seg,) rad/s, ``reference_`` (n_seg, 3) rad/s, ``dof_``."""

    def __init__(self, timer: str = "hp6700", nonlinearity: str | bool = "auto"):
        self.timer = timer
        self.nonlinearity = nonlinearity

    def fit(self, rec: Recording):
        rw, rate = round_windows(rec, self.timer)
        ref = reference_rates(rw, rate)
        turned = [j for j, ax in enumerate(AXES) if ax not in unexcited_axes(ref)]
        if len(turned) != 1:
            raise RecordingError(f"the table turned {len(turned)} gyro axes; a one-axis calibration needs exactly "
                                 "one (GyroCalibration fits the triad when every axis was on the table axis)")
        a = turned[0]
        s_nom, unit = nominal_sensitivity(rec, SPEC)
        y = step_means(rw, GYRO)
        w = ref[:, a]
        quad = self.nonlinearity is True or (self.nonlinearity == "auto" and np.unique(np.round(w, 9)).size - 3 >= 2)
        X = np.column_stack([np.ones_like(w), w] + ([w ** 2] if quad else []))
        beta, cov, dof = ols(X, y[:, a])
        S, b = beta[1], beta[0]
        # forward parameters h(beta) and their delta-method covariance J cov J^T
        est = [S, b / S] + ([beta[2] / S] if quad else [])
        J = np.array([[0, 1, 0][:X.shape[1]], [1 / S, -b / S ** 2, 0][:X.shape[1]]]
                     + ([[0, -beta[2] / S ** 2, 1 / S]] if quad else []))
        se = np.sqrt(np.diag(J @ cov @ J.T))
        ua = f"{'V' if unit == 'V' else unit}/(rad/s)" if unit != "rad/s" else "-"
        params = [{"name": f"sensitivity_{AXES[a]}", "unit": ua, "estimate": float(est[0]), "std_error": float(se[0])},
                  {"name": f"bias_{AXES[a]}", "unit": "rad/s", "estimate": float(est[1]), "std_error": float(se[1])}]
        if quad:
            params.append({"name": f"nonlinearity_{AXES[a]}", "unit": "1/(rad/s)", "estimate": float(est[2]),
                           "std_error": float(se[2])})
        coef = {AXES[a]: beta}
        X1 = X[:, :2]
        for j in (j for j in range(3) if j != a):
            bj, cj, _ = ols(X1, y[:, j])
            coef[AXES[j]] = bj
            s = float(s_nom[j])
            params += [{"name": f"bias_{AXES[j]}", "unit": "rad/s", "estimate": bj[0] / s,
                        "std_error": float(np.sqrt(cj[0, 0])) / s},
                       {"name": f"misalignment_{AXES[j]}{AXES[a]}", "unit": "rad", "estimate": bj[1] / s,
                        "std_error": float(np.sqrt(cj[1, 1])) / s}]
        self.axis_, self.parameters_, self.coef_, self.sensitivity_ = AXES[a], params, coef, np.asarray(s_nom, float)
        self.windows_, self.table_rate_, self.reference_, self.dof_ = rw, rate, ref, dof
        return self

    def apply(self, rec: Recording) -> Recording:
        """Calibrated rates ``gyro_cal_<axis>`` (rad/s): the turned gyro through its fitted line (and the
        first-order inverse of its square term); the others through their nominal sensitivity, less
        their bias and their cross-axis share of the turned rate."""
        self.check_fitted()
        a = self.axis_
        beta = self.coef_[a]
        y = rec.channels[f"gyro_{a}"]
        u = (y - beta[0]) / beta[1]
        w_a = u - (beta[2] / beta[1]) * u ** 2 if len(beta) > 2 else u
        channels, units = dict(rec.channels), dict(rec.units)
        channels[f"gyro_cal_{a}"], units[f"gyro_cal_{a}"] = w_a, "rad/s"
        for j, ax in enumerate(AXES):
            if ax != a:
                bj = self.coef_[ax]
                channels[f"gyro_cal_{ax}"] = (rec.channels[f"gyro_{ax}"] - bj[0] - bj[1] * w_a) / self.sensitivity_[j]
                units[f"gyro_cal_{ax}"] = "rad/s"
        return rec.replace(channels=channels, units=units)

    def to_dict(self) -> dict:
        """The fitted lines, JSON-ready."""
        self.check_fitted()
        return {"kind": KIND, "version": 1, "turned_axis": self.axis_,
                "equation": "turned: y = b + S (w + k2 w^2); others: y = b_j + S_j,nom M_ja w (channel units)",
                "nominal_sensitivity": self.sensitivity_.tolist(),
                "coef": {k: np.asarray(v).tolist() for k, v in self.coef_.items()}}
