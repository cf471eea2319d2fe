"""imurig.campaigns.tilt_rig.RigAhead: the tilt table's run made ahead, its MuJoCo moves stepped in a forked
process (its rows sent back and filled in), the same truth as the run made in the campaign itself."""
from __future__ import annotations

import multiprocessing
import os

import numpy as np
import pytest

import imurig.rigs.tilt_truth as tilt_truth
from imurig.campaigns.tilt_rig import RigAhead, build_table, run_table
from imurig.rigs.tilt_table import TiltTableProtocol
from imurig.rigs.tilt_truth import SIGNALS

needs_fork = pytest.mark.skipif("fork" not in multiprocessing.get_all_start_methods(), reason="no fork here")
#: two mountings, moves in both: several epochs of moves (tilt_truth.EPOCH_MOVES)
PROTO = TiltTableProtocol(theta_deg=(0, 30, 60, 90), phi_deg=(0, 90, 180, 270, 330), dwell_s=0.5, remount_s=10.0)
START = "2005-06-14T18:00:00+02:00"


def _truth(run) -> dict:
    return run.truth_source.rows(0, run.n)


@needs_fork
def test_moves_stepped_in_a_process_give_the_campaigns_own_truth():
    ahead = RigAhead.start(seed=11, protocol=PROTO, start_time=START)
    assert ahead._thread.ident is None   # the fork path: no thread of its own for the run
    table, run = ahead.take(SimpleCamp(seed=11, protocol=PROTO, start_time=START))
    own = run_table(build_table(11, PROTO), PROTO, START, 11)   # MuJoCo here, at once
    got, want = _truth(run), _truth(own)
    assert set(got) == set(SIGNALS)
    for k in SIGNALS:
        np.testing.assert_array_equal(got[k], want[k], err_msg=k)


def test_the_thread_path_gives_the_same_truth():
    ahead = RigAhead.start(seed=11, protocol=PROTO, start_time=START, process=False)
    _, run = ahead.take(SimpleCamp(seed=11, protocol=PROTO, start_time=START))
    own = run_table(build_table(11, PROTO), PROTO, START, 11)
    for k in SIGNALS:
        np.testing.assert_array_equal(_truth(run)[k], _truth(own)[k], err_msg=k)


def _fails(*args, **kwargs):
    raise FloatingPointError("MuJoCo's step went unstable")


def _dies(*args, **kwargs):
    os._exit(3)


@needs_fork
@pytest.mark.parametrize("step, message", [(_fails, "FloatingPointError: MuJoCo's step went unstable"),
                                           (_dies, "ended before the last one")])
def test_a_failure_in_the_moves_process_reaches_the_truths_reader(monkeypatch, step, message):
    monkeypatch.setattr(tilt_truth, "rollout_moves", step)   # the forked process has it
    ahead = RigAhead.start(seed=11, protocol=PROTO, start_time=START)
    _, run = ahead.take(SimpleCamp(seed=11, protocol=PROTO, start_time=START))
    with pytest.raises(RuntimeError, match="the tilt table's moves \\(MuJoCo\\) failed") as err:
        _truth(run)
    assert message in str(err.value)


class SimpleCamp:
    """The settings RigAhead.take compares (those of a TiltTableCampaign), nothing else."""

    def __init__(self, seed, protocol, start_time):
        from imurig.kernel.site import Site

        self.seed, self.protocol, self.start_time = seed, protocol, start_time
        self.draw_table_errors, self.survey_accuracy_arcsec, self.site, self.lab = True, 2.0, Site(), "quiet"
