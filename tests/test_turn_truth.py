"""The turn table's closed-form truth (MuJoCo only for the ramps) against MuJoCo stepping every sample."""
from __future__ import annotations

import numpy as np
import pytest

from imurig.kernel.errors import ConfigError
from imurig.rigs.mujoco_rig import load_model
from imurig.rigs.turn_table import TurnTable, TurnTableProtocol
from imurig.rigs.turn_truth import Spindle

EPS = np.finfo(float).eps
#: agreement of the two truths, relative to each signal group's largest value: the closed form and MuJoCo
#: do the same arithmetic in another order, so they differ by rounding (measured: <= 2e-13 in f_C, where
#: omegadot = kv (c - omega) / M cancels ~3 digits; 1e-15 elsewhere); 1e-12 is 7 orders below the 16-bit
#: converter's step relative to its range (3e-5), so no sample of the campaign can tell them apart
REL = 1e-12


@pytest.mark.parametrize("rate_hz, radius_m, mounts", [(1000.0, 0.4, ("p_up", "r_down")), (100.0, 0.0, ("q_down",))])
def test_closed_form_truth_matches_mujoco_every_sample(rate_hz, radius_m, mounts):
    """Ramps, holds with the once-per-round ripple, both directions, up to 750 deg/s, the IMU on the arm
    (centripetal and tangential specific force), wobble and levelling: the stitched truth is MuJoCo's."""
    proto = TurnTableProtocol(dial_rates_dps=(100, 300, 900), mounts=mounts, radius_m=radius_m, min_window_s=1.0,
                              settle_s=1.0, sample_rate_hz=rate_hz)
    recs = {m: TurnTable(truth=m).simulate(proto, "2005-06-15T18:00:00+02:00", np.random.default_rng(5))
            for m in ("mujoco", "closed_form")}
    a, b = recs["mujoco"], recs["closed_form"]
    assert np.array_equal(a.time_s, b.time_s) and np.array_equal(a.channels["rate_dial"], b.channels["rate_dial"])
    for group in ("f_C", "w_C"):
        x = np.stack([a.truth_signals[f"{group}_{ax}"] for ax in "xyz"])
        y = np.stack([b.truth_signals[f"{group}_{ax}"] for ax in "xyz"])
        assert np.max(np.abs(x - y)) <= REL * np.max(np.abs(x)), group
    th = a.truth_signals["spin_angle"]
    assert np.max(np.abs(th - b.truth_signals["spin_angle"])) <= REL * np.max(np.abs(th))
    assert np.array_equal(a.truth_signals["pulse"], b.truth_signals["pulse"])
    # an edge time moves by the angle's difference over the rate: rounding again
    ea, eb = a.events["pulse_true"], b.events["pulse_true"]
    assert ea.size == eb.size > 10
    assert np.max(np.abs(ea - eb)) <= REL * ea.max()
    if radius_m:  # the arm is exercised: the centripetal acceleration reaches ~ omega^2 R = 27 m/s^2
        assert np.max(np.abs(a.truth_signals["f_C_x"])) > 2 * 9.81


def test_closed_form_refuses_a_spindle_it_does_not_hold_for():
    model = load_model("turn_table.xml")
    model.dof_damping[0] = 0.1
    with pytest.raises(ConfigError, match="truth='mujoco'"):
        Spindle.from_model(model, np.zeros(3))
    with pytest.raises(ConfigError, match="closed_form"):
        TurnTable(truth="analytic").simulate(TurnTableProtocol(mounts=("r_up",), dial_rates_dps=(900,)),
                                             "2005-06-15T18:00:00+02:00", np.random.default_rng(0))
