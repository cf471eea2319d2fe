"""Magnetometer calibration in the field domain and in the heading domain (seed sections 4.6-4.7).

Method: D. Gebre-Egziabher, G. Elkaim, J. D. Powell, B. Parkinson (2001), "A non-linear, two-step
estimation algorithm for calibrating solid-state strapdown magnetometers" ([Elk01] in the seed;
applied in the appended paper, section 3.2 and Fig. 5). The locus of error-free measurements of
a level pair of orthogonal magnetometers is a circle of radius B_H (seed eq. 4.44); hard iron
moves its centre (eq. 4.45-4.47), scale factors and soft iron stretch it into an ellipse
(eq. 4.48-4.51), misalignment/soft iron rotate its axes (Fig. 4.24). In 3-D the sphere of radius
|B| becomes an ellipsoid. The calibration fits that ellipse (ellipsoid) in two steps:

1. an algebraic linear least-squares fit of the conic (quadric) - no initial guess needed;
   its centre and shape give the initial hard iron and the initial shape matrix;
2. a Gauss-Newton (iterated linear least squares) refinement of the physical parameters on the
   residuals ``r_k = |A^-1 (m_k - b)| - F`` with ``F`` the known (IGRF) field intensity; the
   parameter covariance is ``s^2 (J'J)^-1`` from the final Jacobian, ``s^2 = SS_res / (n - p)``
   (computed from an SVD of the column-scaled Jacobian; the normal equations are never formed).

Sensor model (SI, tesla)::

    m = A B_C + b + e            m, B_C, b, e: (3,) or (n, 3) [T];  A: (3, 3) dimensionless

``m`` is the measured field (volts divided by the nominal sensitivity), ``B_C`` the true field
in the sensor/case frame, ``A = diag(s) S_soft (I + M)`` (scale, soft iron, misalignment),
``b`` the hard-iron bias, ``e`` white noise. Only ``|B_C|`` is known, so ``A`` is identifiable
only up to a rotation: ``A R`` (``R`` orthogonal) explains the data equally well. The fits below
fix the rotation by making ``A`` (equivalently ``A^-1``) upper triangular with a positive
diagonal; the rotation-invariant quantities are ``A A'`` and ``b``. A residual rotation about the
vertical is a constant heading offset that no field-domain method can see; it is the ``A``
coefficient of the heading-domain swing (:func:`compass_swing`) or needs a heading reference.

Heading convention (used everywhere in this module)
---------------------------------------------------
Heading ``psi`` is measured from (magnetic) north, positive clockwise seen from above
(north = 0, east = pi/2), in radians, wrapped to [0, 2 pi). Body/sensor axes default to the
aerospace **FRD** convention (x forward, y right, z down - the body counterpart of the NED
navigation frame). A level sensor then measures the horizontal field ``H`` as (seed eq. 4.48/4.49)::

    h_x = H cos(psi),   h_y = -H sin(psi)       ->   psi = atan2(-h_y, h_x)

For **FLU** body axes (x forward, y left, z up - the body counterpart of the ENU frame used by the
rigs, see :mod:`imurig.kernel.site`) ``h_y = +H sin(psi)`` and ``psi = atan2(h_y, h_x)``; pass
``frame="FLU"``. True heading = magnetic heading + declination (declination positive east).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import scipy.linalg

from imurig.calibration.regression import fit_ols
from imurig.kernel.errors import RecordingError, ScheduleError, UnidentifiableTermsError

__all__ = [
    "wrap_pi",
    "wrap_2pi",
    "heading_from_field",
    "fit_ellipse_2d",
    "Ellipse2DResult",
    "fit_ellipsoid_3d",
    "Ellipsoid3DResult",
    "compass_swing",
    "SwingResult",
    "ELLIPSE_PARAMS",
    "ELLIPSOID_PARAMS",
    "SWING_TERMS",
]

TWO_PI = 2.0 * math.pi
FRAMES = ("FRD", "FLU")

#: 2-D parameters: A2 = [[sx, rho], [0, sy]] (dimensionless), b2 = (bx, by) [T].
ELLIPSE_PARAMS = ("sx", "sy", "rho", "bx", "by")
#: 3-D parameters: T = A^-1 upper triangular (dimensionless), b [T].
ELLIPSOID_PARAMS = ("T_xx", "T_xy", "T_xz", "T_yy", "T_yz", "T_zz", "bx", "by", "bz")
_T_INDEX = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
#: Unique entries of the symmetric A A' (row-major upper triangle).
AAT_NAMES = ("AAt_xx", "AAt_xy", "AAt_xz", "AAt_yy", "AAt_yz", "AAt_zz")
#: Heading-domain deviation terms (seed eq. 4.42-4.43).
SWING_TERMS = ("A", "B", "C", "D", "E")


# ---------------------------------------------------------------------------
# angles and heading


def _scalar_or_array(x: np.ndarray):
    return float(x) if np.ndim(x) == 0 else x


def wrap_pi(angle):
    """Wrap angle(s) [rad] to (-pi, pi]. Scalars give floats, arrays keep their shape."""
    a = np.asarray(angle, dtype=np.float64)
    w = np.mod(a + math.pi, TWO_PI) - math.pi          # [-pi, pi)
    w = np.where(w <= -math.pi, w + TWO_PI, w)         # -pi -> +pi
    return _scalar_or_array(w)


def wrap_2pi(angle):
    """Wrap angle(s) [rad] to [0, 2 pi)."""
    w = np.mod(np.asarray(angle, dtype=np.float64), TWO_PI)
    w = np.where(w >= TWO_PI, 0.0, w)                  # mod can round up to 2 pi for tiny negatives
    return _scalar_or_array(w)


def _check_frame(frame: str) -> None:
    if frame not in FRAMES:
        raise ValueError(f"frame must be one of {FRAMES} (FRD: x fwd, y right, z down; FLU: x fwd, y left, "
                         f"z up), got {frame!r}")


def heading_from_field(h_xy, hy=None, declination_rad: float = 0.0, *, frame: str = "FRD"):
    """Heading [rad, [0, 2 pi)] from the calibrated horizontal field of a level sensor.

    Call as ``heading_from_field(h_xy)`` with ``h_xy`` of shape (n, 2) (or (2,)), or as
    ``heading_from_field(hx, hy)`` with two arrays of equal shape; tesla or any common unit.

    Measurement equation (level sensor, horizontal intensity H [T], magnetic heading psi_m)::

        FRD (x fwd, y right, z down):  hx = H cos psi_m,  hy = -H sin psi_m  ->  psi_m = atan2(-hy, hx)
        FLU (x fwd, y left,  z up):    hx = H cos psi_m,  hy = +H sin psi_m  ->  psi_m = atan2(+hy, hx)

    Returns ``psi = wrap_2pi(psi_m + declination_rad)`` (true heading if the declination, positive
    east, is given; magnetic heading for the default 0). Clockwise from north seen from above.
    """
    _check_frame(frame)
    if hy is None:
        h = np.asarray(h_xy, dtype=np.float64)
        if h.shape[-1:] != (2,):
            raise ValueError(f"h_xy must have shape (n, 2) or (2,), got {h.shape}; or pass hx, hy separately")
        hx, hy_ = h[..., 0], h[..., 1]
    else:
        hx = np.asarray(h_xy, dtype=np.float64)
        hy_ = np.asarray(hy, dtype=np.float64)
        if hx.shape != hy_.shape:
            raise ValueError(f"hx and hy must have the same shape, got {hx.shape} and {hy_.shape}")
    sign = -1.0 if frame == "FRD" else 1.0
    return wrap_2pi(np.arctan2(sign * hy_, hx) + float(declination_rad))


# ---------------------------------------------------------------------------
# input checks


def _finite_field(arr, what: str, shape_hint: str) -> np.ndarray:
    a = np.asarray(arr)
    if a.dtype.kind not in "biuf":
        raise RecordingError(f"{what} must be a real numeric array ({shape_hint}, tesla), got dtype {a.dtype}")
    a = a.astype(np.float64, copy=False)
    bad = ~np.isfinite(a)
    if bad.any():
        rows = np.flatnonzero(bad.reshape(a.shape[0], -1).any(axis=1)) if a.ndim else np.array([0])
        raise RecordingError(
            f"{what} contains NaN/inf in {rows.size} of {a.shape[0] if a.ndim else 1} samples "
            f"(first: {rows[:5].tolist()}); drop or repair those samples (e.g. ADC dropouts) before calibrating")
    return a


def _positive_field(value, what: str) -> float:
    v = float(value)
    if not math.isfinite(v) or v <= 0:
        raise ValueError(f"{what} must be a positive field intensity in tesla (e.g. 19010e-9 from IGRF), got {value!r}")
    if v > 1e-3:
        raise ValueError(f"{what}={v!r} looks like nT, not tesla: the Earth's field is ~2e-5 to 6.5e-5 T; "
                         f"multiply nT by 1e-9")
    return v


# ---------------------------------------------------------------------------
# shared numerics


def _cov_from_jacobian(J: np.ndarray, s2: float) -> np.ndarray:
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


def _gauss_newton(theta0: np.ndarray, fun: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
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


def _coverage_deg(d: np.ndarray) -> float:
    """Angular coverage [deg] of 2-D vectors ``d`` (n, 2) seen from the origin: 360 - largest gap."""
    ang = np.sort(np.arctan2(d[:, 1], d[:, 0]))
    gaps = np.diff(ang, append=ang[0] + TWO_PI)
    return float(np.degrees(TWO_PI - gaps.max()))


def _check_semi_axes(A0: np.ndarray, bounds: tuple[float, float], F: float, fname: str, fix: str) -> None:
    """Refuse an initial shape whose semi-axes (singular values of A0, in units of F) are implausible."""
    sv = np.linalg.svd(A0, compute_uv=False)
    lo, hi = bounds
    if sv.min() < lo or sv.max() > hi:
        axes = ", ".join(f"{v * F * 1e9:.0f}" for v in sv)
        raise ScheduleError(
            f"the fitted {'ellipsoid' if A0.shape[0] == 3 else 'ellipse'} has semi-axes {axes} nT, outside "
            f"[{lo:g}, {hi:g}] x {fname} = {F * 1e9:.0f} nT: the data do not trace the expected field "
            f"locus; {fix}, and check the field intensity (tesla) and the nominal sensitivity")


def _normalise(m: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Centre on the mean and scale by the RMS distance (conditioning of the algebraic fit)."""
    c = m.mean(axis=0)
    x = m - c
    L = float(np.sqrt(np.mean(np.sum(x * x, axis=1))))
    if L == 0.0:
        raise ScheduleError("all field samples are identical: the sensor did not move; "
                            "swing/tumble it through the required headings/orientations")
    return x / L, c, L


# ---------------------------------------------------------------------------
# 2-D: level swing


@dataclass
class Ellipse2DResult:
    """Two-step fit of a level swing (see :func:`fit_ellipse_2d`).

    Model (n samples, SI)::

        m_xy = A2 h + b2 + e     m_xy, h, e: (n, 2) [T]; A2 = [[sx, rho], [0, sy]]; b2 = (bx, by) [T]
        h    = H (cos psi, -sin psi)   (FRD axes; |h| = H, the IGRF horizontal intensity [T])

    Fields: ``params``/``std_errors`` dicts over ``names`` = (sx, sy, rho, bx, by) (scale factors
    and rho dimensionless, bx/by in tesla), ``cov`` (5, 5) in the same units, ``A2`` (2, 2),
    ``b2`` (2,) [T], ``T2 = A2^-1``, ``residuals_T`` (n,) = |A2^-1 (m - b2)| - H [T],
    ``rms_residual_T``, ``max_abs_residual_T``, ``sigma_T = sqrt(SS_res / (n - 5))`` [T],
    ``coverage_deg`` (heading coverage seen from the step-1 centre), ``initial`` (step-1 params),
    ``iterations``, ``converged``.
    """

    names: tuple[str, ...]
    params: dict[str, float]
    std_errors: dict[str, float]
    cov: np.ndarray
    A2: np.ndarray
    b2: np.ndarray
    T2: np.ndarray
    field_horizontal_T: float
    n: int
    residuals_T: np.ndarray = field(repr=False)
    rms_residual_T: float
    max_abs_residual_T: float
    sigma_T: float
    coverage_deg: float
    initial: dict[str, float]
    iterations: int
    converged: bool

    def apply(self, mx, my) -> tuple[np.ndarray, np.ndarray]:
        """Calibrated horizontal field ``(hx, hy) = A2^-1 (m_xy - b2)`` [T], same shape as ``mx``."""
        mx = np.asarray(mx, dtype=np.float64)
        my = np.asarray(my, dtype=np.float64)
        dx, dy = mx - self.b2[0], my - self.b2[1]
        T = self.T2
        return T[0, 0] * dx + T[0, 1] * dy, T[1, 1] * dy

    def heading(self, mx, my, declination_rad: float = 0.0, *, frame: str = "FRD"):
        """Heading [rad, [0, 2 pi)] of the level sensor from raw ``mx, my`` [T]; see :func:`heading_from_field`."""
        hx, hy = self.apply(mx, my)
        return heading_from_field(hx, hy, declination_rad, frame=frame)

    def to_dict(self) -> dict:
        return {"kind": "imurig.magnetometer_ellipse_2d", "names": list(self.names),
                "params": dict(self.params), "std_errors": dict(self.std_errors),
                "cov": self.cov.tolist(), "A2": self.A2.tolist(), "b2_T": self.b2.tolist(),
                "field_horizontal_T": self.field_horizontal_T, "n": self.n,
                "rms_residual_T": self.rms_residual_T, "max_abs_residual_T": self.max_abs_residual_T,
                "sigma_T": self.sigma_T, "coverage_deg": self.coverage_deg, "initial": dict(self.initial),
                "iterations": self.iterations, "converged": self.converged}


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


def fit_ellipse_2d(mx, my, field_horizontal_T: float, *, min_coverage_deg: float = 180.0,
                   scale_bounds: tuple[float, float] = (0.5, 2.0), max_iter: int = 50,
                   rtol: float = 1e-10) -> Ellipse2DResult:
    """Calibrate the horizontal magnetometer pair from a level swing (seed eq. 4.44-4.51, [Elk01]).

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
    H = _positive_field(field_horizontal_T, "field_horizontal_T")
    mx = _finite_field(mx, "mx", "(n,)")
    my = _finite_field(my, "my", "(n,)")
    if mx.ndim != 1 or mx.shape != my.shape:
        raise RecordingError(f"mx and my must be 1-D arrays of equal length, got shapes {mx.shape} and {my.shape}")
    n = mx.shape[0]
    if n < 10:
        raise ScheduleError(f"{n} samples for the 2-D magnetometer fit: need at least 10 (5 parameters); "
                            f"record more samples while swinging through the full heading circle")
    m = np.column_stack([mx, my])

    # --- step 1: algebraic conic fit -----------------------------------------------------
    x, c0, L = _normalise(m)
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
    coverage = _coverage_deg(m - centre)
    if coverage < min_coverage_deg:
        raise ScheduleError(
            f"the swing covers only {coverage:.1f} deg of heading (need >= {min_coverage_deg:g} deg): an arc "
            f"does not determine the ellipse; swing the level sensor through a full 360 deg turn of heading")
    # shape in normalised units (m/H): |T (m/H - b/H)|^2 = 1 with T'T = (H/L)^2 P
    T0 = np.linalg.cholesky((H / L) ** 2 * P).T                # upper triangular, positive diagonal
    A0 = scipy.linalg.solve_triangular(T0, np.eye(2))
    _check_semi_axes(A0, scale_bounds, H, "H", "swing the level sensor through a full 360 deg turn of heading")
    theta0 = np.array([A0[0, 0], A0[1, 1], A0[0, 1], centre[0] / H, centre[1] / H])

    # --- step 2: Gauss-Newton on the physical parameters ------------------------------------
    mn = m / H
    theta, r, J, it, conv = _gauss_newton(theta0, lambda t: _ellipse_residuals(t, mn), max_iter, rtol)
    dof = n - 5
    s2 = float(r @ r) / dof
    cov_n = _cov_from_jacobian(J, s2)
    unit = np.array([1.0, 1.0, 1.0, H, H])                      # normalised -> SI
    values = theta * unit
    cov = cov_n * np.outer(unit, unit)
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    sx, sy, rho, bx, by = values
    coverage_final = _coverage_deg(m - values[3:])
    if coverage_final < min_coverage_deg:
        raise ScheduleError(
            f"the swing covers only {coverage_final:.1f} deg of heading around the fitted centre (need >= "
            f"{min_coverage_deg:g} deg); swing the level sensor through a full 360 deg turn of heading")
    A2 = np.array([[sx, rho], [0.0, sy]])
    T2 = np.array([[1.0 / sx, -rho / (sx * sy)], [0.0, 1.0 / sy]])
    res = r * H
    return Ellipse2DResult(
        names=ELLIPSE_PARAMS,
        params={k: float(v) for k, v in zip(ELLIPSE_PARAMS, values)},
        std_errors={k: float(v) for k, v in zip(ELLIPSE_PARAMS, se)},
        cov=cov, A2=A2, b2=np.array([bx, by]), T2=T2, field_horizontal_T=H, n=n,
        residuals_T=res, rms_residual_T=float(np.sqrt(np.mean(res ** 2))),
        max_abs_residual_T=float(np.max(np.abs(res))), sigma_T=math.sqrt(s2) * H,
        coverage_deg=coverage,
        initial={k: float(v) for k, v in zip(ELLIPSE_PARAMS, theta0 * unit)},
        iterations=it, converged=conv)


# ---------------------------------------------------------------------------
# 3-D: tumbling


@dataclass
class Ellipsoid3DResult:
    """Two-step fit of a 3-D tumble (see :func:`fit_ellipsoid_3d`).

    Model (n samples, SI)::

        m = A B + b + e,   |B| = F        m, B, b, e: (n, 3) [T];  A = T^-1: (3, 3), upper triangular

    Fields: ``T`` (3, 3) = A^-1, ``A`` (3, 3), ``b`` (3,) [T]; ``params``/``std_errors`` over
    ``names`` = (T_xx, T_xy, T_xz, T_yy, T_yz, T_zz, bx, by, bz) (T dimensionless, b in tesla),
    ``cov`` (9, 9); ``A_std`` (3, 3) and ``b_std`` (3,) standard errors (delta method);
    rotation-invariant truth-comparison quantities ``AAt = A A'`` (3, 3) with ``AAt_std`` (3, 3)
    and ``invariant_cov`` (9, 9) over ``invariant_names`` (6 unique AAt entries, bx, by, bz);
    ``residuals_T`` (n,) = |T (m - b)| - F [T], ``rms_residual_T``, ``max_abs_residual_T``,
    ``sigma_T = sqrt(SS_res / (n - 9))``, ``direction_spread`` (smallest eigenvalue of the
    covariance of the unit directions of m - b0), ``initial`` (step-1 params), ``iterations``,
    ``converged``.

    ``A`` is identifiable only up to a rotation (``A R`` fits the same data); compare ``b`` and
    ``A A'`` with the truth, not ``A``.
    """

    names: tuple[str, ...]
    params: dict[str, float]
    std_errors: dict[str, float]
    cov: np.ndarray
    T: np.ndarray
    A: np.ndarray
    b: np.ndarray
    A_std: np.ndarray
    b_std: np.ndarray
    AAt: np.ndarray
    AAt_std: np.ndarray
    invariant_names: tuple[str, ...]
    invariant_cov: np.ndarray
    field_total_T: float
    n: int
    residuals_T: np.ndarray = field(repr=False)
    rms_residual_T: float
    max_abs_residual_T: float
    sigma_T: float
    direction_spread: float
    initial: dict[str, float]
    iterations: int
    converged: bool

    def apply(self, m) -> np.ndarray:
        """Calibrated field ``T (m - b)`` [T], shape (n, 3) (or (3,)) like ``m``."""
        m = np.asarray(m, dtype=np.float64)
        if m.shape[-1:] != (3,):
            raise ValueError(f"m must have shape (n, 3) or (3,), got {m.shape}")
        return (m - self.b) @ self.T.T

    def to_dict(self) -> dict:
        return {"kind": "imurig.magnetometer_ellipsoid_3d", "names": list(self.names),
                "params": dict(self.params), "std_errors": dict(self.std_errors), "cov": self.cov.tolist(),
                "T": self.T.tolist(), "A": self.A.tolist(), "b_T": self.b.tolist(),
                "A_std": self.A_std.tolist(), "b_std_T": self.b_std.tolist(),
                "AAt": self.AAt.tolist(), "AAt_std": self.AAt_std.tolist(),
                "field_total_T": self.field_total_T, "n": self.n, "rms_residual_T": self.rms_residual_T,
                "max_abs_residual_T": self.max_abs_residual_T, "sigma_T": self.sigma_T,
                "direction_spread": self.direction_spread, "initial": dict(self.initial),
                "iterations": self.iterations, "converged": self.converged}


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


def fit_ellipsoid_3d(m, field_total_T: float, *, min_direction_spread: float = 0.01,
                     scale_bounds: tuple[float, float] = (0.5, 2.0), max_iter: int = 50,
                     rtol: float = 1e-10) -> Ellipsoid3DResult:
    """Calibrate a magnetometer triad from a 3-D tumble ([Elk01] ellipsoid; seed section 4.7).

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
    F = _positive_field(field_total_T, "field_total_T")
    m = _finite_field(m, "m", "(n, 3)")
    if m.ndim != 2 or m.shape[1] != 3:
        raise RecordingError(f"m must have shape (n, 3) (x, y, z field in tesla), got {m.shape}")
    n = m.shape[0]
    if n < 20:
        raise ScheduleError(f"{n} samples for the 3-D magnetometer fit: need at least 20 (9 parameters); "
                            f"record more samples and " + _TUMBLE)

    # --- step 1: algebraic quadric fit -----------------------------------------------------
    x, c0, L = _normalise(m)
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
    _check_semi_axes(scipy.linalg.solve_triangular(T0, np.eye(3)), scale_bounds, F, "F", _TUMBLE)
    theta0 = np.concatenate([[T0[i, j] for i, j in _T_INDEX], b0 / F])

    # --- step 2: Gauss-Newton ------------------------------------------------------------------
    mn = m / F
    theta, r, J, it, conv = _gauss_newton(theta0, lambda t: _ellipsoid_residuals(t, mn), max_iter, rtol)
    dof = n - 9
    s2 = float(r @ r) / dof
    cov_n = _cov_from_jacobian(J, s2)
    unit = np.concatenate([np.ones(6), np.full(3, F)])
    values = theta * unit
    cov = cov_n * np.outer(unit, unit)
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    _check_spread(_direction_spread(m - values[6:]), min_direction_spread, " around the fitted centre")
    T = _T_from_theta(values[:6])
    A = scipy.linalg.solve_triangular(T, np.eye(3))
    b = values[6:]
    AAt = A @ A.T

    # --- delta method: A = T^-1 (dA = -A dT A), AAt = (T'T)^-1 (dAAt = -AAt (dT'T + T'dT) AAt)
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
    res = r * F
    return Ellipsoid3DResult(
        names=ELLIPSOID_PARAMS,
        params={k: float(v) for k, v in zip(ELLIPSOID_PARAMS, values)},
        std_errors={k: float(v) for k, v in zip(ELLIPSOID_PARAMS, se)},
        cov=cov, T=T, A=A, b=b, A_std=A_std, b_std=se[6:].copy(), AAt=AAt, AAt_std=AAt_std,
        invariant_names=AAT_NAMES + ("bx", "by", "bz"), invariant_cov=inv_cov, field_total_T=F, n=n,
        residuals_T=res, rms_residual_T=float(np.sqrt(np.mean(res ** 2))),
        max_abs_residual_T=float(np.max(np.abs(res))), sigma_T=math.sqrt(s2) * F,
        direction_spread=spread,
        initial={k: float(v) for k, v in zip(ELLIPSOID_PARAMS, theta0 * unit)},
        iterations=it, converged=conv)


# ---------------------------------------------------------------------------
# heading domain: compass swing


@dataclass
class SwingResult:
    """Heading-domain deviation fit (see :func:`compass_swing`).

    ``delta(psi) = A + B sin psi + C cos psi + D sin 2 psi + E cos 2 psi`` [rad], with
    ``delta = indicated - true`` (note: the mariner's "deviation, east positive" is the opposite
    sign, magnetic = compass + deviation). Fields: ``coef``/``std_errors`` dicts over A..E [rad],
    ``cov`` (5, 5), ``residuals_rad`` (n,), ``sigma_rad = sqrt(SS_res / (n - 5))``, ``n``,
    ``regression`` (the underlying :class:`~imurig.calibration.regression.RegressionResult`).
    """

    names: tuple[str, ...]
    coef: dict[str, float]
    std_errors: dict[str, float]
    cov: np.ndarray
    residuals_rad: np.ndarray = field(repr=False)
    sigma_rad: float
    n: int
    regression: object = field(repr=False)

    @property
    def coef_(self) -> np.ndarray:
        return np.array([self.coef[k] for k in SWING_TERMS])

    def deviation(self, psi_true):
        """``delta(psi)`` [rad] at true heading(s) ``psi_true`` [rad]."""
        p = np.asarray(psi_true, dtype=np.float64)
        return _scalar_or_array(_swing_design(p) @ self.coef_)

    def correct(self, psi_indicated, iterations: int = 20, tol: float = 1e-13):
        """True heading [rad, [0, 2 pi)] from indicated heading(s): solves ``psi + delta(psi) = psi_ind``.

        Fixed-point iteration ``psi <- psi_ind - delta(psi)`` (converges because |d delta/d psi| < 1
        for any physically plausible deviation), vectorised; stops after ``iterations`` or when the
        largest change is below ``tol``.
        """
        pi_ = np.asarray(psi_indicated, dtype=np.float64)
        c = self.coef_
        psi = pi_ - (_swing_design(pi_) @ c)
        for _ in range(iterations):
            new = pi_ - (_swing_design(psi) @ c)
            done = np.max(np.abs(wrap_pi(new - psi))) <= tol if new.size else True
            psi = new
            if done:
                break
        return wrap_2pi(psi)

    def to_dict(self) -> dict:
        return {"kind": "imurig.compass_swing", "coef_rad": dict(self.coef), "std_errors_rad": dict(self.std_errors),
                "cov": self.cov.tolist(), "sigma_rad": self.sigma_rad, "n": self.n}


def _swing_design(psi: np.ndarray) -> np.ndarray:
    return np.stack([np.ones_like(psi), np.sin(psi), np.cos(psi), np.sin(2 * psi), np.cos(2 * psi)], axis=-1)


def compass_swing(heading_true_rad, heading_indicated_rad) -> SwingResult:
    """Classic heading-domain calibration ("swinging" on a compass rose; seed section 4.6.2, eq. 4.42-4.43).

    Parameters
    ----------
    heading_true_rad : (n,) reference heading of each compass-rose mark [rad] (typically 12 marks,
        30 deg apart), same convention as the indicated heading.
    heading_indicated_rad : (n,) heading indicated by the (uncalibrated) compass [rad].

    Measurement equation::

        wrap_pi(psi_ind - psi_true) = A + B sin psi_true + C cos psi_true + D sin 2 psi_true
                                      + E cos 2 psi_true + e          [rad], (n,)

    A: constant (mounting/alignment); B, C: hard iron (one cycle per turn); D, E: soft iron
    (two cycles per turn). Fitted by linear least squares (:func:`fit_ols`).

    Raises
    ------
    RecordingError : NaN/inf or mismatched shapes.
    ScheduleError : fewer than 6 headings, or headings that do not separate the five terms.
    """
    t = _finite_field(heading_true_rad, "heading_true_rad", "(n,)")
    i = _finite_field(heading_indicated_rad, "heading_indicated_rad", "(n,)")
    if t.ndim != 1 or t.shape != i.shape:
        raise RecordingError(f"heading_true_rad and heading_indicated_rad must be 1-D of equal length, got "
                             f"{t.shape} and {i.shape}")
    n = t.shape[0]
    if n < 6:
        raise ScheduleError(f"{n} headings for the compass swing: need at least 6 for the 5 deviation terms "
                            f"A..E (12 headings 30 deg apart is standard); swing through more compass-rose marks")
    y = wrap_pi(i - t)
    try:
        reg = fit_ols(_swing_design(t), y, list(SWING_TERMS))
    except UnidentifiableTermsError as exc:
        raise ScheduleError(f"the headings do not separate the deviation terms {exc.terms}: spread the swing "
                            f"over the whole compass rose (e.g. 12 marks 30 deg apart)") from exc
    return SwingResult(
        names=SWING_TERMS,
        coef={k: float(v) for k, v in zip(SWING_TERMS, reg.coef_)},
        std_errors={k: float(v) for k, v in zip(SWING_TERMS, reg.std_error_)},
        cov=reg.cov_, residuals_rad=reg.residuals_, sigma_rad=math.sqrt(reg.ms_res), n=n, regression=reg)
