"""The six-position-and-rotation protocol, the smallest protocols and `imurig calibrate` for every rig.

The recordings here come from a forward model written in this file with numpy only (no imports
from the rigs or sensors): a box still on its six faces, turned between them, then rotated by hand
through 360 deg about each axis. Per sample, with f the specific force and w the rate in the body:

    acc = K_a f + b_a + n_a,    gyro = K_g w + b_g + n_g,    K = diag(1 + s) (I + M),

white noise n of known standard deviation. Estimates are checked against this truth within
k standard errors, with the standard errors from the noise.
"""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from imurig.calibration.preprocess import lowpass_downsample
from imurig.calibration.six_face import FACES, detect, face_table, fit_accelerometer
from imurig.calibration.six_face_gyro import fit_gyro
from imurig.campaigns.turn_table import TurnTableCampaign
from imurig.cli.main import main
from imurig.kernel.labcsv import write_csv
from imurig.kernel.recording import Recording, save_h5
from imurig.reports.tilt_table import _report_md, analyse
from imurig.rigs.turn_table import TurnTableProtocol

G = 9.81
FS = 102.4
SIG_A = 0.02            # m/s^2 per sample
SIG_G = math.radians(0.2)  # rad/s per sample


def _rot(axis: int, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    R = np.eye(3)
    i, j = [k for k in range(3) if k != axis]
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


def truth(rng: np.random.Generator) -> dict:
    def k(scale, mis):
        M = rng.normal(0, mis, (3, 3))
        np.fill_diagonal(M, 0)
        return np.diag(1 + rng.normal(0, scale, 3)) @ (np.eye(3) + M)
    return {"K_a": k(0.01, 0.005), "b_a": rng.normal(0, 0.1, 3),
            "K_g": k(0.01, 0.005), "b_g": rng.normal(0, math.radians(0.5), 3)}


#: (axis, angle deg, duration s) of the turns: four 90 deg turns and one 180 deg turn onto the six
#: faces (+z, +y, -z, -y, -x, +x), then 360 deg about x, y and z
TURNS = [(0, 90, 2.0), (0, 90, 2.0), (0, 90, 2.0), (2, 90, 2.0), (2, 180, 3.0),
         (0, 360, 4.0), (1, 360, 5.0), (2, -360, 4.0)]


def make_session(rng: np.random.Generator, tr: dict, still_s: float = 8.0, units=("m_s2", "dps")) -> Recording:
    """A six-face-and-rotation recording at FS from the forward model of the module doc."""
    f0 = np.array([0.0, 0.0, G])
    fs, ws = [], []
    n_still = int(still_s * FS)
    for turn in TURNS + [None]:
        fs.append(np.tile(f0, (n_still, 1)))
        ws.append(np.zeros((n_still, 3)))
        if turn is None:
            break
        ax, deg, dur = turn
        n = int(dur * FS)
        t = (np.arange(n) + 0.5) / FS
        rate = math.radians(deg) * 2 / dur * np.sin(np.pi * t / dur) ** 2   # integrates to the angle
        phi = np.cumsum(rate) / FS
        w = np.zeros((n, 3))
        w[:, ax] = rate
        fs.append(np.array([_rot(ax, -p) @ f0 for p in phi]))
        ws.append(w)
        f0 = _rot(ax, -phi[-1]) @ f0
        f0[np.abs(f0) < 1e-9] = 0.0
    f, w = np.vstack(fs), np.vstack(ws)
    acc = f @ tr["K_a"].T + tr["b_a"] + rng.normal(0, SIG_A, f.shape)
    gyro = w @ tr["K_g"].T + tr["b_g"] + rng.normal(0, SIG_G, w.shape)
    chans = {f"acc_{a}": acc[:, j] for j, a in enumerate("xyz")}
    chans.update({f"gyro_{a}": gyro[:, j] for j, a in enumerate("pqr")})
    units_si = {"m_s2": "m/s^2", "dps": "rad/s"}
    rec = Recording(time_s=np.arange(len(f)) / FS, channels=chans,
                    units={k: "m/s^2" if k.startswith("acc") else "rad/s" for k in chans},
                    meta={"rig": "six_face", "site": {"gravity_m_s2": G}, "source": "forward-model"})
    assert units_si[units[0]] == "m/s^2"
    return rec.validate()


def true_params(K: np.ndarray, b: np.ndarray, axes: str, prefix: str = "") -> dict:
    """The forward model's parameters as the calibration names them: sensitivity K_jj, misalignment
    K_jk / K_jj, bias b_j / K_jj."""
    out = {f"{prefix}sensitivity_{a}": K[j, j] for j, a in enumerate(axes)}
    out.update({f"{prefix}misalignment_{axes[i]}{axes[k]}": K[i, k] / K[i, i]
                for i in range(3) for k in range(3) if i != k})
    out.update({f"{prefix}bias_{a}": b[j] / K[j, j] for j, a in enumerate(axes)})
    return out


@pytest.fixture(scope="module")
def session():
    rng = np.random.default_rng(20261124)
    tr = truth(rng)
    return tr, make_session(rng, tr)


def test_protocol_recognised_six_faces_and_three_rotations(session):
    _, rec = session
    p = detect(rec)
    assert all(len(p.faces[f]) >= 1 for f in FACES)
    assert len(p.faces["+x"]) == 4          # the last face, and the still windows between the rotations
    assert [(r["axis"], r["sign"]) for r in p.rotations] == [(0, 1.0), (1, 1.0), (2, -1.0)]


def test_six_face_estimates_within_4_se_of_truth(session):
    tr, rec = session
    p = detect(rec)
    acc = rec.stack(["acc_x", "acc_y", "acc_z"])
    m, v, _ = face_table(acc, p.faces)
    ra = fit_accelerometer(m, v, G)
    gy = fit_gyro(rec.stack(["gyro_p", "gyro_q", "gyro_r"]), FS, p.faces, p.rotations)
    want = {**true_params(tr["K_a"], tr["b_a"], "xyz"), **true_params(tr["K_g"], tr["b_g"], "pqr")}
    got = ra["parameters"] + gy["parameters"]
    assert len(got) == 24
    for q in got:
        assert abs(q["estimate"] - want[q["name"]]) < 4 * q["std_error"], q
    # six faces: the linear model only; the own square would leave one degree of freedom, the cross
    # products are zero on every face; each is named with its reason
    assert all(t == ["1", "fx", "fy", "fz"] for t in ra["terms"].values())
    assert any("own square (A_x, A_y, A_z)" in s and "degree(s) of freedom" in s for s in ra["left_out"])
    assert any("fx*fy" in s and "not identifiable" in s for s in ra["left_out"])
    # the gyro's standard errors come from the noise: the scale's SE is the white noise integrated
    # over the rotation, sqrt(sigma^2 T / fs) / angle, within the bias's share
    T = np.array([r["slice"].stop - r["slice"].start for r in p.rotations]) / FS
    se_scale = SIG_G * np.sqrt(T / FS) / (2 * np.pi)
    got_se = np.array([q["std_error"] for q in gy["parameters"][:3]])
    assert np.all(got_se > 0.8 * se_scale * np.diag(tr["K_g"])) and np.all(got_se < 1.5 * se_scale)


def test_standard_errors_are_honest_over_sessions():
    """30 sessions drawn sample by sample from the forward model, each recognised and fitted: the
    z = (estimate - truth) / SE of the 12 accelerometer and 12 gyro parameters have RMS 1 within
    the scatter of 720 z values (about 0.03, correlated within a session)."""
    rng = np.random.default_rng(99)
    z = []
    for _ in range(30):
        tr = truth(rng)
        rec = make_session(rng, tr)
        p = detect(rec)
        m, v, _ = face_table(rec.stack(["acc_x", "acc_y", "acc_z"]), p.faces)
        got = fit_accelerometer(m, v, G)["parameters"] + fit_gyro(
            rec.stack(["gyro_p", "gyro_q", "gyro_r"]), FS, p.faces, p.rotations)["parameters"]
        want = {**true_params(tr["K_a"], tr["b_a"], "xyz"), **true_params(tr["K_g"], tr["b_g"], "pqr")}
        z += [(q["estimate"] - want[q["name"]]) / q["std_error"] for q in got]
    rms = float(np.sqrt(np.mean(np.square(z))))
    assert len(z) == 720 and 0.85 < rms < 1.2, rms


def test_standard_errors_do_not_shrink_when_faces_are_cut(session):
    """1 window per face vs each face cut into 5 sub-windows: the same independent observations, so
    the same standard errors (here equal to rounding; the bound is the SE's own sampling scatter,
    sqrt(1 / (2 dof)) with dof = 2 residual degrees of freedom of six faces)."""
    _, rec = session
    p = detect(rec)
    one = {f: [slice(p.faces[f][0].start, p.faces[f][0].stop)] for f in FACES}
    cut = {f: [slice(a, min(a + (s.stop - s.start) // 5 + 1, s.stop))
               for s in one[f] for a in range(s.start, s.stop, (s.stop - s.start) // 5 + 1)] for f in FACES}
    assert all(len(cut[f]) == 5 for f in FACES)
    acc = rec.stack(["acc_x", "acc_y", "acc_z"])
    se = []
    for faces in (one, cut):
        m, v, _ = face_table(acc, faces)
        se.append(np.array([q["std_error"] for q in fit_accelerometer(m, v, G)["parameters"]]))
    assert np.all(np.abs(se[1] / se[0] - 1) < 0.5), se[1] / se[0]


# ------------------------------------------------------------------ the command line
def _csv(rec: Recording, path) -> str:
    write_csv(rec, path)
    return str(path)


def test_cli_six_face_csv_in_physical_units(session, tmp_path, capsys):
    """A 102.4 Hz lab CSV in m/s^2 and deg/s with only a '# rig:' line calibrates from the command line."""
    tr, rec = session
    path = _csv(rec.replace(meta={"rig": "six_face", "site": {"gravity_m_s2": G}}), tmp_path / "box.csv")
    assert main(["calibrate", path, "--out", str(tmp_path / "cal")]) == 0
    s = json.loads((tmp_path / "cal" / "summary.json").read_text())
    want = {**true_params(tr["K_a"], tr["b_a"], "xyz"), **true_params(tr["K_g"], tr["b_g"], "pqr", "gyro_")}
    assert {p["name"] for p in s["parameters"]} == set(want)
    for p in s["parameters"]:
        assert abs(p["estimate"] - want[p["name"]]) < 4 * p["std_error"], p
    # the calibrations apply: the gyro's calibrated rate on a still face is the bias removed
    assert main(["apply", str(tmp_path / "cal" / "calibration_gyro.json"), path, "--out",
                 str(tmp_path / "applied.h5")]) == 0


def test_cli_refuses_a_gyro_nonlinearity_from_one_rotation_per_axis(session, tmp_path, capsys):
    _, rec = session
    path = _csv(rec, tmp_path / "box.csv")
    assert main(["calibrate", path, "--model", "physical", "--out", str(tmp_path / "cal")]) == 2
    err = capsys.readouterr().err
    assert "nonlinearity cannot be identified" in err and "--model linear" in err and "Traceback" not in err
    assert not (tmp_path / "cal").exists()


def test_cli_refuses_a_missing_face(session, tmp_path, capsys):
    _, rec = session
    p = detect(rec)
    keep = np.ones(rec.n, bool)
    keep[p.faces["-y"][0]] = False   # the box never rests on -y
    cut = rec.replace(time_s=rec.time_s[keep], channels={k: v[keep] for k, v in rec.channels.items()})
    assert main(["calibrate", _csv(cut, tmp_path / "box.csv"), "--out", str(tmp_path / "cal")]) == 2
    err = capsys.readouterr().err
    assert "missing ['-y']" in err and "Traceback" not in err


def test_counts_need_their_sensitivity_and_then_calibrate(session, tmp_path, capsys):
    """ADC counts: refused without counts per SI unit in the metadata, calibrated with it (the
    sensitivity then comes out in counts/(m/s^2) at the nominal value times the true scale)."""
    tr, rec = session
    k = 1000.0  # counts per m/s^2 and per rad/s
    ch = {n: np.round(v * k) for n, v in rec.channels.items()}
    counts = rec.replace(channels=ch, units={n: "1" for n in ch})
    assert main(["calibrate", _csv(counts, tmp_path / "c.csv"), "--rig", "six-face", "--out",
                 str(tmp_path / "c0")]) == 2
    assert "acc_nominal_sensitivity_counts_per_m_s2" in capsys.readouterr().err
    meta = {**rec.meta, "acc_nominal_sensitivity_counts_per_m_s2": k, "gyro_nominal_sensitivity_counts_per_rad_s": k}
    assert main(["calibrate", _csv(counts.replace(meta=meta), tmp_path / "c1.csv"), "--rig", "six-face",
                 "--out", str(tmp_path / "c1")]) == 0
    s = {p["name"]: p for p in json.loads((tmp_path / "c1" / "summary.json").read_text())["parameters"]}
    for j, a in enumerate("xyz"):
        p = s[f"sensitivity_{a}"]
        assert p["unit"] == "counts/(m/s^2)"
        assert abs(p["estimate"] - k * tr["K_a"][j, j]) < 4 * p["std_error"], p


def test_any_sample_rate_goes_through_the_preprocessing(session):
    """102.4 Hz has no whole ratio to 100 Hz: the record keeps its rate (and is low-passed)."""
    _, rec = session
    seg = rec.replace(segments={"start_s": np.array([0.0]), "stop_s": np.array([5.0])},
                      segment_units={"start_s": "s", "stop_s": "s"})
    out = lowpass_downsample(seg)
    assert out.n == rec.n and math.isclose(out.meta["sample_rate_hz"], FS)
    fast = seg.replace(time_s=np.arange(rec.n) / 250.0)
    assert math.isclose(lowpass_downsample(fast).meta["sample_rate_hz"], 125.0)


@pytest.fixture(scope="module")
def turn_table_h5(tmp_path_factory):
    """A short turn-table campaign (one rate, both directions, three mountings) as the project records it."""
    path = tmp_path_factory.mktemp("tt") / "turn.h5"
    p = TurnTableProtocol(dial_rates_dps=(100,), min_window_s=2.0, settle_s=1.0, ramp_s=1.0, remount_s=5.0)
    save_h5(TurnTableCampaign(protocol=p, seed=5).simulate(), path)
    return path


def test_cli_calibrates_a_turn_table_recording(turn_table_h5, tmp_path, capsys):
    assert main(["calibrate", str(turn_table_h5), "--rig", "turn-table", "--model", "linear",
                 "--out", str(tmp_path / "cal")]) == 0
    s = json.loads((tmp_path / "cal" / "summary.json").read_text())
    assert len(s["parameters"]) == 12
    for p in s["parameters"]:
        assert abs(p["z"]) < 4, p
    assert json.loads((tmp_path / "cal" / "calibration.json").read_text())["kind"] == "imurig.gyro_inverse_model"
    assert main(["calibrate", str(turn_table_h5), "--model", "cross", "--out", str(tmp_path / "x")]) == 2
    assert "--model" in capsys.readouterr().err
    # one rate per direction cannot carry the seed's ten-term model: refused with the count, no traceback
    assert main(["calibrate", str(turn_table_h5), "--model", "seed_final", "--out", str(tmp_path / "y")]) == 2
    err = capsys.readouterr().err
    assert "6 observations cannot fit the 10 terms" in err and "Traceback" not in err


def test_tilt_table_with_six_positions_selects_only_what_the_data_can_test(small_recording):
    """Six tilt-table positions (fewer than the ten-term library): the selection keeps the linear model,
    says which terms it could not test and why, and every parameter stays within 4 SE of the truth
    (the analysis `imurig calibrate` runs, without its figures)."""
    rec = small_recording
    s = rec.segments
    th, ph = np.round(np.degrees(s["theta"])), np.round(np.degrees(s["phi"]))
    idx = [i for i in range(rec.n_segments) if (th[i] == 0 and ph[i] == 0) or (th[i] == 90 and ph[i] in (0, 120, 240))]
    seg = {k: v[idx[:6]] for k, v in s.items()}
    keep = np.zeros(rec.n, bool)
    for a, b in zip(seg["start_s"], seg["stop_s"]):
        keep |= (rec.time_s >= a - 0.5) & (rec.time_s < b + 0.5)   # the six windows only (a short record)
    six = rec.replace(segments=seg, time_s=rec.time_s[keep], channels={k: v[keep] for k, v in rec.channels.items()},
                      truth_signals={k: v[keep] for k, v in rec.truth_signals.items()})
    res = analyse(six, "linear")
    assert res["main"].results_["x"].n == 6
    for p in res["parameters"]:
        assert abs(p["z"]) < 4, p
    for key in ("stepwise", "backward"):
        assert all(res[key].results_[a].names == ["1", "ax", "ay", "az"] for a in "xyz")
    assert "fewer than 2 residual degrees of freedom" in _report_md(None, six, res, {}, {})


@pytest.mark.slow
def test_cli_calibrates_thermal_and_magnetometer_recordings(tmp_path):
    """The thermal chamber's and the magnetometer rig's recordings (rig from their metadata) calibrate
    from the command line; every parameter within 4 SE of the simulation's truth."""
    from imurig.campaigns.magnetometer import MagnetometerCampaign
    from imurig.campaigns.thermal import ThermalCampaign
    from imurig.rigs.thermal_chamber import ThermalProfile

    short = ThermalProfile(low_C=-40, high_C=40, step_C=20, soak_s=2400, attitude_dwell_s=40)
    for name, rec in (("thermal", ThermalCampaign(profile=short, seed=1).simulate()),
                      ("mag", MagnetometerCampaign(seed=1).simulate())):
        save_h5(rec, tmp_path / f"{name}.h5")
        assert main(["calibrate", str(tmp_path / f"{name}.h5"), "--out", str(tmp_path / name)]) == 0
        s = json.loads((tmp_path / name / "summary.json").read_text())
        assert s["parameters"] and all(abs(p["z"]) < 4 for p in s["parameters"] if p["z"] is not None)


def test_minimal_lab_csvs_through_calibrate(tmp_path, capsys):
    """The other lab's minimal CSVs (time, set-points, volts, `# rig:` and `# site:` only) calibrate to
    that lab's truth: the tilt table's triad, and the one gyro a table turned about one axis only."""
    import independent_lab as lab

    tilt = lab.write_recording(tmp_path / "tilt.csv", "tilt_table", None, 3)
    assert main(["calibrate", str(tilt), "--out", str(tmp_path / "cal_tilt")]) == 0
    summary = json.loads((tmp_path / "cal_tilt" / "summary.json").read_text())
    est = {q["name"]: q for q in summary["parameters"]}
    tri = json.loads(tilt.with_suffix(".json").read_text())["triad"]
    for j, a in enumerate("xyz"):      # against the other lab's truth, within 4 standard errors
        K, b = tri["K_V_per_m_s2"][j], tri["bias_V"][j] / tri["K_V_per_m_s2"][j]
        for name, truth in ((f"sensitivity_{a}", K), (f"bias_{a}", b)):
            assert abs(est[name]["estimate"] - truth) < 4 * est[name]["std_error"], (name, est[name], truth)
    # a table that turned about r only: the r gyro calibrated against the other lab's truth; the p and q
    # gyros' cross-axis sensitivity (the lab has none) within 4 SE of 0
    turn = lab.write_recording(tmp_path / "turn.csv", "turn_table", None, 4)
    assert main(["calibrate", str(turn), "--out", str(tmp_path / "cal_turn")]) == 0
    est = {q["name"]: q for q in json.loads((tmp_path / "cal_turn" / "summary.json").read_text())["parameters"]}
    gy = json.loads(turn.with_suffix(".json").read_text())["gyros"]
    S_r = gy["S_V_per_dps"][2] * 180 / math.pi
    for name, truth in (("sensitivity_r", S_r), ("bias_r", gy["bias_V"][2] / S_r), ("misalignment_pr", 0.0),
                        ("misalignment_qr", 0.0)):
        assert abs(est[name]["estimate"] - truth) < 4 * est[name]["std_error"], (name, est[name], truth)
    assert "sensitivity_p" not in est
    # a triad model asked of it is refused with what is missing, naming the file, writing nothing
    capsys.readouterr()
    assert main(["calibrate", str(turn), "--model", "seed_final", "--out", str(tmp_path / "cal_turn2")]) == 2
    err = capsys.readouterr().err
    assert str(turn) in err and "only about the r gyro's axis" in err and "p_up and q_up" in err
    assert "Traceback" not in err and not (tmp_path / "cal_turn2").exists()
