"""Thermal calibration (seed section 4.5, paper section 3.1).

Per temperature step, the six attitudes (+-x, +-y, +-z up) separate bias from scale factor
(the six-position method). With u the indicated quantity (volts / nominal sensitivity) and
r the reference along the axis (+g, -g for accelerometers):

    b_i(T) = (u_i(+) + u_i(-)) / 2,     s_i(T) = (u_i(+) - u_i(-)) / (2 |r|)      (accelerometers)
    b_j(T) = mean over attitudes of (u_j - w_ref,j)                              (gyros: Earth rate)

and each is fitted against its temperature sensor's reading T (K), dT = T - 298.15 K:

    b(T) = c0 + c1 dT + c2 dT^2 + c3 dT^3 + H s      (accelerometers: third order, seed)
    b(T) = c0 + c1 dT + H s                           (gyros: first order, seed)

where s = +1/2 on steps reached by heating and -1/2 on steps reached by cooling, so H is the
hysteresis gap between the branches, estimated and reported rather than hidden.
"""
from __future__ import annotations

from typing import Self

import numpy as np

from imurig.calibration.preprocess import segment_statistic
from imurig.calibration.regression import fit_ols
from imurig.kernel.errors import RecordingError
from imurig.kernel.estimator import Estimator
from imurig.kernel.recording import Recording
from imurig.kernel.site import Site
from imurig.kernel.units import T_REF_K
from imurig.rigs.thermal_chamber import attitude_R_WC

T0 = T_REF_K  # K, dT = T - T0
ACC = ("acc_x", "acc_y", "acc_z")
GYRO = ("gyro_p", "gyro_q", "gyro_r")
TEMP_ACC = ("temp_acc_x", "temp_acc_y", "temp_acc_z")
PAIRS = {0: ("x_up", "x_down"), 1: ("y_up", "y_down"), 2: ("z_up", "z_down")}


def sensor_temperature_K(volts: np.ndarray, uA_per_K: float = 1.0, uA_at_T0: float = 298.2,
                         load_ohm: float = 10e3) -> np.ndarray:
    """Temperature (K) from a 1 uA/K sensor's voltage over its load (the nominal characteristic)."""
    return T0 + (np.asarray(volts) / load_ohm * 1e6 - uA_at_T0) / uA_per_K


def step_table(rec: Recording, source: str = "channels", channels=None) -> dict:
    """Per temperature step: accelerometer bias and scale, gyro bias, sensor temperatures.

    ``source='truth_signals'`` with ``channels`` (a dict of ideal volt arrays) computes the
    same table on noise-free data (the noise-free twin). Returns arrays over steps.
    """
    seg = rec.segments
    for col in ("attitude", "step", "branch"):
        if col not in seg:
            raise RecordingError(f"thermal recordings need the segment column '{col}' (attitude per window)")
    work = rec if channels is None else rec.replace(channels={**rec.channels, **channels},
                                                     units={**rec.units, **{k: "V" for k in channels}})
    # a Recording, or a FileRecord read one window at a time (the diagnosis streams the file)
    have = work.channels if hasattr(work, "channels") else work.channel_names
    names = [c for c in ACC + GYRO + TEMP_ACC + ("temp_box",) if c in have]
    med = segment_statistic(work, names, "median")
    col = {n: med[:, k] for k, n in enumerate(names)}
    steps = np.unique(seg["step"])
    g = Site.from_dict(rec.meta.get("site", {})).gravity_m_s2
    s_acc = np.asarray(rec.meta.get("acc_nominal_sensitivity_V_per_m_s2", [np.nan] * 3), float)
    s_gyro = np.asarray(rec.meta.get("gyro_nominal_sensitivity_V_per_rad_s", [np.nan] * 3), float)
    out = {"step": [], "T_set": [], "branch": [], "cycle": [], "acc_bias": [], "acc_scale": [], "T_acc": [],
           "gyro_bias": [], "T_box": []}
    earth_W = Site.from_dict(rec.meta.get("site", {})).earth_rate_W()
    for k in steps:
        sel = np.flatnonzero(seg["step"] == k)
        att = {str(seg["attitude"][i]): i for i in sel}
        out["step"].append(int(k))
        out["T_set"].append(float(seg["T_set"][sel[0]]))
        out["branch"].append(str(seg["branch"][sel[0]]))
        out["cycle"].append(int(seg["cycle"][sel[0]]))
        if "acc_x" in col:
            b, s = np.full(3, np.nan), np.full(3, np.nan)
            for ax, (up, dn) in PAIRS.items():
                if up in att and dn in att:
                    u_up, u_dn = col[ACC[ax]][att[up]] / s_acc[ax], col[ACC[ax]][att[dn]] / s_acc[ax]
                    b[ax], s[ax] = (u_up + u_dn) / 2, (u_up - u_dn) / (2 * g)
            out["acc_bias"].append(b)
            out["acc_scale"].append(s)
            out["T_acc"].append([sensor_temperature_K(col[c][sel]).mean() for c in TEMP_ACC if c in col])
        if "gyro_p" in col:
            u = np.stack([col[c][sel] / s_gyro[j] for j, c in enumerate(GYRO)], 1)
            w_ref = np.stack([attitude_R_WC(str(seg["attitude"][i])).T @ earth_W for i in sel])
            out["gyro_bias"].append((u - w_ref).mean(axis=0))
        if "temp_box" in col:
            out["T_box"].append(float(sensor_temperature_K(col["temp_box"][sel]).mean()))
    return {k: np.array(v) for k, v in out.items() if len(v)}


def _design(T, order, s=None):
    dT = T - T0
    cols = [np.ones_like(dT)] + [dT**k for k in range(1, order + 1)]
    if s is not None:
        cols.append(np.asarray(s, float))
    return np.column_stack(cols)


def term_names(order: int, hysteresis: bool) -> list[str]:
    return ["1"] + ["dT" if k == 1 else f"dT^{k}" for k in range(1, order + 1)] + (["hysteresis"] if hysteresis else [])


class ThermalCalibration(Estimator):
    """Temperature models of the bias (and the accelerometers' scale) against each sensor's
    temperature reading, with the hysteresis gap between heating and cooling (module doc).

    Settings: polynomial orders ``acc_order`` (accelerometer bias), ``scale_order``
    (accelerometer scale), ``gyro_order`` (gyro bias), and ``hysteresis`` (estimate H when the
    record has both branches). ``fit(table)`` takes the per-step table of :func:`step_table` (or a
    thermal :class:`~imurig.kernel.recording.Recording`, tabulated first).

    Fitted: ``results_`` {key: RegressionResult} over the keys ``acc_bias_<a>``, ``acc_scale_<a>``
    (a = x, y, z) and ``gyro_bias_<a>`` (a = p, q, r) present in the table; ``order_`` {key: order};
    ``hysteresis_`` whether H was estimated. :meth:`apply` compensates indicated specific forces.
    """

    def __init__(self, acc_order: int = 3, gyro_order: int = 1, scale_order: int = 1, hysteresis: bool = True):
        self.acc_order = acc_order
        self.gyro_order = gyro_order
        self.scale_order = scale_order
        self.hysteresis = hysteresis

    def terms_needed(self, hysteresis: bool) -> int:
        """The largest model's number of terms: polynomial order + 1, + 1 for the hysteresis gap."""
        return max(self.acc_order, self.scale_order, self.gyro_order) + 1 + int(hysteresis)

    def fit(self, table: dict | Recording) -> Self:
        """Fit every model of the step table (module doc); returns self."""
        self._clear_fitted()
        if isinstance(table, Recording):
            table = step_table(table)
        if np.unique(np.round(table["T_set"], 3)).size < 2:
            raise RecordingError("the record holds one temperature only: a thermal calibration needs several "
                                 "set-points")
        s = np.where(table["branch"] == "up", 0.5, -0.5)
        use_h = self.hysteresis and np.unique(s).size == 2
        need = self.terms_needed(use_h)
        if len(s) <= need:
            raise RecordingError(f"{len(s)} temperature steps for {need} terms (cubic accelerometer bias"
                                 f"{' and the hysteresis gap' if use_h else ''}): least squares needs more steps than "
                                 "terms; widen the temperature range, shrink the step or add a cycle")
        results, order = {}, {}
        if "acc_bias" in table:
            for j, a in enumerate("xyz"):
                T = table["T_acc"][:, j]
                for key, y, o in ((f"acc_bias_{a}", table["acc_bias"][:, j], self.acc_order),
                                  (f"acc_scale_{a}", table["acc_scale"][:, j], self.scale_order)):
                    X = _design(T, o, s if use_h else None)
                    results[key] = fit_ols(X, y, term_names(o, use_h))
                    order[key] = o
        if "gyro_bias" in table:
            for j, a in enumerate("pqr"):
                X = _design(table["T_box"], self.gyro_order, s if use_h else None)
                key = f"gyro_bias_{a}"
                results[key] = fit_ols(X, table["gyro_bias"][:, j], term_names(self.gyro_order, use_h))
                order[key] = self.gyro_order
        self.results_, self.order_, self.hysteresis_ = results, order, bool(use_h)
        return self

    def predict(self, key: str, T_K: np.ndarray, h: np.ndarray | float = 0.0) -> np.ndarray:
        """Model value of ``key`` at sensor temperatures ``T_K`` (K) and hysteresis state h (+-1/2, or 0: mid-way)."""
        self.check_fitted("predict")
        r = self.results_[key]
        T = np.atleast_1d(np.asarray(T_K, float))
        s = np.broadcast_to(h, T.shape) if "hysteresis" in r.names else None
        return _design(T, self.order_[key], s) @ r.coef_

    def compensation(self, T_K: np.ndarray, h: np.ndarray, T_ref_K: float = T0):
        """Per accelerometer axis, the thermal change of the six-position bias and scale relative to the
        conditions (T_ref, hysteresis state 0), at temperatures ``T_K`` (n, 3) K and states ``h`` (n, 3):

            ΔB = B(T, h) − (S(T, h)/S(T_ref, 0)) B(T_ref, 0),   ρ = S(T, h)/S(T_ref, 0)      [(n, 3)]

        Returns (ΔB m/s², ρ, σ_ΔB): σ_ΔB (n, 3) the fit's standard error of ΔB (delta method on the
        coefficient covariance)."""
        self.check_fitted("compensation")
        T_K = np.asarray(T_K, float)
        h = np.asarray(h, float)
        dB, rho, sdB = (np.empty_like(T_K) for _ in range(3))
        for j, a in enumerate("xyz"):
            kb, ks = f"acc_bias_{a}", f"acc_scale_{a}"
            S0 = float(self.predict(ks, np.array([T_ref_K]), 0.0)[0])
            rho[:, j] = self.predict(ks, T_K[:, j], h[:, j]) / S0
            B0 = float(self.predict(kb, np.array([T_ref_K]), 0.0)[0])
            dB[:, j] = self.predict(kb, T_K[:, j], h[:, j]) - rho[:, j] * B0
            r = self.results_[kb]
            X = _design(T_K[:, j], self.order_[kb], h[:, j]) - _design(np.array([T_ref_K]), self.order_[kb], np.zeros(1))
            sdB[:, j] = np.sqrt(np.einsum("ni,ij,nj->n", X, r.cov_, X))
        return dB, rho, sdB

    def apply(self, f: np.ndarray, T_K: np.ndarray, h: np.ndarray, T_ref_K: float = T0) -> np.ndarray:
        """Indicated specific force ``f`` (n, 3) m/s² at accelerometer temperatures ``T_K`` (n, 3) K and
        hysteresis states ``h`` (n, 3) brought back to (T_ref, 0): f_ref = (f − ΔB) / ρ (:meth:`compensation`)."""
        dB, rho, _ = self.compensation(T_K, h, T_ref_K)
        return (np.asarray(f, float) - dB) / rho


def branch_gap(table: dict, key: str, axis: int) -> dict:
    """Mean difference heating minus cooling branch at the temperatures both visit (per cycle)."""
    y = table[key][:, axis]
    T = np.round(table["T_set"], 3)
    up = {t: [] for t in np.unique(T)}
    dn = {t: [] for t in np.unique(T)}
    for t, b, v in zip(T, table["branch"], y):
        (up if b == "up" else dn)[t].append(v)
    common = [t for t in up if up[t] and dn[t]]
    d = np.array([np.mean(up[t]) - np.mean(dn[t]) for t in common])
    return {"temperatures_K": common, "gap": d.tolist(), "mean_gap": float(d.mean()) if d.size else None}
