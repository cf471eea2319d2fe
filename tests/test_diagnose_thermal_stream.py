"""The thermal-chamber diagnosis from a file read one segment at a time (imurig.kernel.filerecord):
each window's statistic is the loaded recording's to the bit, the diagnosis is the same, and the
memory the segment statistics take is one window's, not the recording's."""
from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from imurig.calibration.preprocess import huber_scale, segment_statistic
from imurig.concealed.suite import _thermal
from imurig.diagnose.dispatch import diagnose
from imurig.kernel.filerecord import FileRecord
from imurig.kernel.recording import load_h5, save_h5


@pytest.fixture(scope="module")
def thermal_file(tmp_path_factory):
    return save_h5(_thermal(3), tmp_path_factory.mktemp("thermal") / "thermal.h5")


NAMES = ["acc_x", "gyro_q", "temp_box"]


@pytest.mark.parametrize("statistic", ["median", "mean", "std"])
def test_segment_statistic_of_a_file_is_the_loaded_ones(thermal_file, statistic):
    rec = load_h5(thermal_file)
    with FileRecord(thermal_file) as f:
        assert f.segment_slices() == rec.segment_slices()
        got = segment_statistic(f, NAMES, statistic)
    np.testing.assert_array_equal(got, segment_statistic(rec, NAMES, statistic))


def test_segment_huber_of_a_file_agrees_to_its_stopping_rule(thermal_file):
    """The loaded recording's Huber M-estimates iterate all windows of one length together and stop
    when every window's Newton step is below tol s; a window read alone stops at its own
    convergence. Once the samples inside +-k s are fixed, a step is exact, so the two differ by at
    most that stopping rule, 1e-10 s (+ rounding), with s the window's own Huber scale."""
    rec = load_h5(thermal_file)
    with FileRecord(thermal_file) as f:
        got = segment_statistic(f, NAMES, "huber")
    want = segment_statistic(rec, NAMES, "huber")
    x = np.stack([rec.channels[n] for n in NAMES], axis=1)
    s = np.stack([huber_scale(x[sl], 0)[0] for sl in rec.segment_slices()])
    assert np.all(np.abs(got - want) <= 1e-10 * s + 8 * np.finfo(float).eps * np.abs(want))


def test_thermal_diagnosis_streamed_equals_loaded(thermal_file):
    """The dispatch reads a thermal FileRecord in windows (STREAMED); the diagnosis equals the one
    of the loaded recording, and the segment statistics' allocations stay below one eighth of the
    channels' size in memory."""
    rec = load_h5(thermal_file).validate()
    whole = diagnose(rec, seed=4)
    with FileRecord(thermal_file) as f:
        streamed = diagnose(f, seed=4)
        names = [c for c in f.channel_names if c.startswith(("acc_", "gyro_", "temp_"))]
        tracemalloc.start()
        segment_statistic(f, names, "median")
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    assert streamed == whole
    loaded_bytes = 8 * rec.n * len(names)
    assert peak < loaded_bytes / 8, (peak, loaded_bytes)
