"""The contract between the bench and a user's estimator: the bench's own estimator contract
(:mod:`imurig.kernel.estimator`; settings in ``__init__``, ``fit`` returns ``self``, fitted values
in attributes ending in ``_``, a separate ``apply``). Two kinds of estimator take part:

**Calibrator** (the :class:`~imurig.kernel.estimator.Estimator` base class is optional)::

    class MyCalibrator:
        def fit(self, recording: Recording) -> "MyCalibrator":      # sets self.estimates_
            ...
            return self
        def apply(self, recording: Recording) -> Recording: ...      # optional

``fit`` receives the campaign's recording *without truth* (:meth:`Recording.without_truth`,
1 kHz SI channels, segments with set-points, metadata), returns ``self`` and leaves estimates
of the campaign's parameters (:func:`imurig.scoring.campaigns.parameter_template` lists names and
units) in ``estimates_``, as any of

- a list of parameter rows ``{"name", "unit", "estimate" | "value", "std_error"}``
  (the bench's own row format, e.g. ``TriadCalibration.physical_parameters()``);
- a mapping ``name -> (value, std_error)`` in the template's units (SI);
- a mapping ``name -> {"value", "std_error", "unit"}``;
- a list of :class:`ParameterEstimate`.

``apply`` (optional) returns a copy of the recording with calibrated channels
(``acc_cal_x..z`` in m/s^2, ``gyro_cal_p..r`` in rad/s); the bench then also scores the
calibrated output against the true input.

**NavFilter**::

    class MyFilter:
        def fit(self, streams: NavStreams) -> "MyFilter": ...       # sets self.solution_
        def apply(self) -> NavSolution: ...                           # the filtered solution

takes IMU, GPS and magnetometer streams, returns ``self`` and leaves time-stamped position,
velocity and attitude estimates, optionally with their covariances, in ``solution_`` (a
:class:`NavSolution`); :mod:`imurig.scoring.nav` scores the errors and, where covariances are
given, the filter's consistency (NEES).

Frames, as in :mod:`imurig.flights`: N is the local navigation frame north-east-down at a
fixed origin (positions ``r_N`` are metres from that origin), B the body frame
front-right-down. Quaternions are scalar first (w, x, y, z); ``q_NB`` maps body to
navigation coordinates, x_N = C(q_NB) x_B. The IMU stream and the GPS fixes are the
project's one type each (:class:`imurig.kernel.navdata.ImuStream`,
:class:`imurig.kernel.navdata.GpsFixes`, the fixes here given as ``r_N`` with ``v_N`` in N axes).
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from imurig.kernel.errors import ImurigError
from imurig.kernel.navdata import GpsFixes, ImuStream
from imurig.kernel.recording import Recording


class EstimatesError(ImurigError, ValueError):
    """A set of estimates is malformed: missing or unknown parameters, wrong units, NaN, duplicates."""


@dataclass(frozen=True)
class ParameterEstimate:
    """One estimated parameter: value and 1-sigma standard error in ``unit``."""

    name: str
    value: float
    std_error: float
    unit: str

    def to_dict(self) -> dict:
        return {"name": self.name, "value": self.value, "std_error": self.std_error, "unit": self.unit}


@runtime_checkable
class Calibrator(Protocol):
    """fit(recording without truth) -> self, with the estimates in ``estimates_`` (module doc)."""

    def fit(self, recording: Recording) -> Any: ...


@dataclass
class MagStream:
    """Magnetometer samples: field ``B_B`` (k, 3) tesla in the body frame."""

    time_s: np.ndarray
    B_B: np.ndarray


@dataclass
class NavStreams:
    """What a navigation filter sees: IMU, and optionally GPS and magnetometer, plus metadata
    (site, origin of N, initial conditions the bench gives every filter, e.g. ``initial_r_N``)."""

    imu: ImuStream
    gps: GpsFixes | None = None
    mag: MagStream | None = None
    meta: dict = field(default_factory=dict)


@dataclass
class NavSolution:
    """A filter's output at times ``time_s`` (k,): any of position ``r_N`` (k, 3) m, velocity
    ``v_N`` (k, 3) m/s, attitude ``q_NB`` (k, 4) scalar first; covariances (k, 3, 3) of each
    (attitude: of the small rotation error in N, rad^2), or None when not reported."""

    time_s: np.ndarray
    r_N: np.ndarray | None = None
    v_N: np.ndarray | None = None
    q_NB: np.ndarray | None = None
    P_r: np.ndarray | None = None
    P_v: np.ndarray | None = None
    P_att: np.ndarray | None = None


@runtime_checkable
class NavFilter(Protocol):
    """fit(streams) -> self, with the filtered solution in ``solution_`` (a :class:`NavSolution`)."""

    def fit(self, streams: NavStreams) -> Any: ...


def _fitted(estimator, what: str, attribute: str):
    """``estimator``'s fitted ``attribute`` after its ``fit`` returned ``what``; refuses anything that
    does not follow the contract (fit returns self, fitted values in ``<name>_``)."""
    name = type(estimator).__name__
    if what is not estimator:
        raise EstimatesError(f"{name}.fit() must return the estimator itself (the bench's estimator contract: "
                             f"fit returns self and leaves its results in '{attribute}'), got {type(what).__name__}")
    if not hasattr(estimator, attribute):
        raise EstimatesError(f"{name}.fit() left no '{attribute}': put the results there before returning self")
    return getattr(estimator, attribute)


def fitted_estimates(calibrator, recording: Recording):
    """Fit ``calibrator`` on ``recording`` and return its ``estimates_`` (module doc)."""
    return _fitted(calibrator, calibrator.fit(recording), "estimates_")


def fitted_solution(nav_filter, streams: NavStreams) -> NavSolution:
    """Fit ``nav_filter`` on ``streams`` and return its ``solution_``, a :class:`NavSolution`."""
    sol = _fitted(nav_filter, nav_filter.fit(streams), "solution_")
    if not isinstance(sol, NavSolution):
        raise EstimatesError(f"{type(nav_filter).__name__}.solution_ must be a NavSolution, got {type(sol).__name__}")
    return sol


def _float(v, what: str) -> float:
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise EstimatesError(f"{what} is not a number: {v!r}") from None
    return x


def normalise_estimates(est, default_units: Mapping[str, str] | None = None) -> list[ParameterEstimate]:
    """Turn any accepted estimate form (module doc) into a list of :class:`ParameterEstimate`.

    ``default_units`` (name -> unit) supplies the unit where the estimator gives none (the
    mapping ``name -> (value, std_error)`` form, which is in the template's SI units).
    Checks values only for type; :func:`imurig.scoring.score.check_estimates` validates
    names, units, NaN and duplicates against a campaign.
    """
    units = dict(default_units or {})
    out: list[ParameterEstimate] = []
    if isinstance(est, Mapping):
        items = []
        for name, v in est.items():
            if isinstance(v, Mapping):
                items.append({"name": name, **v})
            elif isinstance(v, (tuple, list)) and len(v) == 2:
                items.append({"name": name, "value": v[0], "std_error": v[1]})
            else:
                raise EstimatesError(f"estimate of {name!r} must be (value, std_error) or a mapping with "
                                     f"'value' and 'std_error', got {v!r}")
    elif isinstance(est, (list, tuple)):
        items = list(est)
    else:
        raise EstimatesError(f"a calibrator's estimates_ must be parameter rows or a mapping name -> (value, "
                             f"std_error), got {type(est).__name__}")
    for r in items:
        if isinstance(r, ParameterEstimate):
            out.append(r)
            continue
        if not isinstance(r, Mapping) or "name" not in r:
            raise EstimatesError(f"each estimate needs a 'name'; got {r!r}")
        name = str(r["name"])
        if "value" in r and "estimate" in r:
            raise EstimatesError(f"estimate {name!r} gives both 'value' and 'estimate'; give one")
        if "value" not in r and "estimate" not in r:
            raise EstimatesError(f"estimate {name!r} has no 'value'")
        val = _float(r.get("value", r.get("estimate")), f"value of {name!r}")
        if r.get("std_error") is None or r.get("std_error") == "":
            raise EstimatesError(f"estimate {name!r} has no 'std_error'; every estimate needs its 1-sigma "
                                 "standard error (the bench scores errors in units of it)")
        se = _float(r["std_error"], f"std_error of {name!r}")
        unit = r.get("unit") or units.get(name)
        if unit is None:
            raise EstimatesError(f"estimate {name!r} has no unit")
        out.append(ParameterEstimate(name, val, se, str(unit)))
    return out
