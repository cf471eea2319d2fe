"""The table's own rate in a turn-table time series: mains factor and slip from the index pulses
(or from the integrated rate), as the appendix-B rows give them from the stopwatch.

Per whole-round window i (:func:`imurig.calibration.gyro.round_windows`) the measured table rate
r_i = 2 pi n_i / (t_last - t_first) from the n_i rounds between the pulses, against the dial D_i:

    k_i = |r_i| / |D_i|                           (ratio measured / dial)
    f   = f_mains / f_motor, the motor/mains pair nearest the mean ratio, f_mains from the
          recording's ``mains_hz`` (default 50 Hz), f_motor 50 or 60 Hz; named when the mean ratio
          lies more than 5 standard errors from 1 (the :mod:`mains_rate_factor` test)
    d_i = k_i / f - 1                             (relative shortfall; slip: d = -s0 - s1 r^-alpha)

and the shortfall goes through the engine with the library's :class:`RateShortfallView`
candidates (table slip), as the rows' diagnosis does (:func:`imurig.diagnose.rate_table._shortfall`).
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

from imurig.diagnose.rate_table import _shortfall

#: the motor designs a synchronous table motor is built for (Hz)
MOTOR_DESIGNS_HZ = (50.0, 60.0)


def mains_factor(k: np.ndarray, mains_hz: float = 50.0) -> dict:
    """The mean ratio measured / dial with its SE, and the factor f_mains / f_motor it matches:
    {mean_ratio, mean_ratio_se, factor, pair, named} (named: > 5 SE from 1 and f != 1)."""
    k = np.asarray(k, float)
    m = float(np.mean(k))
    se = float(np.std(k, ddof=1) / np.sqrt(k.size)) if k.size > 1 else float("inf")
    pairs = {f"{f_m:g} Hz motor on {mains_hz:g} Hz mains": mains_hz / f_m for f_m in MOTOR_DESIGNS_HZ}
    pair, f = min(pairs.items(), key=lambda it: abs(np.log(m / it[1])))
    return {"mean_ratio": m, "mean_ratio_se": se, "factor": f, "pair": pair,
            "named": bool(abs(m - 1) > 5 * se and abs(f - 1) > 1e-12)}


def diagnose_table_rate(dial_rad_s: np.ndarray, measured_rad_s: np.ndarray, rng: np.random.Generator,
                        mains_hz: float = 50.0, alpha: float = 0.01, n_sim: int = 300, min_windows: int = 6,
                        window_s: np.ndarray | None = None, edge_sigma_s: float | None = None) -> dict:
    """Mains factor and slip of the table from the windows' dial and measured rates (module doc);
    ``window_s``: each window's length first to last pulse (s), whose square weights the slip's
    joint refit (:func:`slip_joint_fit`); with ``edge_sigma_s``, the pulse edges' timing error (s),
    the weights are the inverse variances 2 sigma_e^2 / window^2 of the relative rates."""
    dial, meas = np.abs(np.asarray(dial_rad_s, float)), np.abs(np.asarray(measured_rad_s, float))
    ok = dial > 0
    if ok.sum() < min_windows:
        return {"tested": False, "why": f"{int(ok.sum())} whole-round windows with a dial rate; the table's rate "
                                        f"needs at least {min_windows}"}
    k = meas[ok] / dial[ok]
    mf = mains_factor(k, mains_hz)
    f_use = mf["factor"] if mf["named"] else 1.0
    d = k / f_use - 1.0
    r_dps = np.degrees(meas[ok])
    out = {"tested": True, "mains_hz": mains_hz, "windows": int(ok.sum()), **mf,
           "mean_shortfall": float(-np.mean(d)), "note": "d = measured rate / (factor x dial) - 1"}
    if mf["named"]:
        out["finding_mains"] = {"effect": "mains_rate_factor",
                                "physics": f"synchronous table motor: {mf['pair']} turns at {mf['factor']:.4f} of the dial",
                                "parameters": [{"name": "factor", "estimate": mf["mean_ratio"],
                                                "std_error": mf["mean_ratio_se"]}],
                                "matched_factor": mf["factor"]}
    if np.unique(np.round(r_dps, 6)).size >= 3:
        # pulse-timed windows: relative rate errors sqrt(2) sigma_e / T_w, so weights T_w^2 (:func:`_shortfall`)
        wts = None if window_s is None else np.asarray(window_s, float)[ok] ** 2
        _lib, diag = _shortfall(d, r_dps, rng, alpha, n_sim, weights=wts)
        out["shortfall"] = diag.to_dict()
        out["residuals"] = {"unit": "1", "rate_dps": r_dps.tolist(), "before": diag.before.residuals_.tolist(),
                            "after": diag.after.residuals_.tolist()}
        w = None if window_s is None else np.asarray(window_s, float)[ok] ** 2
        absolute = w is not None and edge_sigma_s is not None and edge_sigma_s > 0
        if absolute:
            w = w / (2.0 * edge_sigma_s**2)
        for f in out["shortfall"]["findings"]:
            if f["effect"] == "table_slip":
                f["joint_fit"] = slip_joint_fit(d, r_dps, w, absolute)
                f["parameters"] = f["joint_fit"]["parameters"]
    return out


def _cond_se(r: np.ndarray, sw: np.ndarray, a: float, s2: float) -> float:
    """SE of s1 at a fixed exponent ``a``: weighted least squares of [1, r^-a] with variance s2 / w."""
    X = np.column_stack([np.ones_like(r), r ** -a]) * sw[:, None]
    return float(np.sqrt(s2 * np.linalg.pinv(X.T @ X)[1, 1]))


def slip_joint_fit(d: np.ndarray, r_dps: np.ndarray, weight: np.ndarray | None = None, absolute: bool = False) -> dict:
    """The slip d = c - s1' r^-alpha refitted with the exponent free, so that the SE of the
    coefficient s1 (of r^-alpha, as the library names it) includes the exponent's uncertainty:

        d_i = c + s1 r_i^-alpha + e_i,    var(e_i) = sigma^2 / weight_i

    (weight_i = the window length squared: a pulse-timed rate's error falls as 1 / length).
    Weighted least squares in (c, s1, alpha), started from the best of an alpha grid 0.05 ... 3;
    covariance sigma_hat^2 (J' W J)^-1 with sigma_hat^2 = weighted RSS / (n - 3), at least 1 when
    ``absolute`` (the weights are then known inverse variances: a few residuals' small RSS must
    not shrink the SE). s1's SE is the
    larger of that and the profile's: sqrt(SE(s1 | alpha)^2 + h^2), h half the range of s1 over the
    exponents whose weighted RSS is within sigma_hat^2 of the best (Delta chi^2 = 1)."""
    d, r = np.asarray(d, float), np.asarray(r_dps, float)
    w = np.ones_like(d) if weight is None else np.asarray(weight, float) / (1.0 if absolute else np.mean(weight))
    sw = np.sqrt(w)

    def lin(a):
        X = np.column_stack([np.ones_like(r), r ** -a])
        beta = np.linalg.lstsq(X * sw[:, None], d * sw, rcond=None)[0]
        return beta, float(np.sum(w * (d - X @ beta) ** 2))

    grid = np.arange(0.05, 3.001, 0.05)
    a0 = grid[int(np.argmin([lin(a)[1] for a in grid]))]
    b0 = lin(a0)[0]
    res = least_squares(lambda p: sw * (d - p[0] - p[1] * r ** -p[2]), [b0[0], b0[1], a0],
                        bounds=([-np.inf, -np.inf, 0.01], [np.inf, np.inf, 5.0]))
    c, s1, a = res.x
    J = res.jac
    dof = max(d.size - 3, 1)
    s2 = float(np.sum(res.fun ** 2)) / dof
    s2 = max(s2, 1.0) if absolute else s2
    cov = s2 * np.linalg.pinv(J.T @ J)
    se = np.sqrt(np.clip(np.diag(cov), 0, None))
    # the profile over the exponent: where the linearisation fails (s1 and alpha trade off
    # nonlinearly), s1's spread over the exponents within Delta chi^2 = 1 of the best
    A = r[None, :] ** -np.arange(0.02, 3.001, 0.01)[:, None]          # (exponents, windows)
    S0, S1, S2 = np.sum(w), A @ w, (A * A) @ w
    Y0, Y1 = float(np.sum(w * d)), A @ (w * d)
    det = S0 * S2 - S1**2
    cs, s1s = (S2 * Y0 - S1 * Y1) / det, (S0 * Y1 - S1 * Y0) / det
    rss = np.sum(w * (d - cs[:, None] - s1s[:, None] * A) ** 2, axis=1)
    inside = rss <= min(rss.min(), float(np.sum(res.fun ** 2))) + s2
    half = 0.5 * float(np.ptp(s1s[inside])) if inside.any() else 0.0
    se[1] = max(se[1], float(np.hypot(_cond_se(r, sw, float(a), s2), half)))
    return {"parameters": [{"name": "table_slip:s1", "estimate": float(s1), "std_error": float(se[1])},
                           {"name": "table_slip:alpha", "estimate": float(a), "std_error": float(se[2])},
                           {"name": "table_slip:s0", "estimate": float(-c), "std_error": float(se[0])}],
            "residual_sigma": float(np.sqrt(s2)), "dof": dof,
            "weights": ("inverse variances" if absolute else "window length squared") if weight is not None else "equal", "note": "s1's SE includes the exponent's uncertainty (joint fit)"}
