"""Scoring a navigation filter against the true trajectory: errors and consistency (NEES).

For each block X of the solution (position r_N, velocity v_N, attitude q_NB) at the k
solution times:

    e_X(t) = X_est(t) - X_true(t)                        (position m, velocity m/s)
    e_att(t) = rotation vector of q_est ⊗ q_true^-1      (rad, small rotation error in N)

and, where the filter reports the covariance P_X(t) (3 x 3),

    NEES_X(t) = e_X(t)' P_X(t)^-1 e_X(t),   ANEES_X = mean over t.

For a consistent filter NEES is chi-square with 3 degrees of freedom, so ANEES ≈ 3. The
95 % acceptance interval for ANEES is [chi2.ppf(0.025, 3k) / k, chi2.ppf(0.975, 3k) / k]:
this assumes errors independent between the k epochs, which holds for a Monte-Carlo set
of runs at one epoch and only approximately along one run (a filter's errors are
correlated in time; there the interval is too narrow and flags real filters more often).
The truth is interpolated to the solution times (linear; attitude by normalised linear
interpolation of the quaternions, adequate for truth sampled much faster than it turns).
"""
from __future__ import annotations

import numpy as np
from scipy import stats

from imurig.kernel.quaternion import q_conj as quat_conj  # noqa: F401  (this module's names too)
from imurig.kernel.quaternion import q_mult as quat_mul
from imurig.scoring.interface import EstimatesError, NavFilter, NavSolution, NavStreams, fitted_solution


def quat_to_rotvec(q: np.ndarray) -> np.ndarray:
    """Rotation vector (..., 3) rad of unit quaternions (..., 4) (shortest rotation)."""
    q = np.where(q[..., :1] < 0, -q, q)
    v = q[..., 1:]
    s = np.linalg.norm(v, axis=-1, keepdims=True)
    angle = 2 * np.arctan2(s, q[..., :1])
    with np.errstate(invalid="ignore", divide="ignore"):
        k = np.where(s > 1e-12, angle / s, 2.0)
    return v * k


def rotvec_to_quat(r: np.ndarray) -> np.ndarray:
    a = np.linalg.norm(r, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        k = np.where(a > 1e-12, np.sin(a / 2) / a, 0.5)
    return np.concatenate([np.cos(a / 2), r * k], axis=-1)


def _interp(t_src, x, t):
    return np.stack([np.interp(t, t_src, x[:, j]) for j in range(x.shape[1])], axis=1)


def _check(name, x, k, width):
    x = np.asarray(x, float)
    if x.shape[:2] != (k, width) and x.shape != (k, width):
        raise EstimatesError(f"{name} must have shape ({k}, {width}), got {x.shape}")
    if not np.all(np.isfinite(x)):
        raise EstimatesError(f"{name} holds NaN/inf values (first at epoch {int(np.argwhere(~np.isfinite(x))[0, 0])})")
    return x


def nees_interval(k: int, dof: int = 3, level: float = 0.95) -> tuple[float, float]:
    """Acceptance interval of the average NEES over k independent epochs."""
    a = (1 - level) / 2
    return float(stats.chi2.ppf(a, dof * k) / k), float(stats.chi2.ppf(1 - a, dof * k) / k)


def score_navigation(sol: NavSolution, truth: NavSolution) -> dict:
    """Errors of ``sol`` against ``truth`` and, where covariances exist, NEES (module doc).

    Returns {block: {"rms": [3], "max_abs": [3], "rms_norm", "unit", "anees", "nees_interval",
    "consistent"}} for each block the solution reports.
    """
    t = np.asarray(sol.time_s, float)
    k = t.size
    if k < 1 or np.any(np.diff(t) <= 0):
        raise EstimatesError("solution time_s must be non-empty and strictly increasing")
    if t[0] < truth.time_s[0] or t[-1] > truth.time_s[-1]:
        raise EstimatesError(f"solution spans {t[0]:.3f}..{t[-1]:.3f} s, beyond the truth's "
                             f"{truth.time_s[0]:.3f}..{truth.time_s[-1]:.3f} s")
    out = {}
    blocks = (("position", "r_N", "P_r", "m"), ("velocity", "v_N", "P_v", "m/s"), ("attitude", "q_NB", "P_att", "rad"))
    for block, key, pkey, unit in blocks:
        x = getattr(sol, key)
        if x is None:
            continue
        xt = getattr(truth, key)
        if xt is None:
            raise EstimatesError(f"the truth holds no {block}; cannot score it")
        if key == "q_NB":
            x = _check(key, x, k, 4)
            qt = _interp(truth.time_s, np.asarray(xt, float), t)
            qt /= np.linalg.norm(qt, axis=1, keepdims=True)
            e = quat_to_rotvec(quat_mul(x / np.linalg.norm(x, axis=1, keepdims=True), quat_conj(qt)))
        else:
            x = _check(key, x, k, 3)
            e = x - _interp(truth.time_s, np.asarray(xt, float), t)
        r = {"unit": unit, "rms": np.sqrt(np.mean(e**2, axis=0)).tolist(),
             "max_abs": np.max(np.abs(e), axis=0).tolist(),
             "rms_norm": float(np.sqrt(np.mean(np.sum(e**2, axis=1))))}
        P = getattr(sol, pkey)
        if P is not None:
            P = np.asarray(P, float)
            if P.shape != (k, 3, 3):
                raise EstimatesError(f"{pkey} must have shape ({k}, 3, 3), got {P.shape}")
            nees = np.einsum("ki,ki->k", e, np.linalg.solve(P, e[..., None])[..., 0])
            lo, hi = nees_interval(k)
            a = float(np.mean(nees))
            r.update(anees=a, nees_interval=[lo, hi], consistent=bool(lo <= a <= hi))
        out[block] = r
    return out


def score_filter(nav_filter: NavFilter, streams: NavStreams, truth: NavSolution) -> dict:
    """Fit ``nav_filter`` on ``streams`` and score its ``solution_`` against ``truth``."""
    return score_navigation(fitted_solution(nav_filter, streams), truth)
