"""The two-step ellipsoid fit of a tumbled magnetometer triad ([Elk01]; seed section 4.7), used through
:class:`imurig.calibration.magnetometer.MagnetometerCalibration`.

Measurement equation::

    m_k = A B_k + b + e_k,   |B_k| = F,   A = T^-1,   T upper triangular (6 entries)

(m_k, B_k, b, e_k in tesla, shape (3,); A, T dimensionless). ``A`` is identifiable only up to
a rotation (``A R`` gives the same data); the upper-triangular T fixes it. Compare ``b`` and
``A A'`` (rotation invariant) with a truth.
"""
from __future__ import annotations

import math

import numpy as np
import scipy.linalg

from imurig.calibration.field_fit import check_semi_axes, cov_from_jacobian, gauss_newton, normalise
from imurig.calibration.heading import finite_samples, positive_field
from imurig.calibration.regression import fit_ols
from imurig.kernel.errors import RecordingError, ScheduleError, UnidentifiableTermsError

#: 3-D parameters: T = A^-1 upper triangular (dimensionless), b [T].
ELLIPSOID_PARAMS = ("T_xx", "T_xy", "T_xz", "T_yy", "T_yz", "T_zz", "bx", "by", "bz")
_T_INDEX = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
#: Unique entries of the symmetric A A' (row-major upper triangle).
AAT_NAMES = ("AAt_xx", "AAt_xy", "AAt_xz", "AAt_yy", "AAt_yz", "AAt_zz")


_TUMBLE = ("tumble the sensor through more orientations (the field must point in directions spread over "
           "the whole sphere of the sensor frame, e.g. the 24 cube attitudes or a random tumble; a level "
           "swing or a small cone is not enough)")


def _direction_spread(d: np.ndarray) -> float:
    """Smallest eigenvalue of the covariance of the unit vectors of ``d`` (n, 3)."""
    u = d / np.linalg.norm(d, axis=1)[:, None]
    return float(np.linalg.eigvalsh(np.cov(u, rowvar=False))[0])


def _check_spread(spread: float, minimum: float, where: str = "") -> None:
    if spread < minimum:
        raise ScheduleError(f"the field directions{where} do not span the sphere (direction spread {spread:.3g} "
                            f"< {minimum:g}; uniform = 0.333); " + _TUMBLE)


def _T_from_theta(t: np.ndarray) -> np.ndarray:
    T = np.zeros((3, 3))
    for k, (i, j) in enumerate(_T_INDEX):
        T[i, j] = t[k]
    return T


def _ellipsoid_residuals(theta: np.ndarray, m: np.ndarray):
    """r = |T (m - b)| - 1 in units of F, Jacobian (n, 9) w.r.t. (T upper entries, b)."""
    T = _T_from_theta(theta[:6])
    dlt = m - theta[6:]
    h = dlt @ T.T
    nrm = np.linalg.norm(h, axis=1)
    u = h / nrm[:, None]
    # dr/dT_ij = u_i d_j ; dr/db = -T' u
    JT = np.column_stack([u[:, i] * dlt[:, j] for i, j in _T_INDEX])
    Jb = -(u @ T)
    return nrm - 1.0, np.hstack([JT, Jb])


def _quadric_start(m: np.ndarray, F: float, min_direction_spread: float, scale_bounds) -> tuple[np.ndarray, float]:
    """Step 1: the general quadric m'Qm + u'm + k = 0 by linear least squares of the 9 coefficients of
    x'Qx + u'x = 1 on centred, scaled data: centre b0 = -Q^-1 u / 2 and T0 the upper Cholesky factor of
    the shape matrix scaled so the sphere radius is F. Returns (theta0 (9,) in units of F, the
    direction spread around b0)."""
    n = m.shape[0]
    x, c0, L = normalise(m)
    X = np.column_stack([x[:, 0] ** 2, x[:, 1] ** 2, x[:, 2] ** 2, x[:, 0] * x[:, 1], x[:, 0] * x[:, 2],
                         x[:, 1] * x[:, 2], x[:, 0], x[:, 1], x[:, 2]])
    try:
        quad = fit_ols(X, np.ones(n), ["xx", "yy", "zz", "xy", "xz", "yz", "x", "y", "z"])
    except UnidentifiableTermsError as exc:
        raise ScheduleError(f"the ellipsoid is not identifiable from these samples ({exc}); " + _TUMBLE) from exc
    qa, qb, qc, qd, qe, qf, u1, u2, u3 = quad.coef_
    Q = np.array([[qa, qd / 2, qe / 2], [qd / 2, qb, qf / 2], [qe / 2, qf / 2, qc]])
    u = np.array([u1, u2, u3])
    try:
        x0 = -0.5 * np.linalg.solve(Q, u)
    except np.linalg.LinAlgError as exc:
        raise ScheduleError("the fitted quadric is not an ellipsoid (singular shape matrix); " + _TUMBLE) from exc
    g = 1.0 + float(x0 @ Q @ x0)
    P = Q / g
    ev = np.linalg.eigvalsh(P)
    if not np.all(ev > 0):
        raise ScheduleError(f"the fitted quadric is not an ellipsoid (shape eigenvalues {ev.round(4).tolist()}); "
                            + _TUMBLE)
    b0 = c0 + L * x0
    spread = _direction_spread(m - b0)
    _check_spread(spread, min_direction_spread)
    T0 = np.linalg.cholesky((F / L) ** 2 * P).T               # upper triangular, positive diagonal
    check_semi_axes(scipy.linalg.solve_triangular(T0, np.eye(3)), scale_bounds, F, "F", _TUMBLE)
    theta0 = np.concatenate([[T0[i, j] for i, j in _T_INDEX], b0 / F])
    return theta0, spread


def _delta_method(T: np.ndarray, A: np.ndarray, AAt: np.ndarray, cov: np.ndarray):
    """Standard errors of A = T^-1 (dA = -A dT A) and of the invariants (A A' unique entries, b), with
    AAt = (T'T)^-1 (dAAt = -AAt (dT'T + T'dT) AAt), from the parameters' covariance ``cov`` (9, 9).
    Returns (A_std (3, 3), AAt_std (3, 3), invariant covariance (9, 9))."""
    GA = np.zeros((9, 9))          # d vec(A) / d T-params (first 6 columns)
    Ginv = np.zeros((9, 9))        # d (AAt unique, b) / d params
    iu = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)]
    for k, (i, j) in enumerate(_T_INDEX):
        E = np.zeros((3, 3))
        E[i, j] = 1.0
        GA[:, k] = (-A @ E @ A).ravel()
        dM = E.T @ T + T.T @ E
        dAAt = -AAt @ dM @ AAt
        Ginv[:6, k] = [dAAt[p, q] for p, q in iu]
    Ginv[6:, 6:] = np.eye(3)
    A_std = np.sqrt(np.clip(np.diag(GA @ cov @ GA.T), 0.0, None)).reshape(3, 3)
    inv_cov = Ginv @ cov @ Ginv.T
    inv_cov = 0.5 * (inv_cov + inv_cov.T)
    inv_se = np.sqrt(np.clip(np.diag(inv_cov), 0.0, None))
    AAt_std = np.zeros((3, 3))
    for k, (p, q) in enumerate(iu):
        AAt_std[p, q] = AAt_std[q, p] = inv_se[k]
    return A_std, AAt_std, inv_cov


def _fit_ellipsoid_3d(m, field_total_T: float, *, min_direction_spread: float = 0.01,
                      scale_bounds: tuple[float, float] = (0.5, 2.0), max_iter: int = 50,
                      rtol: float = 1e-10) -> dict:
    """Calibrate a magnetometer triad from a 3-D tumble ([Elk01] ellipsoid; seed section 4.7); the values
    of :class:`imurig.calibration.magnetometer.MagnetometerCalibration` (method 'ellipsoid').

    Parameters
    ----------
    m : (n, 3) measured field [T] (volts / nominal sensitivity) in many orientations.
    field_total_T : IGRF total intensity F [T] at the site (e.g. 48724e-9).
    min_direction_spread : smallest accepted eigenvalue of the covariance of the unit directions
        of ``m - b0`` (b0: step-1 centre). Uniform on the sphere gives 1/3, a hemisphere 1/12,
        a cap of half-angle a gives (1 - cos a)^2 / 12 along its axis, a single plane 0.
    scale_bounds : accepted range of the semi-axes of the step-1 ellipsoid in units of F.

    Measurement equation::

        m_k = A B_k + b + e_k,   |B_k| = F,   A = T^-1,   T upper triangular (6 entries)

    (m_k, B_k, b, e_k in tesla, shape (3,); A, T dimensionless). ``A`` is identifiable only up to
    a rotation (``A R`` gives the same data); the upper-triangular T fixes it. Compare ``b`` and
    ``A A'`` (rotation invariant) with a truth.

    Step 1: general quadric ``m'Qm + u'm + k = 0`` by linear least squares of the 9 coefficients
    of ``x'Qx + u'x = 1`` on centred, scaled data -> centre ``b0 = -Q^-1 u / 2`` and
    ``T0`` = upper Cholesky factor of the shape matrix scaled so the sphere radius is F.
    Step 2: Gauss-Newton on ``r_k = |T (m_k - b)| - F`` for the 9 parameters; covariance
    ``s^2 (J'J)^-1``, ``s^2 = SS_res / (n - 9)``; AAt and A errors by the delta method.

    Raises
    ------
    RecordingError : NaN/inf, non-numeric or mis-shaped samples.
    ScheduleError : fewer than 20 samples, unidentifiable quadric, quadric not an ellipsoid,
        semi-axes outside ``scale_bounds`` x F, or directions that do not span the sphere.
    """
    F = positive_field(field_total_T, "field_total_T")
    m = finite_samples(m, "m", "(n, 3)")
    if m.ndim != 2 or m.shape[1] != 3:
        raise RecordingError(f"m must have shape (n, 3) (x, y, z field in tesla), got {m.shape}")
    n = m.shape[0]
    if n < 20:
        raise ScheduleError(f"{n} samples for the 3-D magnetometer fit: need at least 20 (9 parameters); "
                            f"record more samples and " + _TUMBLE)

    theta0, spread = _quadric_start(m, F, min_direction_spread, scale_bounds)

    # --- step 2: Gauss-Newton ------------------------------------------------------------------
    mn = m / F
    theta, r, J, it, conv = gauss_newton(theta0, lambda t: _ellipsoid_residuals(t, mn), max_iter, rtol)
    dof = n - 9
    s2 = float(r @ r) / dof
    cov_n = cov_from_jacobian(J, s2)
    unit = np.concatenate([np.ones(6), np.full(3, F)])
    values = theta * unit
    cov = cov_n * np.outer(unit, unit)
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    _check_spread(_direction_spread(m - values[6:]), min_direction_spread, " around the fitted centre")
    T = _T_from_theta(values[:6])
    A = scipy.linalg.solve_triangular(T, np.eye(3))
    b = values[6:]
    AAt = A @ A.T

    A_std, AAt_std, inv_cov = _delta_method(T, A, AAt, cov)
    res = r * F
    return {"names": ELLIPSOID_PARAMS, "params": {k: float(v) for k, v in zip(ELLIPSOID_PARAMS, values)},
            "std_errors": {k: float(v) for k, v in zip(ELLIPSOID_PARAMS, se)}, "cov": cov, "T": T, "A": A, "b": b,
            "A_std": A_std, "b_std": se[6:].copy(), "AAt": AAt, "AAt_std": AAt_std,
            "invariant_names": AAT_NAMES + ("bx", "by", "bz"), "invariant_cov": inv_cov, "field_T": F, "n": n,
            "residuals": res, "rms_residual_T": float(np.sqrt(np.mean(res ** 2))),
            "max_abs_residual_T": float(np.max(np.abs(res))), "sigma": math.sqrt(s2) * F,
            "direction_spread": spread, "initial": {k: float(v) for k, v in zip(ELLIPSOID_PARAMS, theta0 * unit)},
            "n_iter": it, "converged": conv}
