"""The tilt table's dynamic twin (imurig.diagnose.tilt_twin): MuJoCo only where the table moves and
while the servo's transient lasts, the closed form at rest, against MuJoCo stepping every sample."""
from __future__ import annotations

import mujoco
import numpy as np
import pytest

from imurig.diagnose.tilt_twin import (SETTLE_TOL, _pieces, _near_limits, _plan, tilt_table_twin,
                                       tilt_table_twin_full)
from imurig.kernel.errors import ConfigError
from imurig.kernel.recording import Recording
from imurig.kernel.units import ARCMIN, DEG
from imurig.rigs.mujoco_rig import load_model, servo_settle_samples
from imurig.rigs.tilt_kinematics import specific_force_C
from imurig.rigs.tilt_table import MOUNTS, _quat_wxyz

FS = 200.0


def _run(sp_deg: list[tuple[float, float, float]], ramp_s: float = 0.0) -> np.ndarray:
    """Set-points (n, 2) rad at FS from (theta, phi, hold s) steps; with ``ramp_s`` the last step is
    logged as a linear ramp over that time (a logger that writes the trajectory)."""
    rows = []
    for k, (th, ph, hold) in enumerate(sp_deg):
        if ramp_s and k == len(sp_deg) - 1:
            p0, p1 = np.array(rows[-1][-1]), np.array([th, ph]) * DEG
            s = np.arange(1, int(ramp_s * FS) + 1)[:, None] / (ramp_s * FS)
            rows.append(p0 + s * (p1 - p0))
        rows.append(np.repeat(np.array([[th, ph]]) * DEG, int(hold * FS), 0))
    return np.concatenate(rows)


def _recording(theta_max_deg: float = 60.0) -> Recording:
    """Two runs (z_down, then z_up after a gap): stepped moves, a hold too short to settle (0.3 s) and a
    logged ramp; the survey's zero errors and levelling; 200 Hz."""
    a = _run([(0, 0, 2.0), (30, 60, 2.5), (theta_max_deg, 90, 0.3), (-20, 200, 2.5), (10, 120, 2.0)], ramp_s=1.0)
    b = _run([(10, 0, 1.5), (45, -90, 0.2), (0, 30, 2.5), (80, 330, 2.0)], ramp_s=0.8)
    n_a, n_b = a.shape[0], b.shape[0]
    t = np.concatenate([np.arange(n_a) / FS, 100.0 + np.arange(n_b) / FS])
    sp = np.concatenate([a, b])
    survey = {"theta_zero_rad": 1.1 * ARCMIN, "level_x_rad": 0.3 * ARCMIN,
              "phi_zero_rad": {"z_down": 85 * ARCMIN, "z_up": 101 * ARCMIN}}
    return Recording(time_s=t, channels={"theta": sp[:, 0], "phi": sp[:, 1]}, units={"theta": "rad", "phi": "rad"},
                     segments={"start_s": np.array([0.5, 100.5]), "stop_s": np.array([1.5, 101.0]),
                               "mount": np.array(["z_down", "z_up"])},
                     meta={"rig": "tilt_table", "runs": ["z_down", "z_up"], "table_survey": survey,
                           "table_azimuth_deg": 20.0, "protocol": {"slew_rate_deg_s": 30.0}}).validate()


def _labels(rec: Recording, tol: float = SETTLE_TOL, stops: str = "infer") -> np.ndarray:
    """Per sample: 1 at rest (closed form), 2 stepped, 3 stepped near a joint's limit."""
    out = np.zeros(rec.n, int)
    for b, _, m, ctrl in _plan(rec, None, 1e-5, stops)["replays"]:
        near = _near_limits(m, ctrl, 0.0)
        for a, e, hold in _pieces(ctrl, servo_settle_samples(m, tol), near):
            out[b.start + a:b.start + e] = 1 if hold else (3 if near[a:e].any() else 2)
    return out


@pytest.fixture(scope="module")
def twins():
    rec = _recording()
    return rec, tilt_table_twin_full(rec), tilt_table_twin(rec)


def test_servo_settles_within_its_bound():
    """MuJoCo's step of the table (implicitfast) decays at least as fast as exp(-dt min(kp / kv)) (the
    servo's slow pole, rigs.mujoco_rig.servo_settle_samples) at any pose, mounting and sample rate: the
    spectral radius of the linearised step, from mjd_transitionFD, lies below it."""
    for dt in (1e-3, 1 / 102.4, 0.02):
        for mount in MOUNTS:
            for q in ((0.0, 0.0), (0.8, 2.0), (1.6, 4.0)):
                m = load_model("tilt_table.xml")
                m.opt.timestep = dt
                m.body_quat[m.body("imu_mount").id] = _quat_wxyz(MOUNTS[mount])
                d = mujoco.MjData(m)
                d.qpos[:] = d.ctrl[:] = q
                mujoco.mj_forward(m, d)
                A = np.zeros((2 * m.nv, 2 * m.nv))
                mujoco.mjd_transitionFD(m, d, 1e-7, 1, A, None, None, None)
                rate = np.min(m.actuator_gainprm[:, 0] / -m.actuator_biasprm[:, 2])
                assert np.max(np.abs(np.linalg.eigvals(A))) < np.exp(-dt * rate)
    m = load_model("tilt_table.xml")
    assert servo_settle_samples(m, 1e-12) == int(np.ceil(np.log(1e12) / (20.0 * m.opt.timestep)))
    with pytest.raises(ConfigError):
        servo_settle_samples(m, 0.0)


def test_moves_are_stepped_and_rests_are_closed_form(twins):
    """MuJoCo steps from each change of the commands to the settling time after the last (a 0.2-0.3 s hold
    and a logged ramp are stepped through); the rest is closed form."""
    rec, _, _ = twins
    lab = _labels(rec)
    ns = servo_settle_samples(_plan(rec, None, 1e-5)["replays"][0][2], SETTLE_TOL)
    assert ns == int(np.ceil(np.log(1 / SETTLE_TOL) / (20.0 / FS)))
    for b, _, _, ctrl in _plan(rec, None, 1e-5)["replays"]:
        ch = np.flatnonzero(np.any(ctrl[:, 1:] != ctrl[:, :-1], axis=(0, 2))) + 1
        stepped = np.zeros(b.stop - b.start, bool)
        for c in ch:
            stepped[c:c + ns] = True
        np.testing.assert_array_equal(lab[b] == 2, stepped)
        assert np.any(lab[b] == 1)


def _bounds(rec: Recording, resting: bool) -> dict:
    """What the stitched twin may differ by from the full replay. A joint error e0 at the start of a
    piece: the settling leaves SETTLE_TOL of the largest move d (the span of the commands), and the
    replay rounds the joint angles (4 eps |q|max). At rest it is in the servo's slow mode (rate r at
    most 2 kp / kv): f_C by g e0 (attitude) plus |r0| r^2 e0 (the servo's acceleration at the lever
    arm r0), w_C by r e0. A move starting from it excites the fast mode too: up to (kp / I) |r0| e0 in
    f_C (I: the joint's armature, the least inertia). The responses: two replays over delta_rad."""
    m = load_model("tilt_table.xml")
    kp, kv = m.actuator_gainprm[:, 0], -m.actuator_biasprm[:, 2]
    span = max(np.ptp(rec.channels[k]) for k in ("theta", "phi")) + 2 * 2 * DEG   # + survey offsets
    e0 = SETTLE_TOL * span + 4 * np.finfo(float).eps * (np.max(np.abs(rec.channels["phi"])) + 2 * DEG)
    r, r0, g = 2 * np.max(kp / kv), 0.09, 9.82
    acc = r ** 2 if resting else np.max(kp / m.dof_armature)
    f = (g + r0 * acc) * e0
    return {"f_C": f, "w_C": (r if resting else np.max(kv / m.dof_armature)) * e0, "resp": 2 * f / 1e-5}


def test_stitched_twin_equals_full_stepping(twins):
    """Against MuJoCo stepping every sample: at rest (closed form) and in the moves (MuJoCo from a rest
    state), f_C, w_C and the responses resp agree within what the settling and the rounding of the
    joint angles leave (:func:`_bounds`); at rest f_C is the closed form of tilt_kinematics
    (specific_force_C, another evaluation of R_CW (0, 0, g)) to rounding, and w_C = 0."""
    rec, full, new = twins
    lab = _labels(rec)
    for where in (1, 2):
        for k, bound in _bounds(rec, resting=where == 1).items():
            diff = np.abs(new[k] - full[k]).reshape(-1, rec.n, 3).max(axis=(0, 2))[lab == where]
            assert diff.max() < bound, (k, where, diff.max(), bound)
    np.testing.assert_array_equal(new["window_start"], full["window_start"])
    np.testing.assert_array_equal(new["r0_C"], full["r0_C"])
    sv = rec.meta["table_survey"]
    for b, mount in zip(rec.blocks(), ("z_down", "z_up")):
        rest = lab[b] == 1
        th, ph = rec.channels["theta"][b][rest], rec.channels["phi"][b][rest]
        f = specific_force_C(th, ph, mount, new["gravity_m_s2"], sv["theta_zero_rad"], sv["phi_zero_rad"][mount],
                             sv["level_x_rad"])
        np.testing.assert_allclose(new["f_C"][b][rest], f, rtol=0, atol=16 * np.spacing(new["gravity_m_s2"]))
        assert np.all(new["w_C"][b][rest] == 0)


def test_limits_are_stepped():
    """A command beyond a joint's range (theta 120 deg; the MJCF's range is +-1.75 rad): the limit's
    constraint, not the servo, sets where the table rests, so MuJoCo steps it as the full replay does;
    the two agree to the constraint solver's tolerance (opt.tolerance of g)."""
    rec = _recording(theta_max_deg=120.0)
    full, new = tilt_table_twin_full(rec, stops="model"), tilt_table_twin(rec, stops="model")
    lab = _labels(rec, stops="model")
    assert np.any(lab == 3)
    m = load_model("tilt_table.xml")
    diff = np.abs(new["f_C"] - full["f_C"]).max(axis=1)
    assert diff.max() < m.opt.tolerance * full["gravity_m_s2"]


def test_stops_past_the_set_points_are_removed():
    """Another lab's table commanded to theta 150 deg (past the MJCF's +-1.75 rad stops) evidently gets
    there: by default the twin removes the stops it is commanded past, says so, and rests at the
    commanded attitude (the closed form of tilt_kinematics to rounding, at 150 deg too); with
    stops="model" it rests at the stop instead, tens of degrees away (metres per second squared in f_C)."""
    sp = _run([(0, 0, 2.0), (150, 30, 12.0), (10, 0, 8.0)])
    survey = {"theta_zero_rad": 1.1 * ARCMIN, "level_x_rad": 0.3 * ARCMIN, "phi_zero_rad": {"z_up": 101 * ARCMIN}}
    rec = Recording(time_s=np.arange(sp.shape[0]) / FS, channels={"theta": sp[:, 0], "phi": sp[:, 1]},
                    units={"theta": "rad", "phi": "rad"},
                    segments={"start_s": np.array([0.5]), "stop_s": np.array([1.5]), "mount": np.array(["z_up"])},
                    meta={"rig": "tilt_table", "runs": ["z_up"], "table_survey": survey, "table_azimuth_deg": 0.0,
                          "protocol": {"slew_rate_deg_s": 30.0}}).validate()
    new, kept = tilt_table_twin(rec), tilt_table_twin(rec, stops="model")
    assert len(new["stops_removed"]) == 1 and new["stops_removed"][0].startswith("theta")
    assert kept["stops_removed"] == []
    rest = _labels(rec) == 1
    far = rest & (rec.channels["theta"] > 2.0)
    assert far.sum() > FS
    th, ph = rec.channels["theta"][rest], rec.channels["phi"][rest]
    f = specific_force_C(th, ph, "z_up", new["gravity_m_s2"], survey["theta_zero_rad"], survey["phi_zero_rad"]["z_up"],
                         survey["level_x_rad"])
    np.testing.assert_allclose(new["f_C"][rest], f, rtol=0, atol=16 * np.spacing(new["gravity_m_s2"]))
    assert np.abs(kept["f_C"][far] - new["f_C"][far]).min() > 1.0
    with pytest.raises(ValueError, match="stops must be"):
        tilt_table_twin(rec, stops="none")
