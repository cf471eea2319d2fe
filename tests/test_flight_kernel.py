"""The compiled flight steps (imurig.flights.flight_kernel) against the per-step Python path they replace,
and the controller at its own rate. Exact: the same forces in the same operation order give the same
bits, so equality is asserted, not closeness."""
import functools
import math

import numpy as np
import pytest
from imurig.flights import earth, flight_kernel
from imurig.flights.aircraft import CitationSim, Cmd
from imurig.flights.plan import AlphaDotSTurns, Elevator3211, FlightPlan, Level, fly, simulate_flight

KIN = ("time_s", "p_N", "q_NB", "v_N", "w_NB_B", "a_N", "wdot_NB_B")


def _same_samples(a, b):
    ka, kb = a.kinematics(), b.kinematics()
    for f in KIN:
        np.testing.assert_array_equal(getattr(ka, f), getattr(kb, f), err_msg=f)
    for c in ka.controls:
        np.testing.assert_array_equal(ka.controls[c], kb.controls[c], err_msg=c)


def test_compiled_steps_equal_the_python_steps_in_flight():
    assert flight_kernel.AVAILABLE
    sims = [CitationSim(rate_hz=1000.0) for _ in range(2)]
    trims = [s.set_airborne(120.0, 1500.0) for s in sims]
    de = trims[0]["de"]
    cmds = [Cmd(de=de + 0.01, da=0.05, dr=-0.02, thr=0.6, flaps=0.3), Cmd(de=de - 0.02, da=-0.1, dr=0.03, thr=0.4)]
    flags = sims[1].model.opt.disableflags
    for c in cmds * 5:
        for _ in range(20):
            sims[0].step(c)
        sims[1].run(c, 20)
    _same_samples(*sims)
    assert sims[1].model.opt.disableflags == flags           # collision detection back on after the steps
    assert sims[0].t == sims[1].t and sims[0].act == sims[1].act and sims[0]._alpha_prev == sims[1]._alpha_prev
    # the controller's state after the compiled steps is the one the Python path computes
    after = {k: getattr(sims[1].s, k) for k in sims[1].s.__slots__}
    sims[1]._update_state()
    assert after == {k: getattr(sims[1].s, k) for k in sims[1].s.__slots__}
    # and the test can fail: a different command is seen in the samples
    sims[0].step(cmds[0])
    sims[1].run(Cmd(de=de + 0.011, da=0.05, dr=-0.02, thr=0.6, flaps=0.3), 1)
    assert sims[0].kinematics().controls["de"][-1] != sims[1].kinematics().controls["de"][-1]


def test_compiled_steps_equal_the_python_steps_on_the_ground():
    """Tyres, steering, brakes and contacts (and two physics steps per sample)."""
    sims = []
    for _ in range(2):
        s = CitationSim(rate_hz=500.0, substeps=2)
        s.data.qpos[3:7] = earth.q_from_euler(0.0, 0.0, 1.0)
        s.settle(1.0)
        sims.append(s)
    cmds = [Cmd(thr=0.3, steer=0.4), Cmd(thr=0.1, steer=-0.3, brake=0.5, de=0.1, da=0.1)]
    for c in cmds * 4:
        for _ in range(25):
            sims[0].step(c)
        sims[1].run(c, 25)
    _same_samples(*sims)
    assert np.linalg.norm(sims[1].kinematics().v_N[-1, :2]) > 0.01     # it rolled


def _short_plan(control_hz: float) -> FlightPlan:
    return FlightPlan(phases=(Level(1.0), Elevator3211(unit_s=0.2, free_s=0.5),
                              AlphaDotSTurns(banks_first_deg=(20.0,), banks_second_deg=(), hold_s=1.5,
                                             doublet_s=0.4, after_s=0.3, level_s=0.5)),
                      rate_hz=200.0, control_hz=control_hz)


def test_controller_at_its_own_rate_flies_the_same_flight_as_python_steps(monkeypatch):
    """The whole flight (pilot, autopilot at 50 Hz, compiled steps) equals the same pilot with the
    Python step per sample."""
    plan = _short_plan(50.0)
    compiled = fly(plan, progress_bar=False)

    def python_run(self, cmd, n):
        for _ in range(n):
            self.step(cmd)

    monkeypatch.setattr(CitationSim, "run", python_run)
    stepped = fly(plan, progress_bar=False)
    for f in KIN:
        np.testing.assert_array_equal(getattr(compiled.kinematics, f), getattr(stepped.kinematics, f), err_msg=f)
    assert compiled.phases == stepped.phases
    roll = np.degrees(earth.euler_from_q(compiled.kinematics.q_NB)[0])
    assert roll.max() == pytest.approx(20.0, abs=2.0)       # the turn is flown


def test_same_seed_same_flight():
    plan = FlightPlan(phases=(Level(1.0),), rate_hz=1000.0)
    a, b = simulate_flight(plan, progress_bar=False), simulate_flight(plan, progress_bar=False)
    for f in ("f_B", "w_IB_B", "lat_rad", "lon_rad", "h_m", "v_N", "q_NB", "B_B"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f), err_msg=f)
    assert a.n == 1000 and math.isclose(a.meta["plan"]["control_hz"], 50.0)


def test_nav_frame_turn_closed_form_matches_the_matrix_product():
    """ζ_N from the closed-form quaternion equals rotvec(C_EN0ᵀ R_zᵀ C_EN1) (the definition) to the
    rounding of the matrix product (|ζ| ≤ 1.2 rad here; products of O(1) entries: ~10 ε)."""
    rng = np.random.default_rng(3)
    lat0, lon0 = rng.uniform(-1.5, 1.5, 2000), rng.uniform(-3.0, 3.0, 2000)
    for scale in (1e-6, 0.3):
        lat1, lon1 = lat0 + rng.normal(0, scale, 2000), lon0 + rng.normal(0, scale, 2000)
        dt = 0.01
        c, s = math.cos(earth.OMEGA_E_RAD_S * dt), math.sin(earth.OMEGA_E_RAD_S * dt)
        R_z_T = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        C = np.swapaxes(earth.C_EN(lat0, lon0), -1, -2) @ R_z_T @ earth.C_EN(lat1, lon1)
        ref = earth.rotvec_from_q(earth.q_from_C(C))
        np.testing.assert_allclose(earth.nav_frame_turn(lat0, lon0, lat1, lon1, dt), ref, rtol=0,
                                   atol=10 * np.finfo(float).eps)


def _equal_to_rounding(a, b, what: str) -> None:
    """a equals b to the rounding of a few float64 operations on a's scale (8 eps max|a|)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    np.testing.assert_allclose(b, a, rtol=0, atol=8 * np.finfo(float).eps * max(np.abs(a).max(), 1e-300),
                               err_msg=what)


TRUTH = ("lat_rad", "lon_rad", "h_m", "v_N", "q_NB", "f_B", "w_IB_B", "B_B", "T_imu_K")


def test_compiled_truth_equals_the_numpy_truth_to_rounding(monkeypatch):
    """truth_from_kinematics' compiled pass (flights/truth_kernel.py) against its numpy reference path:
    a flown flight (held samples, turns, a 3-2-1-1) and the analytic static tests (instantaneous
    samples, rates below the series thresholds). The same operations in the same order, but LLVM may
    fuse a product and a sum into one FMA where the CPU has it (seen on an AVX-512 machine: 2 of 3360
    samples 1 ulp apart), so the bound is the rounding of a few operations on the field's scale:
    |a - b| <= 8 eps max|a|. A wrong term, a missing factor or another order of rotations is far larger."""
    from imurig.flights import truth
    from imurig.flights.truth import cabin_temperature_K, static_tests_truth, truth_from_kinematics

    flown = fly(_short_plan(50.0), progress_bar=False)
    k, p = flown.kinematics, flown.plan
    args = (k, p.origin, p.start_time, "citation", flown.sites["gps_antenna"], flown.sites["magnetometer"],
            flown.phases, {}, cabin_temperature_K(k.time_s, -k.p_N[:, 2]))
    for zoh in (True, False):
        a = truth_from_kinematics(*args, zoh=zoh, compiled=False)
        b = truth_from_kinematics(*args, zoh=zoh, compiled=True)
        for f in TRUTH:
            _equal_to_rounding(getattr(a, f), getattr(b, f), f"{f}, zoh={zoh}")
    assert np.abs(a.w_IB_B).max() > 0.1                       # the turn is in the compared samples
    compiled = static_tests_truth(dwell_s=2.0, transition_s=2.0, rate_hz=50.0)
    monkeypatch.setattr(truth, "truth_from_kinematics", functools.partial(truth_from_kinematics, compiled=False))
    reference = static_tests_truth(dwell_s=2.0, transition_s=2.0, rate_hz=50.0)
    for f in TRUTH:
        _equal_to_rounding(getattr(reference, f), getattr(compiled, f), f"static {f}")
