"""The one estimator contract (:mod:`imurig.kernel.estimator`), checked for every estimator of the
project as scikit-learn's ``check_estimator`` does:

- ``__init__`` stores the settings, unchanged, and nothing else; ``get_params`` round-trips;
- ``fit`` returns the estimator; the fitted values are attributes ending in ``_`` that do not exist
  before fit; fit leaves the settings as they were;
- ``apply`` before ``fit`` raises :class:`~imurig.kernel.errors.NotFittedError`, after fit it works;
- fit is deterministic (the same data give identical fitted attributes), and fitting twice (or after
  fitting other data) gives the result of fitting once: no state leaks between fits.

The data sets are small: closed forms (triads, thermal tables, magnetometer loci, a short S-turn
flight), the packaged SIMONA table, and short simulated campaigns for the bench's wrappers.
``test_every_estimator_is_checked`` fails when an estimator class has no case here.
"""
from __future__ import annotations

import dataclasses
import importlib
import math
import pkgutil
from dataclasses import dataclass
from typing import Any, Callable

from pathlib import Path

import numpy as np
import pytest

import imurig
from imurig.calibration.accelerometer import AccelerometerCalibration
from imurig.calibration.gyro import GyroCalibration
from imurig.calibration.turned_axis import TurnedAxisCalibration
from imurig.calibration.magnetometer import MagnetometerCalibration
from imurig.calibration.simona import SimonaCalibration, read_simona
from imurig.calibration.thermal import ThermalCalibration
from imurig.calibration.triad import TriadCalibration
from imurig.campaigns.magnetometer import MagnetometerCampaign
from imurig.campaigns.thermal import ThermalCampaign
from imurig.campaigns.turn_table import TurnTableCampaign
from imurig.flights import ekf, ins
from imurig.flights.synthetic import synthetic_sensors
from imurig.flights.truth import static_tests_truth
from imurig.kernel.errors import NotFittedError
from imurig.kernel.estimator import Estimator
from imurig.kernel.recording import Recording
from imurig.rigs.mag_rig import CompassSwing, LevelCircle, Tumble
from imurig.rigs.thermal_chamber import ThermalProfile
from imurig.rigs.turn_table import TurnTableProtocol
from imurig.scoring.baselines import MagnetometerCalibrator, ThermalCalibrator, TiltTableCalibrator, TurnTableCalibrator
from imurig.scoring.flight import AttitudeOffset, ProjectEKF, flight_streams
from imurig.scoring.interface import EstimatesError, fitted_estimates, fitted_solution

D = math.pi / 180


# ------------------------------------------------------------------------------------ data sets
def triad_recording(seed: int, channels, inputs_SI: np.ndarray, key: str, sens: float, unit_scale: float,
                    per_segment: int = 20) -> tuple[Recording, np.ndarray]:
    """A triad recording with a closed-form forward model: u = G (I + M) q + b + k2 q^2 + noise,
    volts = s u, ``per_segment`` samples per reference q (n_seg, 3); returns (recording, q)."""
    rng = np.random.default_rng(seed)
    q = inputs_SI
    G = np.diag([1.01, 0.99, 1.02])
    M = np.array([[0, 2e-3, -1e-3], [1e-3, 0, 3e-3], [-2e-3, 1e-3, 0]])
    b = np.array([0.03, -0.02, 0.01]) * unit_scale
    u = q @ (G @ (np.eye(3) + M)).T + b + 1e-3 * q ** 2 / unit_scale
    n_seg = q.shape[0]
    u_s = np.repeat(u, per_segment, axis=0) + 1e-4 * unit_scale * rng.standard_normal((n_seg * per_segment, 3))
    t = np.arange(n_seg * per_segment) * 0.01
    start = t[::per_segment]
    rec = Recording(time_s=t, channels={c: sens * u_s[:, j] for j, c in enumerate(channels)},
                    units={c: "V" for c in channels},
                    segments={"start_s": start, "stop_s": start + per_segment * 0.01},
                    segment_units={"start_s": "s", "stop_s": "s"}, meta={key: [sens] * 3})
    return rec.validate(), q


def _orientations(seed: int, n: int, scale: float) -> np.ndarray:
    rng = np.random.default_rng(100 + seed)
    v = rng.standard_normal((n, 3))
    return scale * v / np.linalg.norm(v, axis=1)[:, None]


def acc_data(seed):
    rec, q = triad_recording(seed, ("acc_x", "acc_y", "acc_z"), _orientations(seed, 24, 9.81),
                             "acc_nominal_sensitivity_V_per_m_s2", 0.1, 1.0)
    return (rec, q), {}


def gyro_data(seed):
    rec, q = triad_recording(seed, ("gyro_p", "gyro_q", "gyro_r"), _orientations(seed, 24, 1.5),
                             "gyro_nominal_sensitivity_V_per_rad_s", 0.34, 0.01)
    return (rec, q), {}


def thermal_table(seed):
    """A step table (:func:`imurig.calibration.thermal.step_table`) from closed-form polynomials."""
    rng = np.random.default_rng(200 + seed)
    T_set = np.tile(np.array([253.15, 273.15, 293.15, 313.15, 333.15, 313.15, 293.15, 273.15]), 2)
    branch = np.tile(np.array(["up"] * 5 + ["down"] * 3), 2)
    n = T_set.size
    h = np.where(branch == "up", 0.5, -0.5)
    T_acc = T_set[:, None] + rng.normal(0, 0.2, (n, 3))
    dT = T_acc - 298.15
    table = {"step": np.arange(n), "T_set": T_set, "branch": branch, "cycle": np.repeat([0, 1], n // 2),
             "acc_bias": 0.01 + 2e-4 * dT + 1e-6 * dT ** 2 + 1e-4 * h[:, None] + rng.normal(0, 1e-5, (n, 3)),
             "acc_scale": 1.0 + 5e-5 * dT + 2e-5 * h[:, None] + rng.normal(0, 1e-6, (n, 3)), "T_acc": T_acc,
             "gyro_bias": 1e-5 + 1e-7 * (T_set[:, None] - 298.15) + rng.normal(0, 1e-8, (n, 3)),
             "T_box": T_set + rng.normal(0, 0.1, n)}
    return (table,), {}


def thermal_apply(est, data):
    T = np.full((5, 3), 310.0)
    return (np.full((5, 3), 9.81), T, np.zeros((5, 3))), {}


H, F = 19010e-9, 48724e-9


def ellipse_data(seed):
    rng = np.random.default_rng(300 + seed)
    psi = np.linspace(0, 2 * np.pi, 200, endpoint=False)
    m = H * np.column_stack([np.cos(psi), -np.sin(psi)]) @ np.array([[1.04, 0.02], [0.0, 0.96]]).T
    return (m + [3e-6, -1.5e-6] + 20e-9 * rng.standard_normal(m.shape), H), {}


def ellipsoid_data(seed):
    rng = np.random.default_rng(400 + seed)
    u = rng.standard_normal((300, 3))
    B = F * u / np.linalg.norm(u, axis=1)[:, None]
    A = np.array([[1.03, 0.02, 0.0], [0.02, 0.98, -0.01], [0.0, -0.01, 1.01]])
    return (B @ A.T + [2e-6, -1e-6, 5e-7] + 20e-9 * rng.standard_normal(B.shape), F), {}


def swing_data(seed):
    rng = np.random.default_rng(500 + seed)
    psi = np.radians(np.arange(0.0, 360.0, 30.0))
    dev = np.radians(1.5) + np.radians(3.0) * np.sin(psi) - np.radians(2.0) * np.cos(2 * psi)
    return (np.mod(psi + dev + np.radians(0.2) * rng.standard_normal(12), 2 * np.pi), psi), {}


def simona_data(seed):
    rec = read_simona()
    if seed:   # a second data set: the same table, rows thinned
        keep = np.arange(rec.n) % 2 == 0
        rec = Recording(time_s=rec.time_s[keep], channels={k: v[keep] for k, v in rec.channels.items()},
                        units=rec.units, segments={k: v[keep] for k, v in rec.segments.items()},
                        segment_units=rec.segment_units, meta=rec.meta)
    return (rec,), {}


def ekf_data(seed):
    truth = ins.s_turn_truth(20.0, 50.0, yaw_amp_rad=30 * D, yaw_period_s=20.0)
    rng = np.random.default_rng(600 + seed)
    imu, gps, _ = synthetic_sensors(truth, ekf.ImuNoise(vrw=5e-4), rng, mag_sigma_rad=1 * D)
    return (imu, gps, ins.state_at(truth, 0)), {}


def first_arg(est, data):
    return data[0][:1], {}


def no_args(est, data):
    return (), {}


# ------------------------------------------------------------------------------------ campaigns (small)
def one_axis_turn_data(seed):
    """The other lab's turn table (about r only), as the minimal lab CSV reads (module doc of
    ``tests/independent_lab``)."""
    import tempfile

    import independent_lab as lab
    from imurig.kernel.files import load
    with tempfile.TemporaryDirectory() as tmp:
        rec = load(lab.write_recording(Path(tmp) / "turn.csv", "turn_table", None, 10 + seed))
    return (rec,), {}


@pytest.fixture(scope="session")
def small_turn_recording():
    return TurnTableCampaign(protocol=TurnTableProtocol(dial_rates_dps=(20, 100), min_window_s=3.0), seed=3).simulate()


@pytest.fixture(scope="session")
def small_thermal_recording():
    profile = ThermalProfile(low_C=-40, high_C=40, step_C=20, soak_s=2400, attitude_dwell_s=40)
    return ThermalCampaign(profile=profile, seed=1).simulate()


@pytest.fixture(scope="session")
def small_mag_recording():
    camp = MagnetometerCampaign(seed=1, circle=LevelCircle(turns=1, rate_dps=30, wobble_deg=0.0),
                                tumble=Tumble(duration_s=60.0), swing=CompassSwing(dwell_s=3.0),
                                validation=LevelCircle(turns=1, rate_dps=30, start_heading_deg=17, wobble_deg=0.0,
                                                       name="validation_circle"))
    return camp.simulate()


@pytest.fixture(scope="session")
def static_flight_streams():
    return flight_streams(2005, truth=static_tests_truth(attitudes_deg=((0.0, 0.0),), dwell_s=30.0))[0]


# ------------------------------------------------------------------------------------ the cases
@dataclass
class Case:
    """An estimator with its settings, data (``data(seed)`` -> (args, kwargs) of fit; seed 1 a second
    data set, or a fixture name) and the arguments of apply (``apply_args(est, data)``)."""

    id: str
    cls: type
    params: dict
    data: Callable[[int], tuple] | str
    apply_args: Callable[[Any, tuple], tuple] = first_arg


def _scoring_cases():
    return [
        Case("TiltTableCalibrator", TiltTableCalibrator, {"model": "physical"}, "small_recording"),
        Case("TurnTableCalibrator", TurnTableCalibrator, {"timer": "hp6700"}, "small_turn_recording"),
        Case("ThermalCalibrator", ThermalCalibrator, {}, "small_thermal_recording", thermal_apply),
        Case("MagnetometerCalibrator", MagnetometerCalibrator, {}, "small_mag_recording",
             lambda e, d: ((np.full((4, 3), 30e-6),), {})),
        Case("ProjectEKF", ProjectEKF, {"use_gps": True, "nav_rate_hz": 10.0}, "static_flight_streams", no_args),
        Case("AttitudeOffset", AttitudeOffset, {"inner": ProjectEKF(nav_rate_hz=10.0)}, "static_flight_streams",
             no_args),
    ]


CASES = [
    Case("AccelerometerCalibration", AccelerometerCalibration, {"model": "physical", "statistic": "median"}, acc_data),
    Case("AccelerometerCalibration-stepwise", AccelerometerCalibration, {"model": "stepwise"}, acc_data),
    Case("GyroCalibration", GyroCalibration, {"model": "linear", "statistic": "mean"}, gyro_data),
    Case("GyroCalibration-turn-table", GyroCalibration, {"timer": "hp6700"}, "small_turn_recording"),
    Case("TurnedAxisCalibration", TurnedAxisCalibration, {"timer": "channel"}, one_axis_turn_data),
    Case("ThermalCalibration", ThermalCalibration, {"acc_order": 2, "hysteresis": True}, thermal_table,
         thermal_apply),
    Case("MagnetometerCalibration-ellipsoid", MagnetometerCalibration, {"method": "ellipsoid"}, ellipsoid_data),
    Case("MagnetometerCalibration-ellipse", MagnetometerCalibration, {"method": "ellipse"}, ellipse_data),
    Case("MagnetometerCalibration-swing", MagnetometerCalibration, {"method": "swing"}, swing_data),
    Case("SimonaCalibration", SimonaCalibration, {"rows": slice(0, -9)}, simona_data),
    Case("LooseEKF", ekf.LooseEKF,
         {"config": ekf.FilterConfig(nav_rate_hz=10.0, mag_heading_sigma_rad=1 * D), "noise": ekf.ImuNoise(vrw=5e-4)},
         ekf_data, no_args),
    *_scoring_cases(),
]


# the data sets of the cases are session fixtures, some of them (``small_recording``) shared with other
# modules: this module's tests run on one worker (tests/conftest.py), so each is simulated once per run
pytestmark = pytest.mark.xdist_group("estimator_contract")


@pytest.fixture(params=CASES, ids=[c.id for c in CASES])
def case(request, small_recording):
    """(case, data(seed), closed_form); a case's recording is built when its data are first asked for
    (``small_recording`` is named here so that its tests, in other modules too, join this group)."""
    c = request.param
    if isinstance(c.data, str):
        return c, (lambda seed: ((request.getfixturevalue(c.data),), {})), False
    return c, c.data, True


def _same(a, b, path="") -> list[str]:
    """Differences between two fitted values (exact, NaN equal to NaN), recursively."""
    if a is b:
        return []
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a_, b_ = np.asarray(a), np.asarray(b)
        ok = a_.shape == b_.shape and a_.dtype == b_.dtype and (
            np.array_equal(a_, b_, equal_nan=a_.dtype.kind in "fc") if a_.dtype.kind != "O"
            else not any(_same(x, y) for x, y in zip(a_.ravel(), b_.ravel())))
        return [] if ok else [path]
    if type(a) is not type(b):
        return [f"{path}: {type(a).__name__} vs {type(b).__name__}"]
    if isinstance(a, dict):
        if list(a) != list(b):
            return [f"{path}: keys"]
        return [d for k in a for d in _same(a[k], b[k], f"{path}[{k!r}]")]
    if isinstance(a, (list, tuple)):
        if len(a) != len(b):
            return [f"{path}: length"]
        return [d for i, (x, y) in enumerate(zip(a, b)) for d in _same(x, y, f"{path}[{i}]")]
    if isinstance(a, float):
        return [] if a == b or (math.isnan(a) and math.isnan(b)) else [path]
    if dataclasses.is_dataclass(a) or hasattr(a, "__dict__"):
        return _same(vars(a), vars(b), path)
    return [] if a == b else [path]


def _fit(cls, params, data, seed):
    args, kw = data(seed)
    est = cls(**params)
    return est, est.fit(*args, **kw), (args, kw)


# ------------------------------------------------------------------------------------ the checks
def test_init_stores_the_settings_only(case):
    c, _, _ = case
    est = c.cls(**c.params)
    assert set(vars(est)) == set(est.param_names()), "__init__ sets attributes that are not settings"
    assert not est.fitted_attributes() and not est.is_fitted()
    p = est.get_params()
    for k, v in c.params.items():
        assert p[k] is v, f"setting {k!r} not stored as given"
    again = c.cls(**p)
    assert not _same(again.get_params(), p)
    assert type(est.set_params(**p)) is c.cls
    with pytest.raises(ValueError, match="no setting"):
        est.set_params(not_a_setting=1)


def test_fit_returns_self_with_fitted_attributes_ending_in_underscore(case):
    c, data, _ = case
    est = c.cls(**c.params)
    before = set(vars(est))
    params = est.get_params()
    est2, out, _ = _fit(c.cls, c.params, data, 0)
    assert out is est2
    new = set(vars(est2)) - before
    assert new and all(k.endswith("_") for k in new), sorted(new)
    assert est2.is_fitted() and set(est2.fitted_attributes()) == new
    assert not _same(est2.get_params(), params), "fit changed the settings"


def test_apply_before_fit_raises_the_clear_error_and_works_after(case):
    c, data, _ = case
    est, _, d = _fit(c.cls, c.params, data, 0)
    args = c.apply_args(est, d)
    if args is None:
        assert not hasattr(c.cls, "apply") or c.cls.apply is Estimator.apply
        return
    a, kw = args
    with pytest.raises(NotFittedError, match="not fitted yet: call fit"):
        c.cls(**c.params).apply(*a, **kw)
    assert est.apply(*a, **kw) is not None


def test_fit_is_deterministic_and_leaves_no_state(case):
    c, data, cheap = case
    first, _, _ = _fit(c.cls, c.params, data, 0)
    other, _, _ = _fit(c.cls, c.params, data, 0)
    assert not _same(first.fitted_attributes(), other.fitted_attributes()), "same data, different fit"
    if cheap:              # fitted on other data first
        args, kw = data(1)
        other.fit(*args, **kw)
        assert _same(first.fitted_attributes(), other.fitted_attributes())
    args, kw = data(0)
    other.fit(*args, **kw)
    other.fit(*args, **kw)
    diff = _same(first.fitted_attributes(), other.fitted_attributes())
    assert not diff, f"refitting changed {diff[:5]}"


def _estimator_classes():
    for m in pkgutil.walk_packages(imurig.__path__, "imurig."):
        importlib.import_module(m.name)

    def subclasses(k):
        for s in k.__subclasses__():
            yield s
            yield from subclasses(s)

    return {k for k in subclasses(Estimator) if k.__module__.startswith("imurig.")}


def test_every_estimator_is_checked():
    """Every estimator class of the project (but the triad base, which needs a sensor's SPEC) has a case."""
    missing = _estimator_classes() - {c.cls for c in CASES} - {TriadCalibration}
    assert not missing, f"estimators without a contract case: {sorted(k.__qualname__ for k in missing)}"


def test_the_scorer_holds_user_estimators_to_the_contract():
    """A user's calibrator or filter whose fit does not return itself, or leaves no results, is refused
    with a message that states the contract."""
    class ReturnsRows:
        def fit(self, recording):
            return [{"name": "bias_x", "unit": "m/s^2", "estimate": 0.0, "std_error": 1.0}]

    class LeavesNothing:
        def fit(self, streams):
            return self

    with pytest.raises(EstimatesError, match="must return the estimator itself"):
        fitted_estimates(ReturnsRows(), None)
    with pytest.raises(EstimatesError, match="left no 'solution_'"):
        fitted_solution(LeavesNothing(), None)
