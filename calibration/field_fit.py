"""The two-step ellipse fit of a level magnetometer swing and the numerics the magnetometer fits share
(Gauss-Newton with step halving, the covariance from the final Jacobian, the step-1 checks).

Method: D. Gebre-Egziabher, G. Elkaim, J. D. Powell, B. Parkinson (2001), "A non-linear, two-step
estimation algorithm for calibrating solid-state strapdown magnetometers" ([Elk01] in the seed):
an algebraic linear least-squares fit of the conic (no initial guess needed), then Gauss-Newton
on the physical parameters with ``r_k = |A^-1 (m_k - b)| - F``; ``cov = s^2 (J'J)^-1`` from an SVD
of the column-scaled Jacobian, ``s^2 = SS_res / (n - p)``. Used through
:class:`imurig.calibration.magnetometer.MagnetometerCalibration`.
"""
from __future__ import annotations

import math
from typing import Callable

import numpy as np
import scipy.linalg

from imurig.calibration.heading import TWO_PI, finite_samples, positive_field
from imurig.calibration.regression import fit_ols
from imurig.kernel.errors import RecordingError, ScheduleError, UnidentifiableTermsError

#: 2-D parameters: A2 = [[sx, rho], [0, sy]] (dimensionless), b2 = (bx, by) [T].
ELLIPSE_PARAMS = ("sx", "sy", "rho", "bx", "by")


def cov_from_jacobian(J: np.ndarray, s2: float) -> np.ndarray:
    """``s2 (J'J)^-1`` via an SVD of the column-scaled ``J`` (no normal equations)."""
    d = np.linalg.norm(J, axis=0)
    d = np.where(d > 0, d, 1.0)
    _, sv, Vt = np.linalg.svd(J / d, full_matrices=False)
    if sv[-1] <= max(J.shape) * np.finfo(np.float64).eps * sv[0]:
        raise ScheduleError("the final Jacobian is rank deficient: the manoeuvre does not identify every "
                            "calibration parameter; cover more headings/orientations")
    W = Vt.T / sv
    cov = s2 * (W @ W.T) / np.outer(d, d)
    return 0.5 * (cov + cov.T)


def gauss_newton(theta0: np.ndarray, fun: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
                  max_iter: int, rtol: float):
    """Minimise ``sum r(theta)^2`` by Gauss-Newton with step halving.

    ``fun(theta) -> (r (n,), J (n, p))``. Each step solves ``J delta = -r`` by least squares
    (``scipy.linalg.lstsq`` on the column-scaled Jacobian). Converged when
    ``||delta|| <= rtol * max(||theta||, 1)``. Returns theta, r, J, iterations, converged.
    """
    theta = np.array(theta0, dtype=np.float64)
    r, J = fun(theta)
    ss = float(r @ r)
    converged = False
    it = 0
    while it < max_iter:
        it += 1
        d = np.linalg.norm(J, axis=0)
        d = np.where(d > 0, d, 1.0)
        sol, *_ = scipy.linalg.lstsq(J / d, -r, check_finite=False)
        delta = sol / d
        small = np.linalg.norm(delta) <= rtol * max(np.linalg.norm(theta), 1.0)
        step = 1.0
        for _ in range(30):
            cand = theta + step * delta
            r_c, J_c = fun(cand)
            ss_c = float(r_c @ r_c)
            if np.isfinite(ss_c) and ss_c <= ss * (1.0 + 1e-12):
                break
            step *= 0.5
        else:
            converged = bool(small)
            break
        theta, r, J, ss = cand, r_c, J_c, ss_c
        if small:
            converged = True
            break
    return theta, r, J, it, converged


def coverage_deg(d: np.ndarray) -> float:
    """Angular coverage [deg] of 2-D vectors ``d`` (n, 2) seen from the origin: 360 - largest gap."""
    ang = np.sort(np.arctan2(d[:, 1], d[:, 0]))
    gaps = np.diff(ang, append=ang[0] + TWO_PI)
    return float(np.degrees(TWO_PI - gaps.max()))


def check_semi_axes(A0: np.ndarray, bounds: tuple[float, float], F: float, fname: str, fix: str) -> None:
    """Refuse an initial shape whose semi-axes (singular values of A0, in units of F) are implausible."""
    sv = np.linalg.svd(A0, compute_uv=False)
    lo, hi = bounds
    if sv.min() < lo or sv.max() > hi:
        axes = ", ".join(f"{v * F * 1e9:.0f}" for v in sv)
        raise ScheduleError(
            f"the fitted {'ellipsoid' if A0.shape[0] == 3 else 'ellipse'} has semi-axes {axes} nT, outside "
            f"[{lo:g}, {hi:g}] x {fname} = {F * 1e9:.0f} nT: the data do not trace the expected field "
            f"locus; {fix}, and check the field intensity (tesla) and the nominal sensitivity")


def normalise(m: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Centre on the mean and scale by the RMS distance (conditioning of the algebraic fit)."""
    c = m.mean(axis=0)
    x = m - c
    L = float(np.sqrt(np.mean(np.sum(x * x, axis=1))))
    if L == 0.0:
        raise ScheduleError("all field samples are identical: the sensor did not move; "
                            "swing/tumble it through the required headings/orientations")
    return x / L, c, L



_NOT_ELLIPSE = ("not an ellipse: the swing did not turn through enough heading or the data are not from "
                "a level swing; swing the level sensor through at least {cov:g} deg of heading (a full "
                "360 deg turn is best)")


def _ellipse_residuals(theta: np.ndarray, m: np.ndarray):
    """r = |A2^-1 (m - b)| - 1 in units of H, and its Jacobian (n, 5) w.r.t. (sx, sy, rho, bx, by)."""
    sx, sy, rho, bx, by = theta
    dx, dy = m[:, 0] - bx, m[:, 1] - by
    # A2^-1 = [[1/sx, -rho/(sx sy)], [0, 1/sy]]
    hy = dy / sy
    hx = (dx - rho * hy) / sx
    nrm = np.hypot(hx, hy)
    ux, uy = hx / nrm, hy / nrm
    # w = A2^-T u ;  dr/dA_ij = -w_i h_j ;  dr/db = -w
    wx = ux / sx
    wy = (uy - rho * wx) / sy
    J = np.column_stack([-wx * hx, -wy * hy, -wx * hy, -wx, -wy])
    return nrm - 1.0, J


def _conic_start(m: np.ndarray, H: float, min_coverage_deg: float, scale_bounds) -> tuple[np.ndarray, float]:
    """Step 1 of the ellipse fit (see :func:`_fit_ellipse_2d`): the conic by linear least squares, its
    centre and the upper Cholesky factor of its shape. Returns (theta0 = (sx, sy, rho, bx/H, by/H),
    the heading coverage around the centre)."""
    n = m.shape[0]
    x, c0, L = normalise(m)
    X = np.column_stack([x[:, 0] ** 2, x[:, 0] * x[:, 1], x[:, 1] ** 2, x[:, 0], x[:, 1]])
    try:
        conic = fit_ols(X, np.ones(n), ["a", "b", "c", "d", "e"])
    except UnidentifiableTermsError as exc:
        raise ScheduleError(_NOT_ELLIPSE.format(cov=min_coverage_deg)
                            + f" (the conic is not identifiable from these samples: {exc})") from exc
    a, b, c, d, e = conic.coef_
    if b * b - 4.0 * a * c >= 0.0:
        raise ScheduleError(_NOT_ELLIPSE.format(cov=min_coverage_deg) + f" (b^2 - 4ac = {b * b - 4 * a * c:.3g} >= 0)")
    Q = np.array([[a, b / 2.0], [b / 2.0, c]])
    x0 = -0.5 * np.linalg.solve(Q, np.array([d, e]))
    g = 1.0 + float(x0 @ Q @ x0)
    P = Q / g
    if not np.all(np.linalg.eigvalsh(P) > 0):
        raise ScheduleError(_NOT_ELLIPSE.format(cov=min_coverage_deg) + " (the fitted ellipse is imaginary)")
    centre = c0 + L * x0
    coverage = coverage_deg(m - centre)
    if coverage < min_coverage_deg:
        raise ScheduleError(
            f"the swing covers only {coverage:.1f} deg of heading (need >= {min_coverage_deg:g} deg): an arc "
            f"does not determine the ellipse; swing the level sensor through a full 360 deg turn of heading")
    # shape in normalised units (m/H): |T (m/H - b/H)|^2 = 1 with T'T = (H/L)^2 P
    T0 = np.linalg.cholesky((H / L) ** 2 * P).T                # upper triangular, positive diagonal
    A0 = scipy.linalg.solve_triangular(T0, np.eye(2))
    check_semi_axes(A0, scale_bounds, H, "H", "swing the level sensor through a full 360 deg turn of heading")
    theta0 = np.array([A0[0, 0], A0[1, 1], A0[0, 1], centre[0] / H, centre[1] / H])
    return theta0, coverage


def _fit_ellipse_2d(mx, my, field_horizontal_T: float, *, min_coverage_deg: float = 180.0,
                    scale_bounds: tuple[float, float] = (0.5, 2.0), max_iter: int = 50,
                    rtol: float = 1e-10) -> dict:
    """Calibrate the horizontal magnetometer pair from a level swing (seed eq. 4.44-4.51, [Elk01]); the
    values of :class:`imurig.calibration.magnetometer.MagnetometerCalibration` (method 'ellipse').

    Parameters
    ----------
    mx, my : (n,) measured field along sensor x and y [T] (volts / nominal sensitivity), roll and
        pitch ~ 0, heading varied over (ideally) a full turn.
    field_horizontal_T : IGRF horizontal intensity H [T] at the site (e.g. 19010e-9).
    min_coverage_deg : smallest accepted heading coverage (360 minus the largest angular gap of
        ``m - centre`` around the step-1 centre, and around the final centre).
    scale_bounds : accepted range of the semi-axes of the fitted ellipse in units of H (the
        singular values of A2). A noisy short arc can produce a small ellipse whose centre lies
        next to the arc (so the arc seems to cover a wide angle); this check refuses it.

    Measurement equation::

        m_k = A2 h_k + b2 + e_k,   h_k = H (cos psi_k, -sin psi_k),   A2 = [[sx, rho], [0, sy]]

    (m_k, h_k, b2, e_k in tesla, shape (2,); sx, sy, rho dimensionless). A2 upper triangular fixes
    the unobservable rotation by taking the sensor's y axis as the reference direction: the x-axis
    non-orthogonality and the off-diagonal soft iron go into rho. A rotation of the whole pair
    (mounting yaw) is a constant heading offset that this fit cannot see.

    Step 1: ``a x^2 + b xy + c y^2 + d x + e y = 1`` by linear least squares (on centred, scaled
    data) -> centre ``x0 = -Q^-1 (d, e)/2`` with ``Q = [[a, b/2], [b/2, c]]``, shape
    ``(x - x0)' Q (x - x0) = 1 + x0' Q x0``; ``A2^-1`` is the upper Cholesky factor of the shape
    matrix scaled so the circle radius is H. Step 2: Gauss-Newton on
    ``r_k = |A2^-1 (m_k - b2)| - H`` for (sx, sy, rho, bx, by) until the relative step is below
    ``rtol`` or ``max_iter`` iterations; ``cov = s^2 (J'J)^-1``, ``s^2 = SS_res / (n - 5)``.

    Raises
    ------
    RecordingError : NaN/inf or non-numeric samples.
    ScheduleError : fewer than 10 samples, a conic that is not an ellipse, heading coverage below
        ``min_coverage_deg``, semi-axes outside ``scale_bounds`` x H, or an unidentifiable fit.
    """
    H = positive_field(field_horizontal_T, "field_horizontal_T")
    mx = finite_samples(mx, "mx", "(n,)")
    my = finite_samples(my, "my", "(n,)")
    if mx.ndim != 1 or mx.shape != my.shape:
        raise RecordingError(f"mx and my must be 1-D arrays of equal length, got shapes {mx.shape} and {my.shape}")
    n = mx.shape[0]
    if n < 10:
        raise ScheduleError(f"{n} samples for the 2-D magnetometer fit: need at least 10 (5 parameters); "
                            f"record more samples while swinging through the full heading circle")
    m = np.column_stack([mx, my])

    theta0, coverage = _conic_start(m, H, min_coverage_deg, scale_bounds)

    mn = m / H
    theta, r, J, it, conv = gauss_newton(theta0, lambda t: _ellipse_residuals(t, mn), max_iter, rtol)
    dof = n - 5
    s2 = float(r @ r) / dof
    cov_n = cov_from_jacobian(J, s2)
    unit = np.array([1.0, 1.0, 1.0, H, H])                      # normalised -> SI
    values = theta * unit
    cov = cov_n * np.outer(unit, unit)
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    sx, sy, rho, bx, by = values
    coverage_final = coverage_deg(m - values[3:])
    if coverage_final < min_coverage_deg:
        raise ScheduleError(
            f"the swing covers only {coverage_final:.1f} deg of heading around the fitted centre (need >= "
            f"{min_coverage_deg:g} deg); swing the level sensor through a full 360 deg turn of heading")
    A2 = np.array([[sx, rho], [0.0, sy]])
    T2 = np.array([[1.0 / sx, -rho / (sx * sy)], [0.0, 1.0 / sy]])
    res = r * H
    return {"names": ELLIPSE_PARAMS, "params": {k: float(v) for k, v in zip(ELLIPSE_PARAMS, values)},
            "std_errors": {k: float(v) for k, v in zip(ELLIPSE_PARAMS, se)}, "cov": cov, "A": A2,
            "b": np.array([bx, by]), "T": T2, "field_T": H, "n": n, "residuals": res,
            "rms_residual_T": float(np.sqrt(np.mean(res ** 2))), "max_abs_residual_T": float(np.max(np.abs(res))),
            "sigma": math.sqrt(s2) * H, "coverage_deg": coverage,
            "initial": {k: float(v) for k, v in zip(ELLIPSE_PARAMS, theta0 * unit)}, "n_iter": it, "converged": conv}
