"""Mismatch discovery, the slews of the tilt table: the dynamic twin (set-points through the
table's slew law and servo), and the effects only the slews show -- a time delay of a channel
against the set-points (the multiplexer's scan skew), a lever arm, a wrong local gravity --
plus the temperature drift of the position means. Concealed-effect cases of
:mod:`imurig.concealed.suite`; truth-based checks within 4 standard errors."""
from __future__ import annotations

import numpy as np
import pytest
from imurig.sensors.accelerometer import lever_arm_specific_force

from imurig.concealed.suite import CASES, diagnose_case, found_effects, null_recording
from imurig.diagnose.tilt_dynamics import diagnose_tilt_dynamics
from imurig.diagnose.tilt_twin import slew_commands, tilt_table_twin


def _case(effect):
    return next(c for c in CASES if c.effect == effect and c.rig == "tilt_table")


def test_slew_law_matches_the_rig():
    """The twin's slew law rebuilds the rig's commanded profile from the step set-points exactly."""
    from imurig.rigs.tilt_table import (
        TiltTableProtocol,
        _command_profile,
        _position_index,
    )

    from imurig.kernel.units import DEG

    p = TiltTableProtocol(theta_deg=(0, 30), phi_deg=(0, 90, 200), dwell_s=1.0, settle_s=0.5, slew_rate_deg_s=20.0)
    th = np.repeat(np.array(p.theta_deg, float) * DEG, 3)
    ph = np.tile(np.array(p.phi_deg, float) * DEG, 2)
    cmd, windows = _command_profile(p, th, ph, 1e-3)
    idx = _position_index(cmd.shape[0], windows)
    steps = np.stack([th[idx], ph[idx]], 1)
    np.testing.assert_array_equal(slew_commands(steps, p.slew_rate_deg_s * DEG, 1e-3), cmd)


def test_lever_arm_kinematics_closed_form():
    """Uniform rotation about z at w: the centripetal term is -w^2 r_xy; a constant angular
    acceleration a about z adds a x r (machine precision)."""
    t = np.arange(0, 1, 1e-3)
    w, a = 2.0, 0.5
    wz = w + a * t
    f = lever_arm_specific_force(np.column_stack([0 * t, 0 * t, wz]), t, np.array([0.1, 0.0, 0.3]))
    np.testing.assert_allclose(f[:, 0], -wz**2 * 0.1, rtol=1e-12)
    np.testing.assert_allclose(f[:, 1], a * 0.1, rtol=1e-9)
    np.testing.assert_allclose(f[:, 2], 0.0, atol=1e-15)


@pytest.fixture(scope="module")
def lever_case(concealed_records):
    """The lever-arm case's record (seed 1), its dynamic twin (one MuJoCo replay) and the nominal calibration."""
    from imurig.campaigns.tilt_table import calibrate

    case = _case("lever_arm")
    rec = concealed_records.make(case, 1, case.realistic_size)
    return case, rec, tilt_table_twin(rec), calibrate(rec)


def test_twin_reproduces_the_rig(lever_case):
    """Replayed from the recording's set-points and the survey, the twin's specific force equals
    the rig's truth up to the table's unknown setting errors (0.25 arcmin resolution): rms below
    g x 1e-4 rad, and the twin's lever arm is the rig's 0.09 m up the phi axis."""
    _, rec, tw, _ = lever_case
    f_true = np.stack([rec.truth_signals[f"f_C_{a}"] for a in "xyz"], 1)
    rms = np.sqrt(np.mean((tw["f_C"] - f_true) ** 2, axis=0))
    assert np.all(rms < 9.81 * 1e-4), rms
    np.testing.assert_allclose(np.abs(tw["r0_C"][:, 2]), 0.09)


def test_lever_arm_found_with_truth(lever_case):
    """A 2 cm offset of the triad (pattern (1, -0.75, 0.5)) left out of the twin is found in the
    slews as a lever arm and nothing else; every component within 4 SE of the truth (z is weakly
    determined by this protocol's slow tilts); x resolved to better than 1 mm."""
    case, rec, tw, cal = lever_case
    d = diagnose_tilt_dynamics(rec, cal, np.random.default_rng(1), twin=tw)
    assert {(f["channel"], f["effect"]) for f in d["findings"]} == case.expected
    f = d["findings"][0]
    truth = np.asarray(rec.truth["sensors"]["accelerometers"]["position_C_m"])
    for p, tv in zip(f["parameters"], truth):
        assert abs(p["estimate"] - tv) < 4 * p["std_error"], (p, tv)
    assert f["parameters"][0]["std_error"] < 1e-3


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2])
def test_lever_arm_case_and_null(seed):
    """The whole case path (static and dynamic diagnosis) names the lever arm only; the same twin on
    data without the offset comes back clean."""
    case = _case("lever_arm")
    rec = case.make(seed, case.realistic_size)
    assert found_effects(diagnose_case(case, rec, seed)) == case.expected
    assert found_effects(diagnose_case(case, null_recording(case, seed), seed, null=True)) == set()


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2])
def test_time_delay_multiplexer_skew(seed, check_concealed_case):
    """The seed's 20 kHz scan reads acc_y (slot 2) 0.1 ms after its time tag; a twin that takes
    the channels as simultaneous finds a delay on acc_y only (acc_x is slot 0), within 4 SE of
    2 / f_mux; the twin that models the skew comes back clean on the same kind of data."""
    case = _case("time_delay")
    check_concealed_case(case, seed, case.realistic_size)


@pytest.mark.slow
def test_wrong_local_gravity_is_absorbed():
    """Standard gravity in the twin instead of Delft's (eps = -5.9e-4): the position means absorb it
    into the scale factors (named indistinguishable) and the slews resolve eps only to ~0.05
    (it equals a 53 um lever-arm error along the phi axis): nothing is reported, and the slews'
    estimate of eps agrees with the truth within 4 SE while its SE exceeds |eps| many times."""
    case = _case("wrong_local_gravity")
    rec = case.make(1, case.realistic_size)
    d = diagnose_case(case, rec, 1)
    assert found_effects(d) == set()
    assert any("wrong_local_gravity" in e["effects"] and "scale_factors" in e["effects"] for e in d["indistinguishable"])
    est, se = case.found_param(d)
    truth = case.truth_param(rec)
    assert abs(est - truth) < 4 * se and se > 10 * abs(truth)


@pytest.mark.slow
def test_temperature_drift_found_with_truth(check_concealed_case):
    """A bias tempco of 280 ug/K (twice the realistic 140 ug/K: the size the power curve finds on all
    three axes in 6/6 seeds; at 1x the z axis is never found, docs/diagnose-study.md) while the lab
    air drifts 3 K/h: the temperature drift is found on all three axes, its coefficient within 4 SE
    of -kb / (D x 10 mV/K); the same record without the tempco comes back clean."""
    case = _case("temperature_drift")
    check_concealed_case(case, 1, 2 * case.realistic_size)


def test_crosstalk_from_a_temperature_channel_is_named_indistinguishable_from_drift():
    """The scan wraps from 'temp_box' to acc_x, so acc_x's crosstalk candidate moves with the
    temperature. On a temperature-drift record (seed 3, where crosstalk used to take the drift's
    place on x) the two columns correlate above 0.9 given the twin: the pair is reported as
    indistinguishable, crosstalk is not claimed on x, and no axis reports crosstalk."""
    case = _case("temperature_drift")
    rec = case.make(3, case.realistic_size)
    assert rec.meta["adc"]["scan_list"][-1] == "temp_box" and rec.meta["adc"]["scan_list"][0] == "acc_x"
    d = diagnose_case(case, rec, 3)
    alias = d["axes"]["x"]["indistinguishable"][0]
    assert alias["effects"] == ["temperature_drift", "adc_crosstalk"] and abs(alias["correlation"]) > 0.9
    found = found_effects(d)
    assert ("x", "temperature_drift") in found
    assert not {e for e in found if e[1] == "adc_crosstalk"}
    assert "indistinguishable" not in d["axes"]["y"]   # acc_y's neighbour is mag_x, not a temperature


def test_crosstalk_in_the_slews_is_crosstalk_not_a_lever_arm():
    """The crosstalk case (c = 2e-4) with the slews on: the position means find crosstalk on y and
    z, so the static fit is known to be incomplete there: those axes are re-calibrated in the
    slews and the previously scanned channel joins their nuisance. The slews then find nothing
    (before, the gains the static fit had bent to absorb the crosstalk showed as a 4 cm lever
    arm), and their residual is white; the position means' crosstalk is within 4 SE of the truth."""
    from imurig.diagnose.tilt_table import diagnose_tilt_table

    case = _case("adc_crosstalk")
    rec = case.make(1, case.realistic_size)
    d = diagnose_tilt_table(rec, np.random.default_rng(1), dynamics=True)
    dyn = d["dynamic"]
    assert dyn["findings"] == []
    assert set(dyn["nominal_terms"]) >= {"gain_yx", "gain_zz", "crosstalk_y_from_mag_x", "crosstalk_z_from_mag_y"}
    assert "gain_xx" not in dyn["nominal_terms"]
    assert found_effects(d) == case.expected
    est, se = case.found_param(d)
    assert abs(est - case.truth_param(rec)) < 4 * se
    assert dyn["unexplained"]["white"]
