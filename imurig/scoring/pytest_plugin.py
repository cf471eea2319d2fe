"""pytest integration: assert in your own test suite that your estimator meets a bound on a
named campaign with a fixed seed.

Enable it in your top-level ``conftest.py``::

    pytest_plugins = ["imurig.scoring.pytest_plugin"]

then::

    def test_my_calibrator(imurig_campaign, assert_calibrator_meets):
        camp = imurig_campaign("tilt-table-quick", seed=1)      # simulated once per session
        assert_calibrator_meets(MyCalibrator(), camp, z_bound=4, max_rms_z=2)

or import the function directly (no plugin needed)::

    from imurig.scoring.pytest_plugin import assert_calibrator_meets

A failure names every parameter that missed, by how much (in its unit) and in units of its
standard error, e.g.::

    MyCalibrator on tilt-table-quick (seed 1): 1 of 15 parameters outside |z| <= 4:
      bias_x: estimate +3.30e-02 vs injected +3.23e-02 m/s^2 -> off by +6.7e-04 m/s^2 = +7.6 SE (SE 8.8e-05)
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import pytest

from imurig.scoring.score import Score

if TYPE_CHECKING:
    from imurig.scoring.campaigns import BenchCampaign


class CalibratorBoundError(AssertionError):
    """An estimator missed a bound on a campaign; ``score`` holds the full score."""

    def __init__(self, message: str, score: Score):
        super().__init__(message)
        self.score = score


def assert_calibrator_meets(calibrator, camp: BenchCampaign | str, seed: int | None = None, z_bound: float = 4.0,
                            max_rms_z: float | None = None, max_se_ratio: float | None = None,
                            max_residual_ratio: float | None = None) -> Score:
    """Fit ``calibrator`` on the campaign (recording without truth) and assert:

    - every parameter within ``|z| <= z_bound``;
    - optionally the RMS of the z-scores <= ``max_rms_z`` (standard errors not too small);
    - optionally every standard error <= ``max_se_ratio`` x the bench's (precise enough:
      without this a calibrator that reports huge standard errors passes any z bound);
    - optionally the forward-model residual RMS <= ``max_residual_ratio`` x its floor.

    Returns the :class:`Score`; raises :class:`CalibratorBoundError` (an AssertionError)
    naming each parameter that missed.
    """
    # heavy (the campaigns' MuJoCo rigs, scipy): loaded when used, not when pytest starts this plugin
    from imurig.scoring.bench import score_calibrator

    s = score_calibrator(calibrator, camp, seed, z_bound=z_bound)
    problems = []
    if not s.passed:
        problems.append(s.failure_message())
    if max_rms_z is not None and s.rms_z > max_rms_z:
        problems.append(f"RMS of the z-scores {s.rms_z:.2f} > {max_rms_z:g}: the standard errors are too small "
                        f"(largest: " + ", ".join(f"{r['name']} {r['z']:+.2f}" for r in
                                                  sorted(s.rows, key=lambda r: -abs(r["z"]))[:3]) + ")")
    if max_se_ratio is not None:
        bad = [r for r in s.rows if r.get("se_ratio") is not None and r["se_ratio"] > max_se_ratio]
        if bad:
            problems.append(f"standard errors above {max_se_ratio:g} x the bench's: " + ", ".join(
                f"{r['name']} {r['std_error']:.2e} {r['unit']} = {r['se_ratio']:.2f} x" for r in bad))
    fm = s.residuals.get("forward_model")
    if max_residual_ratio is not None and fm:
        bad = {a: fm["rms"][a] / fm["floor_rms"][a] for a in fm["rms"]
               if fm["rms"][a] > max_residual_ratio * fm["floor_rms"][a]}
        if bad:
            problems.append(f"forward-model residual RMS above {max_residual_ratio:g} x its floor on axes: " + ", ".join(
                f"{a} {fm['rms'][a]:.3e} {fm['unit']} = {r:.2f} x" for a, r in bad.items()))
    if problems:
        raise CalibratorBoundError("\n".join(problems), s)
    return s


@pytest.fixture(scope="session")
def imurig_campaign():
    """Factory ``imurig_campaign(name, seed=None) -> BenchCampaign`` (simulated once per session)."""
    # heavy (the campaigns' MuJoCo rigs, scipy): loaded when used, not when pytest starts this plugin
    from imurig.scoring.campaigns import campaign

    return campaign


@pytest.fixture(name="assert_calibrator_meets")
def _assert_calibrator_meets_fixture():
    """The function :func:`assert_calibrator_meets`."""
    return assert_calibrator_meets
