"""Navigation filters scored on the simulated flight (imurig.scoring.flight).

Bounds: for a consistent filter E|e|² = tr P, so the RMS error norm of a block is about
sqrt(mean tr P); the bound per block is 3x that figure of the project's own EKF (its
3-sigma gate), computed from the baseline's reported covariance, not from its errors.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from imurig.scoring.flight import (
    AttitudeOffset,
    NavScoreFailure,
    ProjectEKF,
    assert_nav_meets,
    flight_streams,
    score_nav_filter_on_flight,
    simulate_truth,
    trim_solution,
)
from imurig.kernel.navdata import GpsFixes, ImuStream
from imurig.scoring.interface import (
    MagStream,
    NavSolution,
    NavStreams,
)

SEED = 2005
SETTLE_S = 10.0


@pytest.fixture(scope="module")
def flight_truth():
    """The scorer's default flight, flown once for this module (``flight_streams(seed)`` flies the same
    plan; ``test_same_seed_identical_streams`` flies it again and compares)."""
    return simulate_truth()


@pytest.fixture(scope="module")
def nominal(flight_truth):
    return flight_streams(SEED, truth=flight_truth)


@pytest.fixture(scope="module")
def calibrated(flight_truth):
    return flight_streams(SEED, calibrated=True, truth=flight_truth)


@pytest.fixture(scope="module")
def baseline(calibrated):
    """Baseline score and 3-sigma bounds from its own covariance (module doc)."""
    s, _, _ = calibrated
    sol = ProjectEKF().fit(s).solution_
    t = trim_solution(sol, float(s.imu.time_s[0]) + SETTLE_S)
    bounds = {b: 3 * math.sqrt(float(np.mean(np.trace(P, axis1=1, axis2=2))))
              for b, P in (("position", t.P_r), ("velocity", t.P_v), ("attitude", t.P_att))}
    return score_nav_filter_on_flight(ProjectEKF(), streams=calibrated, settle_s=SETTLE_S), bounds


def test_baseline_meets_its_covariance_bounds(baseline):
    score, bounds = baseline
    assert_nav_meets(score, bounds)
    for b in ("position", "velocity", "attitude"):
        assert "anees" in score[b]


def test_dead_reckoning_fails_and_names_position(calibrated, baseline):
    score, bounds = baseline
    poor = score_nav_filter_on_flight(ProjectEKF(use_gps=False), streams=calibrated, settle_s=SETTLE_S)
    assert poor["position"]["rms_norm"] > score["position"]["rms_norm"]
    with pytest.raises(NavScoreFailure, match=r"position RMS error [0-9.e+-]+ m exceeds") as exc:
        assert_nav_meets(poor, bounds)
    assert "velocity RMS error" in str(exc.value)


def test_attitude_offset_fails_and_names_attitude(calibrated, baseline):
    score, bounds = baseline
    off = 5 * math.pi / 180
    poor = score_nav_filter_on_flight(AttitudeOffset(ProjectEKF(), (0.0, 0.0, off)), streams=calibrated,
                                      settle_s=SETTLE_S)
    # the offset is a body-z rotation: the attitude error grows to about the offset, the rest is unchanged
    assert poor["attitude"]["rms_norm"] > off - score["attitude"]["rms_norm"]
    assert poor["position"] == score["position"]
    with pytest.raises(NavScoreFailure, match=r"attitude RMS error") as exc:
        assert_nav_meets(poor, bounds)
    assert "position" not in str(exc.value) and "velocity" not in str(exc.value)
    with pytest.raises(NavScoreFailure, match="attitude ANEES"):
        assert_nav_meets(poor, consistent=("attitude",))


def test_gps_stream_in_truth_frame_within_its_sigma(nominal):
    """Antenna fixes in N0 vs truth + C_NB lever arm, within 5 sigma of the receiver's σ plus the
    time-of-validity error σ_t |v| (the filter's own R model)."""
    from imurig.flights import earth as E

    s, truth, _ = nominal
    assert np.allclose(truth.r_N[0], 0.0, atol=1e-9)
    g = s.gps
    r = np.stack([np.interp(g.time_s, truth.time_s, truth.r_N[:, j]) for j in range(3)], 1)
    v = np.stack([np.interp(g.time_s, truth.time_s, truth.v_N[:, j]) for j in range(3)], 1)
    i = np.searchsorted(truth.time_s, g.time_s)
    ant = r + E.C_from_q(truth.q_NB[i]) @ np.asarray(s.meta["lever_gps_B_m"])
    sig = np.sqrt(np.asarray(g.sigma_pos_N) ** 2 + (s.meta["gps_time_sigma_s"] * v) ** 2)
    z = (g.r_N - ant) / sig
    assert np.max(np.abs(z)) < 5, np.max(np.abs(z))
    zv = (g.v_N - v) / np.sqrt(np.asarray(g.sigma_vel_N) ** 2 + 0.05 ** 2)   # + lever-arm velocity ≲ 0.05 m/s
    assert np.max(np.abs(zv)) < 5


def _flat_numbers(x):
    if isinstance(x, dict):
        for v in x.values():
            yield from _flat_numbers(v)
    elif isinstance(x, (list, tuple, np.ndarray)):
        for v in np.asarray(x, dtype=object).ravel():
            yield from _flat_numbers(v)
    elif isinstance(x, (int, float, np.floating)) and not isinstance(x, bool):
        yield float(x)


def test_streams_hold_no_truth(nominal, flight_truth):
    from imurig.campaigns import flight as R
    from imurig.kernel import random_streams
    from imurig.flights.imu import measure_flight
    from imurig.sensors.chain import ImuLab

    s, _, _ = nominal
    assert type(s) is NavStreams
    assert type(s.imu) is ImuStream and type(s.gps) is GpsFixes and type(s.mag) is MagStream
    assert [f.name for f in dataclasses.fields(s.imu)] == ["time_s", "f_B", "w_IB_B", "B_B", "T_acc_K", "samples"]
    assert s.imu.B_B is None and s.imu.T_acc_K is None          # the field is the mag stream; no temperatures
    assert s.gps.t_true_s is None and s.gps.lat_rad is None      # no true epochs; positions in N0 (r_N)
    assert [f.name for f in dataclasses.fields(s.mag)] == ["time_s", "B_B"]
    assert not any("truth" in k or "true" in k for k in s.meta)
    assert not any(isinstance(v, NavSolution) for v in s.meta.values())
    # measurements differ from the truth by the sensor errors (the IMU is not the truth signal)
    tr = flight_truth.slice(flight_truth.time_s[0], flight_truth.time_s[0] + 30.0)  # = simulate_truth(duration_s=30)
    n = tr.n
    assert np.max(np.abs(s.imu.f_B[:n] - tr.f_B)) > 1e-4
    assert np.max(np.abs(s.mag.B_B[:n] - tr.B_B)) > 1e-8
    # no drawn sensor error of this seed's IMU appears among the numbers handed to the filter
    # (datasheet figures, the same in the nominal lab, are allowed: an operator knows them)
    rec = measure_flight(tr, R.flight_lab(SEED), random_streams.seed_sequence("flight/sensor-chain", SEED))
    nom = measure_flight(tr, ImuLab(), random_streams.seed_sequence("flight/sensor-chain", SEED))
    datasheet = {round(v, 12) for v in _flat_numbers(nom.truth["sensors"])}
    drawn = {round(v, 12) for v in _flat_numbers(rec.truth["sensors"])} - datasheet
    given = {round(v, 12) for v in _flat_numbers(s.meta)}
    assert drawn and not (drawn & given), drawn & given


def test_same_seed_identical_streams(nominal, flight_truth):
    s, truth, _ = nominal
    s2, truth2, _ = flight_streams(SEED)
    for a, b in ((s.imu, s2.imu), (s.gps, s2.gps), (s.mag, s2.mag), (truth, truth2)):
        for f in dataclasses.fields(a):
            x, y = getattr(a, f.name), getattr(b, f.name)
            assert (x is None and y is None) or np.array_equal(x, y), f.name
    assert s.meta == s2.meta
    s3, _, _ = flight_streams(SEED + 1, duration_s=30.0, truth=flight_truth)
    assert not np.array_equal(s3.imu.f_B, s.imu.f_B[: s3.imu.f_B.shape[0]])
