"""Heading from a calibrated field, angle wrapping, and the heading-domain compass swing.

Heading convention (used everywhere in :mod:`imurig.calibration.magnetometer`)
-----------------------------------------------------------------------------
Heading ``psi`` is measured from (magnetic) north, positive clockwise seen from above
(north = 0, east = pi/2), in radians, wrapped to [0, 2 pi). Body/sensor axes default to the
aerospace **FRD** convention (x forward, y right, z down - the body counterpart of the NED
navigation frame). A level sensor then measures the horizontal field ``H`` as (seed eq. 4.48/4.49)::

    h_x = H cos(psi),   h_y = -H sin(psi)       ->   psi = atan2(-h_y, h_x)

For **FLU** body axes (x forward, y left, z up - the body counterpart of the ENU frame used by the
rigs, see :mod:`imurig.kernel.site`) ``h_y = +H sin(psi)`` and ``psi = atan2(h_y, h_x)``; pass
``frame="FLU"``. True heading = magnetic heading + declination (declination positive east).

Compass swing (seed section 4.6.2, eq. 4.42-4.43)::

    wrap_pi(psi_ind - psi_true) = A + B sin psi_true + C cos psi_true + D sin 2 psi_true
                                  + E cos 2 psi_true + e          [rad]
"""
from __future__ import annotations

import math

import numpy as np

from imurig.calibration.regression import fit_ols
from imurig.kernel.errors import RecordingError, ScheduleError, UnidentifiableTermsError

TWO_PI = 2.0 * math.pi
FRAMES = ("FRD", "FLU")
#: Heading-domain deviation terms (seed eq. 4.42-4.43).
SWING_TERMS = ("A", "B", "C", "D", "E")


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


def finite_samples(arr, what: str, shape_hint: str) -> np.ndarray:
    """``arr`` as float64, refused (RecordingError naming the samples) if non-numeric or not finite."""
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


def positive_field(value, what: str) -> float:
    """A field intensity in tesla, refused if not positive or if it looks like nT."""
    v = float(value)
    if not math.isfinite(v) or v <= 0:
        raise ValueError(f"{what} must be a positive field intensity in tesla (e.g. 19010e-9 from IGRF), got {value!r}")
    if v > 1e-3:
        raise ValueError(f"{what}={v!r} looks like nT, not tesla: the Earth's field is ~2e-5 to 6.5e-5 T; "
                         f"multiply nT by 1e-9")
    return v



def swing_design(psi: np.ndarray) -> np.ndarray:
    """Columns (..., 5) of the deviation terms A..E at heading(s) ``psi`` [rad]."""
    return np.stack([np.ones_like(psi), np.sin(psi), np.cos(psi), np.sin(2 * psi), np.cos(2 * psi)], axis=-1)


def _compass_swing(heading_true_rad, heading_indicated_rad) -> dict:
    """The compass-swing fit (module doc) by linear least squares (:func:`fit_ols`); the values of
    :class:`imurig.calibration.magnetometer.MagnetometerCalibration` (method 'swing').

    Raises RecordingError (NaN/inf, mismatched shapes), ScheduleError (fewer than 6 headings, or
    headings that do not separate the five terms)."""
    t = finite_samples(heading_true_rad, "heading_true_rad", "(n,)")
    i = finite_samples(heading_indicated_rad, "heading_indicated_rad", "(n,)")
    if t.ndim != 1 or t.shape != i.shape:
        raise RecordingError(f"heading_true_rad and heading_indicated_rad must be 1-D of equal length, got "
                             f"{t.shape} and {i.shape}")
    n = t.shape[0]
    if n < 6:
        raise ScheduleError(f"{n} headings for the compass swing: need at least 6 for the 5 deviation terms "
                            f"A..E (12 headings 30 deg apart is standard); swing through more compass-rose marks")
    y = wrap_pi(i - t)
    try:
        reg = fit_ols(swing_design(t), y, list(SWING_TERMS))
    except UnidentifiableTermsError as exc:
        raise ScheduleError(f"the headings do not separate the deviation terms {exc.terms}: spread the swing "
                            f"over the whole compass rose (e.g. 12 marks 30 deg apart)") from exc
    return {"names": SWING_TERMS, "params": {k: float(v) for k, v in zip(SWING_TERMS, reg.coef_)},
            "std_errors": {k: float(v) for k, v in zip(SWING_TERMS, reg.std_error_)}, "cov": reg.cov_,
            "coef": np.asarray(reg.coef_, float).copy(), "residuals": reg.residuals_, "sigma": math.sqrt(reg.ms_res),
            "n": n, "regression": reg}
