"""The Citation in MuJoCo, its manoeuvres, the navigation truth with Earth terms, the IMU stream,
and the van. Truth-based: closed forms at machine precision where they exist, approximations
with their stated accuracy where they do not."""
import math

import mujoco
import numpy as np
import pytest
from imurig.flights import earth
from imurig.flights.aircraft import G0, CitationSim, Cmd, isa_density, modes
from imurig.flights.imu import measure_flight
from imurig.flights.plan import (
    AlphaDotSTurns,
    FlightPlan,
    GroundCircle,
    Level,
    Parked,
    Takeoff,
    simulate_flight,
)
from imurig.flights.truth import mechanise, static_tests_truth
from imurig.sensors.chain import ImuLab
from imurig.sensors.gyro import FOGTriad

from imurig.kernel.errors import ConfigError

V0, H0 = 120.0, 1500.0


def _inertia_about_cg(sim):
    """Rigid-body inertia (3x3, body axes) of the whole aircraft (gear included) about its CG."""
    m, d = sim.model, sim.data
    M = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, d, M)
    mass = float(m.body_subtreemass[sim.bid])
    C = d.xmat[sim.bid].reshape(3, 3)
    c = C.T @ (d.subtree_com[sim.bid] - d.xpos[sim.bid])
    return M[3:6, 3:6] - mass * (c @ c * np.eye(3) - np.outer(c, c)), mass


def test_trim_holds_straight_and_level():
    sim = CitationSim()
    trim = sim.set_airborne(V0, H0)
    assert max(abs(r) for r in trim["residual"]) < 1e-8
    for _ in range(2000):                         # 20 s, controls frozen at trim
        sim.step(Cmd(de=trim["de"], thr=sim.act.thr))
    s = sim.s
    # the residual 1e-9 m/s^2 would move 2e-7 m; what remains is the start-up of the alpha-dot
    # estimate (one step of history), far below the phugoid's metres
    assert abs(s.h - H0) < 0.1 and abs(s.V - V0) < 0.05
    assert abs(s.phi) < 1e-9 and abs(s.psi) < 1e-9 and abs(s.theta - trim["theta"]) < 1e-3


def test_linearised_modes_match_approximations():
    sim = CitationSim()
    lin = sim.linearise(V0, H0)
    md = modes(lin["A_lon"], lin["A_lat"])
    a = sim.aero
    I_cg, m = _inertia_about_cg(sim)
    rho = isa_density(H0)
    qS = 0.5 * rho * V0 ** 2 * a.S_m2
    CL = m * G0 / qS
    CD = a.CD0 + CL ** 2 / (math.pi * a.aspect_ratio * a.oswald)
    # short period, 2-state (alpha, q) approximation with the Z_q and M_alpha-dot terms
    Za, Zq = -qS / m * (a.CLa + CD), -qS / m * a.CLq * a.c_m / V0
    Ma = qS * a.c_m * a.Cma / I_cg[1, 1]
    Mq = qS * a.c_m * a.Cmq * (a.c_m / V0) / I_cg[1, 1]
    Mad = qS * a.c_m * a.Cmadot * (a.c_m / V0) / I_cg[1, 1]
    A2 = np.array([[Za / V0, 1 + Zq / V0], [Ma + Mad * Za / V0, Mq + Mad * (1 + Zq / V0)]])
    ev = np.linalg.eigvals(A2)[0]
    wn, zeta = abs(ev), -ev.real / abs(ev)
    sp = md["short_period"]
    # neglected: coupling with the speed/pitch-attitude (phugoid) states, O((w_ph/w_sp)^2) ~ 1e-3,
    # and gravity/alpha0 terms O(g/(V w_sp)) ~ 2 %
    assert sp["omega_n_rad_s"] == pytest.approx(wn, rel=0.02)
    assert sp["zeta"] == pytest.approx(zeta, rel=0.03)
    assert 1.5 < sp["omega_n_rad_s"] < 5.0            # light business jet
    assert 0.3 < sp["zeta"] < 0.9
    ph = md["phugoid"]
    # Lanchester: w = sqrt(2) g / V, accurate to ~15 % (it ignores pitch stiffness and density gradient)
    assert ph["omega_n_rad_s"] == pytest.approx(math.sqrt(2) * G0 / V0, rel=0.15)
    assert 40 < ph["period_s"] < 120 and 0.0 < ph["zeta"] < 0.2
    # roll subsidence: 1-DOF approximation tau = -1/L_p (Dutch-roll coupling ~10 %)
    Lp = qS * a.b_m * a.Clp * (a.b_m / (2 * V0)) / I_cg[0, 0]
    assert md["roll"]["time_constant_s"] == pytest.approx(-1 / Lp, rel=0.10)
    # Dutch roll: w^2 ~ N_beta (directional stiffness), ~10 %
    Nb = qS * a.b_m * a.Cnb / I_cg[2, 2]
    assert md["dutch_roll"]["omega_n_rad_s"] == pytest.approx(math.sqrt(Nb), rel=0.10)
    assert 0.03 < md["dutch_roll"]["zeta"] < 0.4


def test_manoeuvres_come_from_control_inputs(short_flight):
    tr = short_flight
    roll, _pitch, _yaw = earth.euler_from_q(tr.q_NB)
    names = [p[0] for p in tr.phases]
    assert names == ["level", "elevator_3211", "double_doublet", "alpha_dot_s_turns"]
    # the 3-2-1-1 happened in the elevator, and the aircraft answered in pitch rate
    m = tr.phase_mask("elevator_3211")
    w_NB = tr.w_IB_B - np.einsum("nji,nj->ni", earth.C_from_q(tr.q_NB),
                                 earth.omega_IE_N(tr.lat_rad) + earth.omega_EN_N(tr.lat_rad, tr.h_m, tr.v_N))
    assert np.abs(w_NB[m, 1]).max() > 2 * math.radians(1.0)
    s = tr.phase_mask("alpha_dot_s_turns")
    assert np.degrees(roll[s]).max() == pytest.approx(30.0, abs=2.0)
    assert np.degrees(roll[s]).min() == pytest.approx(-30.0, abs=2.0)
    n_z = -tr.f_B[:, 2] / G0
    n_level_turn_28deg = 1 / math.cos(math.radians(28))          # load factor of a level turn at 28 deg bank
    assert n_level_turn_28deg < n_z[s].max() < 3.0               # banked turn + doublet, below the limit load


def test_truth_mechanisation_reproduces_itself(short_flight):
    """Integrating the NED mechanisation with the truth's own f_B and w_IB_B gives back its
    positions: to rounding with the scheme the samples obey, to O(dt) with a trapezoidal one."""
    tr = short_flight
    lat, lon, h, v, _ = mechanise(tr, scheme="euler")
    d = earth.ned_from_geodetic(lat, lon, h, tr.lat_rad, tr.lon_rad, tr.h_m)
    assert np.abs(d).max() < 1e-6 and np.abs(v - tr.v_N).max() < 1e-8
    lat, lon, h, v, _q = mechanise(tr, scheme="trapezoid")
    d = earth.ned_from_geodetic(lat, lon, h, tr.lat_rad, tr.lon_rad, tr.h_m)
    dt = 1 / tr.rate_hz
    # trapezoid vs the samples' piecewise-constant acceleration and end-of-step rate:
    #   velocity error <= dt/2 (max|a - a0| + max|f| * total rotation angle)  (attitude lag dt/2 |w|)
    #   position error <= flight time * that velocity bound
    a_kin = np.gradient(tr.v_N, dt, axis=0)
    angle = np.sum(np.linalg.norm(tr.w_IB_B, axis=1)) * dt
    dv_bound = dt / 2 * (np.linalg.norm(a_kin - a_kin[0], axis=1).max() + np.linalg.norm(tr.f_B, axis=1).max() * angle)
    assert np.linalg.norm(v - tr.v_N, axis=1).max() <= dv_bound
    assert np.linalg.norm(d, axis=1).max() <= dv_bound * (tr.time_s[-1] - tr.time_s[0])
    assert np.linalg.norm(d, axis=1).max() < 5.0


def test_static_truth_closed_form_earth_terms():
    st = static_tests_truth(dwell_s=2.0, transition_s=1.0)
    C = earth.C_from_q(st.q_NB)
    g_B = np.einsum("nji,nj->ni", C, earth.gravity_N(st.lat_rad, st.h_m))
    np.testing.assert_allclose(st.f_B, -g_B, atol=1e-12)
    static = np.zeros(st.n, bool)
    for name, a, b in st.phases:
        static |= (st.time_s >= a) & (st.time_s < b)
    wie_B = np.einsum("nji,nj->ni", C, earth.omega_IE_N(st.lat_rad))
    np.testing.assert_allclose(st.w_IB_B[static], wie_B[static], atol=1e-18)
    assert np.linalg.norm(st.w_IB_B[0]) == pytest.approx(earth.OMEGA_E_RAD_S, rel=1e-12)
    roll, _pitch, _ = earth.euler_from_q(st.q_NB)
    i = st.phase_mask("static_roll-30_pitch+0")
    np.testing.assert_allclose(np.degrees(roll[i]), -30.0, atol=1e-9)
    import pyIGRF

    from imurig.kernel.site import decimal_year, parse_time
    _, _, _, bn, be, bd, F = pyIGRF.igrf_value(52.31, 4.76, 0.043, decimal_year(parse_time(st.meta["start_time"])))
    assert np.linalg.norm(st.B_B[0]) * 1e9 == pytest.approx(F, rel=1e-4)
    np.testing.assert_allclose(C[0] @ st.B_B[0] * 1e9, [bn, be, bd], rtol=2e-4, atol=2.0)


def test_fog_sees_the_earth_rate_through_the_chain():
    """Ideal, noise-free FOGs on the static fixture: the recorded gyro volts average to
    C_BN Omega_IE within the ADC's dither and common-mode noise."""
    st = static_tests_truth(attitudes_deg=((0.0, 0.0),), dwell_s=60.0)
    lab = ImuLab(gyros=FOGTriad(noise_enabled=False))
    rec = measure_flight(st, lab, np.random.SeedSequence(4))
    sens = np.array(rec.meta["gyro_nominal_sensitivity_V_per_rad_s"])
    w = rec.stack(["gyro_p", "gyro_q", "gyro_r"]) / sens
    q = rec.meta["adc"]["lsb_V"]
    per_sample_V = math.sqrt((q ** 2 / 12 + (0.6 * q) ** 2) / rec.meta["adc"]["averaging"] + 30e-6 ** 2)
    se = per_sample_V / sens / math.sqrt(st.n)
    np.testing.assert_array_less(np.abs(w.mean(0) - st.w_IB_B.mean(0)), 4 * se)
    assert np.all(np.abs(st.w_IB_B.mean(0)) > 8 * se[0]) or np.linalg.norm(st.w_IB_B[0]) > 40 * se[0]
    a = measure_flight(st, ImuLab(), np.random.SeedSequence(7))
    b = measure_flight(st, ImuLab(), np.random.SeedSequence(7))
    np.testing.assert_array_equal(a.channels["acc_z"], b.channels["acc_z"])


def test_ground_circle_and_takeoff():
    plan = FlightPlan(phases=(Parked(2.0), GroundCircle(radius_m=25.0, speed_m_s=5.0, turns=1.0), Takeoff()))
    tr = simulate_flight(plan, progress_bar=False)
    lat0, lon0, h0 = tr.lat_rad[0], tr.lon_rad[0], tr.h_m[0]
    p = earth.ned_from_geodetic(tr.lat_rad, tr.lon_rad, tr.h_m, lat0, lon0, h0)
    m = tr.phase_mask("ground_circle") & (tr.time_s > 10.0)
    x, y = p[m, 0], p[m, 1]
    A = np.stack([x, y, np.ones_like(x)], 1)
    c = np.linalg.lstsq(A, x ** 2 + y ** 2, rcond=None)[0]
    R = math.sqrt(c[2] + (c[0] / 2) ** 2 + (c[1] / 2) ** 2)
    assert R == pytest.approx(25.0 + 1.5 + 0.3, abs=2.0)     # the IMU rides 1.5 m ahead of the main gear
    roll, pitch, yaw = earth.euler_from_q(tr.q_NB)
    assert np.abs(np.degrees(roll[m])).max() < 1.0 and np.abs(np.degrees(pitch[m])).max() < 1.0
    assert np.ptp(np.unwrap(yaw[tr.phase_mask("ground_circle")])) > 1.9 * math.pi
    assert tr.h_m[-1] - h0 > 45.0
    assert tr.vehicle == "citation" and tr.lever_gps_B[2] < 0      # antenna on the roof


@pytest.mark.parametrize("phase, match", [
    (AlphaDotSTurns(banks_first_deg=(20.0, 80.0)), "impossible"),
    (AlphaDotSTurns(banks_first_deg=(70.0,)), "limit load factor"),
    (GroundCircle(radius_m=2.0), "nose-wheel"),
    (Level(10.0, speed_m_s=40.0), "V_stall"),
])
def test_impossible_plans_are_refused(phase, match):
    with pytest.raises(ConfigError, match=match):
        FlightPlan(phases=(phase,)).validate()


def test_van_ground_test():
    from imurig.flights.van import (
        VanCircle,
        VanHardBrake,
        VanParked,
        VanPlan,
        VanRamp,
        VanStraight,
        simulate_van,
    )

    plan = VanPlan(phases=(VanParked(2.0), VanStraight(4.0, 8.0), VanCircle(15.0, 5.0, 0.5, "right"),
                           VanHardBrake(10.0), VanParked(2.0), VanRamp(angle_deg=5.0, park_s=6.0)))
    tr = simulate_van(plan)
    assert tr.vehicle == "van" and tr.lever_mag_B[0] < -7.0          # the boom: 5 m behind the van's back
    roll, pitch, _ = earth.euler_from_q(tr.q_NB)
    flat = np.degrees(pitch[tr.phase_mask("parked")][0])
    brake = tr.phase_mask("hard_braking")
    # tyre forces saturate at mu N: the deceleration cannot exceed (mu + c_rr) g
    mu, crr = 0.9, 0.012
    decel = -tr.f_B[brake, 0]
    assert 0.6 * G0 < decel.max() <= (mu + crr) * earth.normal_gravity(tr.lat_rad[0], tr.h_m[0]) * 1.01
    assert np.degrees(pitch[brake]).min() < flat - 1.0                 # the nose dives
    assert np.degrees(roll[tr.phase_mask("circle")]).min() < -1.0      # right turn: body rolls out (left)
    end = tr.time_s > tr.time_s[-1] - 1.0
    np.testing.assert_allclose(np.degrees(pitch[end]), 5.0 + flat, atol=0.3)
    assert np.abs(tr.v_N[end]).max() < 0.01
    lat, lon, h, _v, _q = mechanise(tr, scheme="euler")
    assert np.abs(earth.ned_from_geodetic(lat, lon, h, tr.lat_rad, tr.lon_rad, tr.h_m)).max() < 1e-6
    with pytest.raises(ConfigError, match="skid"):
        VanPlan(phases=(VanCircle(10.0, 12.0),)).validate()
