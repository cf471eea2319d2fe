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
coefficient of the heading-domain swing (method 'swing') or needs a heading reference.

Heading convention: :mod:`imurig.calibration.heading` (FRD by default, ``frame="FLU"`` for the
rigs' axes; clockwise from north, [0, 2 pi)).

The estimator (the bench's contract, :mod:`imurig.kernel.estimator`)::

    cal = MagnetometerCalibration("ellipsoid")      # or "ellipse" (level swing), "swing" (heading domain)
    cal.fit(m, F)                                   # m (n, 3) T and the IGRF total intensity F [T]
    cal.b_, cal.AAt_, cal.invariant_cov_ ...         # fitted values
    cal.apply(m)                                    # calibrated field T (m - b) [T]

The numerics are in :mod:`imurig.calibration.field_fit` (2-D and shared) and
:mod:`imurig.calibration.ellipsoid_fit` (3-D); the compass swing in :mod:`imurig.calibration.heading`.
"""
from __future__ import annotations

from typing import Self

import numpy as np

from imurig.calibration.ellipsoid_fit import AAT_NAMES, ELLIPSOID_PARAMS, _fit_ellipsoid_3d
from imurig.calibration.field_fit import ELLIPSE_PARAMS, _fit_ellipse_2d
from imurig.calibration.heading import (SWING_TERMS, _compass_swing, _scalar_or_array, heading_from_field,
                                        swing_design, wrap_2pi, wrap_pi)
from imurig.kernel.errors import ConfigError, RecordingError
from imurig.kernel.estimator import Estimator

__all__ = ["MagnetometerCalibration", "METHODS", "ELLIPSE_PARAMS", "ELLIPSOID_PARAMS", "AAT_NAMES", "SWING_TERMS"]

#: method -> (what ``fit(data, reference)`` takes, what ``apply`` returns)
METHODS = {
    "ellipsoid": ("m (n, 3) measured field [T] in many orientations, reference = total intensity F [T]",
                  "calibrated field T (m - b) [T], like m"),
    "ellipse": ("m (n, 2) measured horizontal field (x, y) [T] of a level swing, reference = horizontal "
                "intensity H [T]", "calibrated horizontal field A2^-1 (m - b2) [T], like m"),
    "swing": ("indicated headings (n,) [rad], reference = true headings of the compass-rose marks (n,) [rad]",
              "true heading [rad, [0, 2 pi)] from indicated heading(s)"),
}


class MagnetometerCalibration(Estimator):
    """Magnetometer calibration in the field domain (ellipse, ellipsoid) or the heading domain (swing).

    Settings: ``method`` ('ellipsoid', 'ellipse', 'swing', :data:`METHODS`); for the field-domain
    methods ``min_direction_spread`` (3-D: smallest accepted eigenvalue of the covariance of the
    field's unit directions; uniform 1/3, a hemisphere 1/12, a plane 0), ``min_coverage_deg`` (2-D:
    heading coverage, 360 minus the largest angular gap), ``scale_bounds`` (accepted semi-axes in
    units of the field intensity), ``max_iter`` and ``rtol`` of the Gauss-Newton refinement.

    ``fit(data, reference)`` (:data:`METHODS`) returns self. Measurement equations::

        ellipsoid:  m_k = A B_k + b + e_k,   |B_k| = F,   A = T^-1, T upper triangular      [T]
        ellipse:    m_k = A2 h_k + b2 + e_k,  h_k = H (cos psi_k, -sin psi_k),
                    A2 = [[sx, rho], [0, sy]]                                                  [T]
        swing:      wrap_pi(psi_ind - psi_true) = A + B sin psi + C cos psi + D sin 2 psi + E cos 2 psi

    Fitted, every method: ``names_`` (parameter names), ``params_`` / ``std_errors_`` (dicts over
    them; T and dimensionless, or rad), ``cov_``, ``n_``, ``residuals_`` (n,) (field methods:
    |T (m - b)| - F in T; swing: rad), ``sigma_`` = sqrt(SS_res / (n - p)) (T or rad).
    Field methods also: ``A_``, ``b_``, ``T_`` = A^-1 ((3, 3), (3,) for the ellipsoid; (2, 2), (2,)
    for the ellipse), ``field_T_``, ``rms_residual_T_``, ``max_abs_residual_T_``, ``initial_`` (the
    step-1 values), ``n_iter_``, ``converged_``. Ellipsoid also: ``A_std_``, ``b_std_``, the
    rotation-invariant ``AAt_`` = A A' with ``AAt_std_``, ``invariant_names_`` and
    ``invariant_cov_`` (the 6 unique AAt entries and b), ``direction_spread_``. Ellipse also:
    ``coverage_deg_``. Swing also: ``coef_`` (5,) rad (A..E) and ``regression_``. ``A`` is
    identifiable only up to a rotation: compare ``b_`` and ``AAt_`` with a truth, not ``A_``.

    Raises (in fit) RecordingError for NaN/inf, non-numeric or mis-shaped samples and
    ScheduleError for data that do not identify the model (too few samples, an arc, a cone, ...),
    each saying what manoeuvre fixes it.
    """

    def __init__(self, method: str = "ellipsoid", *, min_direction_spread: float = 0.01,
                 min_coverage_deg: float = 180.0, scale_bounds: tuple[float, float] = (0.5, 2.0),
                 max_iter: int = 50, rtol: float = 1e-10):
        self.method = method
        self.min_direction_spread = min_direction_spread
        self.min_coverage_deg = min_coverage_deg
        self.scale_bounds = scale_bounds
        self.max_iter = max_iter
        self.rtol = rtol

    def fit(self, data, reference) -> Self:
        """Fit ``data`` against ``reference`` (:data:`METHODS`); returns self."""
        self._clear_fitted()
        kw = {"scale_bounds": self.scale_bounds, "max_iter": self.max_iter, "rtol": self.rtol}
        if self.method == "ellipsoid":
            values = _fit_ellipsoid_3d(data, reference, min_direction_spread=self.min_direction_spread, **kw)
        elif self.method == "ellipse":
            m = np.asarray(data)
            if m.ndim != 2 or m.shape[1] != 2:
                raise RecordingError(f"the ellipse fit takes m of shape (n, 2) (x, y field in tesla), got {m.shape}")
            values = _fit_ellipse_2d(m[:, 0], m[:, 1], reference, min_coverage_deg=self.min_coverage_deg, **kw)
        elif self.method == "swing":
            values = _compass_swing(reference, data)
        else:
            raise ConfigError(f"unknown method {self.method!r}; choose from {sorted(METHODS)}")
        for k, v in values.items():
            setattr(self, k + "_", v)
        return self

    def _fitted_method(self, *methods: str) -> None:
        self.check_fitted()
        if self.method not in methods:
            raise ConfigError(f"this needs a {' or '.join(methods)} calibration; this one is '{self.method}'")

    def apply(self, data):
        """The calibrated output (:data:`METHODS`): the calibrated field T (m - b) (ellipsoid: m (n, 3)
        or (3,); ellipse: m (n, 2) or (2,)), or the true heading from indicated heading(s) (swing)."""
        self.check_fitted()
        if self.method == "swing":
            return self.correct(data)
        m = np.asarray(data, dtype=np.float64)
        d = self.b_.size
        if m.shape[-1:] != (d,):
            raise ValueError(f"m must have shape (n, {d}) or ({d},), got {m.shape}")
        return (m - self.b_) @ self.T_.T

    def heading(self, m, declination_rad: float = 0.0, *, frame: str = "FRD"):
        """Heading [rad, [0, 2 pi)] of the level sensor from its raw horizontal field ``m`` (n, 2) [T]
        (ellipse), see :func:`imurig.calibration.heading.heading_from_field`."""
        self._fitted_method("ellipse")
        return heading_from_field(self.apply(m), declination_rad=declination_rad, frame=frame)

    def deviation(self, psi_true):
        """delta(psi) [rad] at true heading(s) ``psi_true`` [rad] (swing)."""
        self._fitted_method("swing")
        return _scalar_or_array(swing_design(np.asarray(psi_true, dtype=np.float64)) @ self.coef_)

    def correct(self, psi_indicated, iterations: int = 20, tol: float = 1e-13):
        """True heading [rad, [0, 2 pi)] from indicated heading(s) (swing): solves psi + delta(psi) = psi_ind
        by the fixed-point iteration psi <- psi_ind - delta(psi) (|d delta/d psi| < 1 for any physically
        plausible deviation), vectorised; stops after ``iterations`` or when the largest change is below ``tol``."""
        self._fitted_method("swing")
        pi_ = np.asarray(psi_indicated, dtype=np.float64)
        c = self.coef_
        psi = pi_ - (swing_design(pi_) @ c)
        for _ in range(iterations):
            new = pi_ - (swing_design(psi) @ c)
            done = np.max(np.abs(wrap_pi(new - psi))) <= tol if new.size else True
            psi = new
            if done:
                break
        return wrap_2pi(psi)

    def to_dict(self) -> dict:
        """The fitted calibration, JSON-ready."""
        self.check_fitted("to_dict")
        if self.method == "swing":
            return {"kind": "imurig.compass_swing", "coef_rad": dict(self.params_),
                    "std_errors_rad": dict(self.std_errors_), "cov": self.cov_.tolist(), "sigma_rad": self.sigma_,
                    "n": self.n_}
        three = self.method == "ellipsoid"
        out = {"kind": f"imurig.magnetometer_{'ellipsoid_3d' if three else 'ellipse_2d'}", "names": list(self.names_),
               "params": dict(self.params_), "std_errors": dict(self.std_errors_), "cov": self.cov_.tolist()}
        if three:
            out.update(T=self.T_.tolist(), A=self.A_.tolist(), b_T=self.b_.tolist(), A_std=self.A_std_.tolist(),
                       b_std_T=self.b_std_.tolist(), AAt=self.AAt_.tolist(), AAt_std=self.AAt_std_.tolist(),
                       field_total_T=self.field_T_)
        else:
            out.update(A2=self.A_.tolist(), b2_T=self.b_.tolist(), field_horizontal_T=self.field_T_)
        out.update(n=self.n_, rms_residual_T=self.rms_residual_T_, max_abs_residual_T=self.max_abs_residual_T_,
                   sigma_T=self.sigma_)
        out.update({"direction_spread": self.direction_spread_} if three else {"coverage_deg": self.coverage_deg_})
        out.update(initial=dict(self.initial_), iterations=self.n_iter_, converged=self.converged_)
        return out
