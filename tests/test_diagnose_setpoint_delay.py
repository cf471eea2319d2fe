"""The set-point delay of an imported tilt-table recording with ramped set-points (issue 16).

Truth from the independent lab (tests/independent_lab, numpy only): its table follows the logged
set-points 50 ms late in a ``time_delay`` recording and on time in a null. A 50 Hz file with the
16-bit converter (step coarser than the noise) goes through the user's import and the static
calibration; the slews' test must find tau within 3 SE of the truth, and nothing on the null.
"""
from __future__ import annotations

import numpy as np
import pytest

import independent_lab as lab
from imurig.calibration.tilt_reference import calibrate
from imurig.diagnose.samples import working_record
from imurig.diagnose.tilt_ramps import diagnose_setpoint_delay, ramped
from imurig.kernel.files import load

FS_HZ = 50.0


def _diagnose(tmp_path, effect, seed):
    path = lab.write_recording(tmp_path / f"tilt-{effect}-{seed}.csv", "tilt_table", effect, seed, fs_hz=FS_HZ,
                               converter="16bit_5V")
    rec = load(path)
    cal = calibrate(rec, model="physical", processed=working_record(rec))
    return diagnose_setpoint_delay(rec, cal, alpha=0.01)


@pytest.mark.parametrize("seed", [7])
def test_a_set_point_delay_is_found_within_its_standard_error(tmp_path, seed):
    d = _diagnose(tmp_path, "time_delay", seed)
    assert d["tested"] and len(d["findings"]) == 1
    f = d["findings"][0]
    assert (f["effect"], f["channel"]) == ("time_delay", "acc")
    (p,) = f["parameters"]
    assert p["name"] == "tau_s" and 0 < p["std_error"] < 1e-3
    assert abs(p["estimate"] - 0.05) < 3 * p["std_error"]


@pytest.mark.parametrize("seed", [8])
def test_no_delay_gives_no_finding(tmp_path, seed):
    d = _diagnose(tmp_path, None, seed)
    assert d["tested"] and d["findings"] == []
    # the profiled tau is noise: within 3 SE of zero, and the statistic below its threshold
    assert abs(d["test"]["tau_s"]) < 3 * d["test"]["tau_se_s"]
    assert abs(d["test"]["t"]) < d["test"]["threshold"]


def test_stepped_set_points_are_not_ramps():
    step = np.repeat(np.array([[0.0, 0.0], [0.5, 0.0], [0.5, 1.0]]), 50, axis=0)
    ramp = np.column_stack([np.interp(np.arange(150), [0, 50, 100, 150], [0, 0, 0.5, 0.5]), np.zeros(150)])
    assert not ramped(step) and ramped(ramp)
