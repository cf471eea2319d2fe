"""The static diagnosis after an accepted set-point delay (issue 16): the settle guard.

Truth from the independent lab (tests/independent_lab, numpy only): in a ``time_delay`` recording
its table follows the logged set-points 50 ms late; the same seed without the effect draws the
same noise and the same converter's dither (the delay draws nothing), so the two files differ only
where the table is still moving after a plateau of the set-points has begun. On a 12-bit
converter (step 4.9 mV, 0.05 m/s^2) the clipped mean keeps those samples (1 deg off at 20 deg/s):
the position means of the delayed file carry a bias ordered like the moves (about one sampling
SE per position, but coherent over the 42), which passed as a temperature drift in the 20-seed study (seed 20001). With the guard that follows from the fitted
delay (|tau| + 3 SE + one sample) the position means must be those of the file without the delay,
exactly (the same samples).
"""
from __future__ import annotations

import numpy as np
import pytest

import independent_lab as lab
from imurig.calibration.preprocess import segment_statistic
from imurig.calibration.tilt_reference import calibrate
from imurig.diagnose.samples import working_record
from imurig.diagnose.tilt_ramps import diagnose_setpoint_delay
from imurig.diagnose.tilt_table import diagnose_tilt_table, guarded, settle_guard
from imurig.kernel.files import load

SEED, FS_HZ, CONVERTER = 20001, 50.0, "12bit_10V"
ACC = ["acc_x", "acc_y", "acc_z"]


def _pair(tmp_path):
    return [load(lab.write_recording(tmp_path / f"tilt-{e}.csv", "tilt_table", e, SEED, FS_HZ, CONVERTER))
            for e in ("time_delay", None)]


def test_guarded_position_means_are_those_without_the_delay(tmp_path):
    delayed, on_time = _pair(tmp_path)
    # the ramps' finding as diagnose_setpoint_delay gives it (the fit itself: the slow test below)
    tau = {"name": "tau_s", "estimate": 0.0498, "std_error": 2.2e-4}
    guard = settle_guard({"findings": [{"effect": "time_delay", "channel": "acc", "parameters": [tau]}],
                          "setpoint_sample_s": 1 / FS_HZ})
    assert guard == (pytest.approx(0.0498 + 3 * 2.2e-4 + 1 / FS_HZ), 0.0)

    def means(rec):
        return segment_statistic(rec, ACC, "clipped_mean")
    assert np.array_equal(means(guarded(delayed, *guard)), means(guarded(on_time, *guard)))
    # without the guard they differ on every axis, and inside the positions the files differ only in
    # the first tau (+ one sample) of each: the table still moving into the plateau
    assert not np.any(np.all(means(delayed) == means(on_time), axis=0))
    diff = np.any(delayed.stack(ACC) != on_time.stack(ACC), axis=1)
    touched = 0
    for s, t0 in zip(delayed.segment_slices(), delayed.segments["start_s"]):
        moving = np.flatnonzero(diff[s])
        assert np.all(delayed.time_s[s][moving] < t0 + 0.05 + 1 / FS_HZ)
        touched += moving.size > 0
    # every position reached by a move that turns gravity in the triad: all but the first and the ten
    # reached by turning phi at theta = 0 or 180 deg (about gravity's own axis)
    assert touched == delayed.n_segments - 1 - 10

def test_no_guard_without_an_accepted_set_point_delay():
    assert settle_guard({"tested": False, "why": "-"}) is None
    assert settle_guard({"tested": True, "findings": [], "setpoint_sample_s": 0.01}) is None
    f = {"effect": "time_delay", "channel": "acc", "parameters": [{"name": "tau_s", "estimate": -0.02,
                                                                   "std_error": 0.001}]}
    # a delay from the dynamic twin (no logged ramps) is a channel skew, not a table still moving
    assert settle_guard({"findings": [f]}) is None
    # the table leads its set-points: it leaves each plateau early, so the end is cut
    assert settle_guard({"findings": [f], "setpoint_sample_s": 0.01}) == (0.0, pytest.approx(0.033))


@pytest.mark.slow
def test_the_delayed_record_names_the_delay_alone(tmp_path):
    delayed, _ = _pair(tmp_path)
    dyn = diagnose_setpoint_delay(delayed, calibrate(delayed, model="physical", processed=working_record(delayed)))
    (p,) = dyn["findings"][0]["parameters"]
    assert abs(p["estimate"] - 0.05) < 3 * p["std_error"]
    assert settle_guard(dyn) == (pytest.approx(abs(p["estimate"]) + 3 * p["std_error"] + 1 / FS_HZ), 0.0)
    d = diagnose_tilt_table(delayed, np.random.default_rng(SEED), dynamics=True)
    assert [f["effect"] for f in d["dynamic"]["findings"]] == ["time_delay"]
    assert d["settle_guard_s"]["start"] > 0.05
    assert all(d["axes"][a]["findings"] == [] for a in "xyz")
