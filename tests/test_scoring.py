"""Bring your own algorithm: the bench scores a user's estimator, in process and through files."""
from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from imurig.scoring.baselines import (
    MagnetometerCalibrator,
    ThermalCalibrator,
    TiltTableCalibrator,
    TurnTableCalibrator,
)
from imurig.scoring.bench import score_calibrator
from imurig.scoring.campaigns import campaign
from imurig.scoring.files import (
    read_estimates,
    write_estimates_csv,
    write_estimates_json,
)
from imurig.scoring.interface import EstimatesError, NavSolution
from imurig.scoring.nav import nees_interval, quat_mul, rotvec_to_quat, score_navigation
from imurig.scoring.pytest_plugin import CalibratorBoundError, assert_calibrator_meets
from imurig.scoring.score import TruthSet, score_estimates
from imurig.scoring.units import UnitError, conversion_factor

pytest_plugins = ["pytester"]

ROOT = Path(__file__).resolve().parents[1]
TILT = "tilt-table-quick"
TURN = "turn-table-quick"


@pytest.fixture(scope="module")
def tilt():
    return campaign(TILT)


@pytest.fixture(scope="module")
def turn():
    return campaign(TURN)


@pytest.fixture(scope="module")
def tilt_score(tilt):
    return score_calibrator(TiltTableCalibrator(), tilt)


@pytest.fixture(scope="module")
def tilt_export(tilt, tmp_path_factory):
    from imurig.scoring.export import export_campaign

    d = tmp_path_factory.mktemp("export")
    export_campaign(TILT, d / "tilt", truth_out=d / "secret" / "tilt.truth.json")
    return d / "tilt", d / "secret" / "tilt.truth.json"


# ------------------------------------------------------------ in process == internal
def test_tilt_bench_through_interface_scores_as_internally(tilt, tilt_score):
    """The bench's calibrator, run through the public interface on the recording without
    truth, gives exactly the campaign's own compare_with_truth rows."""
    from imurig.campaigns.tilt_table import calibrate, compare_with_truth

    rec = tilt.simulate()
    internal = {p["name"]: p for p in compare_with_truth(calibrate(rec), rec.truth)}
    assert [r["name"] for r in tilt_score.rows] == list(internal)
    for r in tilt_score.rows:
        p = internal[r["name"]]
        assert r["injected"] == p["injected"] and r["estimate"] == p["estimate"]
        assert r["std_error"] == p["std_error"] and r["z"] == p["z"] and r["within_bound"] == p["within_bound"]
    assert tilt_score.passed and tilt_score.rms_z < 2
    # the recording given to the estimator holds no truth and no seed
    seen = tilt.recording()
    assert seen.truth is None and not seen.truth_signals and "seed" not in seen.meta["campaign"]


def test_tilt_residuals_reach_the_noise_floor(tilt_score):
    """With the injected parameters the forward-model residual is the noise floor; the bench's
    estimates (fitted to the same windows) sit at or just below it, and its calibrated
    output (apply) matches the true specific force to the same level."""
    fm = tilt_score.residuals["forward_model"]
    out = tilt_score.extra["output_residuals"]["rms"]
    for a in "xyz":
        assert 0.8 * fm["floor_rms"][a] <= fm["rms"][a] <= 1.05 * fm["floor_rms"][a]
        assert out[a] < 1.1 * fm["floor_rms"][a]


def test_turn_bench_through_interface_scores_as_internally(turn):
    from imurig.calibration.gyro import GyroCalibration
    from imurig.campaigns.turn_table import gyro_parameters

    rec = turn.simulate()
    cal = GyroCalibration().fit(rec)
    internal = {p["name"]: p for p in gyro_parameters(cal, rec)}
    s = score_calibrator(TurnTableCalibrator(), turn)
    for r in s.rows:
        p = internal[r["name"]]
        assert (r["injected"], r["estimate"], r["std_error"], r["z"]) == (p["injected"], p["estimate"],
                                                                            p["std_error"], p["z"])
    assert s.passed
    fm = s.residuals["forward_model"]
    assert all(fm["rms"][a] <= 1.05 * fm["floor_rms"][a] for a in "pqr")


def test_thermal_and_magnetometer_bench_scores_as_internally(default_magnetometer):
    from imurig.campaigns.magnetometer import analyse as mag_analyse
    from imurig.campaigns.thermal import analyse as th_analyse

    th = campaign("thermal-quick")
    s = score_calibrator(ThermalCalibrator(), th)
    internal = {p["name"]: p for p in th_analyse(th.simulate())["coefficients"]}
    assert len(s.rows) == len(internal) == 33
    for r in s.rows:
        assert (r["injected"], r["estimate"], r["z"]) == pytest.approx(
            (internal[r["name"]]["injected"], internal[r["name"]]["estimate"], internal[r["name"]]["z"]), rel=1e-12)
    mg = default_magnetometer
    s = score_calibrator(MagnetometerCalibrator(), mg)
    internal = {p["name"]: p for p in mag_analyse(mg.simulate())["parameters"]}
    for r in s.rows:
        assert (r["injected"], r["estimate"], r["z"]) == pytest.approx(
            (internal[r["name"]]["injected"], internal[r["name"]]["estimate"], internal[r["name"]]["z"]), rel=1e-9)
    assert s.passed
    # the calibrated field norm from b and A A' alone reaches the 5 nT sensor noise
    assert s.residuals["forward_model"]["rms"]["norm"] < 1.1 * s.residuals["forward_model"]["floor_rms"]["norm"]


# ---------------------------------------------------------------- failing estimators
class BiasedTilt(TiltTableCalibrator):
    """The bench's calibrator with bias_y shifted by 8 of its standard errors."""

    name = "biased"

    def fit(self, recording):
        super().fit(recording)
        for r in self.estimates_:
            if r["name"] == "bias_y":
                r["estimate"] += 8 * r["std_error"]
        return self


def test_biased_estimator_fails_naming_the_parameter(tilt, tilt_score):
    with pytest.raises(CalibratorBoundError) as e:
        assert_calibrator_meets(BiasedTilt(), tilt)
    msg = str(e.value)
    assert "bias_y" in msg and "1 of 15" in msg
    z0 = next(r["z"] for r in tilt_score.rows if r["name"] == "bias_y")
    assert f"{z0 + 8:+.2f} SE" in msg           # by how much, in units of its standard error
    assert "m/s^2" in msg
    assert e.value.score.failures[0]["name"] == "bias_y"
    # the honest one passes, and the optional bounds bite
    assert assert_calibrator_meets(TiltTableCalibrator(), tilt, max_se_ratio=1.0 + 1e-12).passed


class Overcautious(TiltTableCalibrator):
    """Huge standard errors pass any z bound; the SE-ratio and RMS-z bounds catch it."""

    def fit(self, recording):
        self.estimates_ = [{**r, "std_error": 100 * r["std_error"]} for r in super().fit(recording).estimates_]
        return self


class Overconfident(TiltTableCalibrator):
    def fit(self, recording):
        self.estimates_ = [{**r, "std_error": r["std_error"] / 20} for r in super().fit(recording).estimates_]
        return self


def test_standard_error_bounds_catch_inflated_and_shrunk_errors(tilt):
    s = assert_calibrator_meets(Overcautious(), tilt)          # passes the z bound ...
    assert s.rms_z < 0.05
    with pytest.raises(CalibratorBoundError, match="100.00 x"):
        assert_calibrator_meets(Overcautious(), tilt, max_se_ratio=2)
    with pytest.raises(CalibratorBoundError, match="RMS of the z-scores"):
        assert_calibrator_meets(Overconfident(), tilt, z_bound=1e9, max_rms_z=2)


# --------------------------------------------------------------------- export, no truth
#: lab settings and datasheet figures that the truth repeats and the metadata rightly publishes
# datasheet figures the lab knows and the recording's metadata carries on purpose
PUBLIC = {"nominal_scale_V_per_rad_s", "arw_rad_s_per_sqrt_hz", "bias_instability_rad_s", "bias_instability_tau_s",
          "setting_resolution_rad"}


def _truth_numbers(bench_campaign) -> list[float]:
    """Every drawn error of the simulation (sensors and rig, flattened) and every scored
    injected parameter; the acquisition chain's settings (truth['chain']) are lab settings."""
    rec = bench_campaign.simulate()
    out = [p["injected"] for p in bench_campaign.truth(with_bench=False).parameters]

    def walk(v, key=""):
        if key in PUBLIC:
            return
        if isinstance(v, dict):
            for k, x in v.items():
                walk(x, k)
        elif isinstance(v, (list, tuple)):
            for x in v:
                walk(x, key)
        elif isinstance(v, float) and v not in (0.0, 1.0) and math.isfinite(v):
            out.append(v)

    walk(rec.truth["sensors"])
    walk(rec.truth["rig"])
    return out


def _assert_no_truth_in_text(text: str, truth_vals, where: str, keys=True):
    low = text.lower()
    for key in ("truth", "injected", "true_", "_true", "seed") if keys else ():
        assert key not in low, (where, key)
    for v in truth_vals:
        for s in {repr(v), f"{v:.10g}", f"{v:.12g}"}:
            if len(s.strip("-0.")) >= 6:        # skip short, generic numbers such as 0.5
                assert s not in text, (where, s)


def _csv_head(path: Path) -> tuple[str, str]:
    """(metadata lines, header row) of a lab CSV."""
    meta = []
    with open(path, encoding="utf-8") as fh:
        for line in fh:
            if not line.startswith("#"):
                return "".join(meta), line
            meta.append(line)
    return "".join(meta), ""


def _check_export(folder: Path, bench_campaign):
    from scipy.io import loadmat

    rec = bench_campaign.simulate()
    vals = _truth_numbers(bench_campaign)
    files = sorted(p.name for p in folder.iterdir())
    assert not any("truth" in f for f in files), files
    head, header = _csv_head(folder / "recording.csv")
    _assert_no_truth_in_text(head + header, vals, "recording.csv metadata/header")
    for f in ("manifest.json", "parameters.csv", "parameters.json", "segments.csv"):
        _assert_no_truth_in_text((folder / f).read_text(), vals, f)
    _assert_no_truth_in_text((folder / "README.txt").read_text(), vals, "README.txt", keys=False)  # says where
    m = loadmat(folder / "recording.mat", simplify_cells=True)
    _assert_no_truth_in_text(m["meta_json"], vals, "recording.mat meta_json")
    names = set(m) | set(m["channels"]) | set(m["events"]) | set(m["segments"])
    assert not any("true" in n or "truth" in n for n in names), names
    # no truth signal hides under another name, and the channels are the recording's
    for k, x in m["channels"].items():
        np.testing.assert_array_equal(np.ravel(x), rec.channels[k])
        for ts in rec.truth_signals.values():
            assert not np.array_equal(np.ravel(x), ts)
    for k, ev in m["events"].items():
        assert not np.array_equal(np.ravel(ev), rec.events.get("pulse_true", np.array([])))
    return m


def test_tilt_export_holds_no_truth(tilt_export, tilt):
    folder, truth_file = tilt_export
    assert not truth_file.is_relative_to(folder)
    m = _check_export(folder, tilt)
    assert set(m["channels"]) == set(tilt.recording().channels)
    # the truth file holds the 15 injected parameters
    t = TruthSet.load(truth_file)
    assert len(t.parameters) == 15 and t.seed == tilt.seed


def test_turn_export_holds_no_truth(turn, tmp_path):
    from imurig.scoring.export import export_campaign

    export_campaign(TURN, tmp_path / "turn")
    m = _check_export(tmp_path / "turn", turn)
    assert set(m["events"]) == {"pulse_hp6700", "pulse_gps_mark"}         # pulse_true withheld
    assert (tmp_path / "turn.truth.json").exists()
    _, hdr = _csv_head(tmp_path / "turn" / "recording.csv")
    assert "event_pulse_true" not in hdr and "event_pulse_hp6700_s" in hdr


def test_truth_file_inside_export_refused(tmp_path):
    from imurig.kernel.errors import ImurigError
    from imurig.scoring.export import export_campaign

    with pytest.raises(ImurigError, match="inside the export folder"):
        export_campaign(TILT, tmp_path / "e", truth_out=tmp_path / "e" / "truth.json")
    assert not (tmp_path / "e").exists()


# ------------------------------------------------------------- files == in process
def test_scores_from_csv_and_json_equal_in_process(tilt, tilt_score, tilt_export, tmp_path):
    _, truth_file = tilt_export
    truth = TruthSet.load(truth_file)
    est = TiltTableCalibrator().fit(tilt.recording()).estimates_
    write_estimates_csv(tmp_path / "est.csv", est)
    write_estimates_json(tmp_path / "est.json", est)
    for f in ("est.csv", "est.json"):
        s = score_estimates(truth, read_estimates(tmp_path / f), estimator="bench")
        assert s.rows == tilt_score.rows
        assert s.residuals == tilt_score.residuals
    # through the command line: summary.json holds the same numbers
    from imurig.cli.main import main

    assert main(["score", "--truth", str(truth_file), "--estimates", str(tmp_path / "est.csv"),
                 "--out", str(tmp_path / "score")]) == 0
    summary = json.loads((tmp_path / "score" / "summary.json").read_text())
    assert summary["passed"] and summary["parameters"] == tilt_score.rows
    assert (tmp_path / "score" / "report.md").exists() and (tmp_path / "score" / "fig_z.png").exists()


def test_convertible_units_accepted(tilt_score, tilt, tmp_path):
    """bias in mg, misalignment in mrad, sensitivity in mV/g score like SI."""
    f = {"m/s^2": ("mg", 1 / (9.80665e-3)), "rad": ("mrad", 1e3), "V/(m/s^2)": ("mV/g", 1e3 * 9.80665),
         "1/(m/s^2)": ("1/g", 9.80665)}
    lines = ["# my calibrator, written by hand", "unit,name,std_error,value"]
    for r in tilt_score.rows:
        u, k = f[r["unit"]]
        lines.append(f"{u},{r['name']},{r['std_error'] * k!r},{r['estimate'] * k!r}")
    (tmp_path / "e.csv").write_text("\n".join(lines) + "\n")
    s = score_estimates(tilt.truth(), read_estimates(tmp_path / "e.csv"))
    for a, b in zip(s.rows, tilt_score.rows):
        assert a["z"] == pytest.approx(b["z"], rel=1e-9, abs=1e-9)


def _write(tmp_path, rows, name="bad.csv"):
    p = tmp_path / name
    p.write_text("name,value,std_error,unit\n" + "".join(",".join(map(str, r)) + "\n" for r in rows))
    return p


@pytest.mark.parametrize("edit, message", [
    (lambda rows: rows[1:], "missing parameters ['sensitivity_x']"),
    (lambda rows: rows + [("scale_w", 1.0, 0.1, "1")], "unknown parameters ['scale_w']"),
    (lambda rows: rows + [rows[3]], "duplicate rows for ['misalignment_xy']"),
    (lambda rows: [(n, "nan" if n == "bias_z" else v, s, u) for n, v, s, u in rows], "bias_z: value nan"),
    (lambda rows: [(n, v, "" if n == "bias_x" else s, u) for n, v, s, u in rows], "bias_x: value"),
    (lambda rows: [(n, v, s, "deg" if n == "bias_x" else u) for n, v, s, u in rows],
     "bias_x: unit 'deg' has dimension rad but 'm/s^2'"),
    (lambda rows: [(n, v, s, "furlong" if n == "bias_y" else u) for n, v, s, u in rows], "unknown unit 'furlong'"),
    (lambda rows: [(n, v, -1.0 if n == "bias_y" else s, u) for n, v, s, u in rows], "std_error -1.0 must be > 0"),
])
def test_malformed_estimate_files_refused(tilt_score, tilt, tmp_path, edit, message):
    rows = [(r["name"], repr(r["estimate"]), repr(r["std_error"]), r["unit"]) for r in tilt_score.rows]
    p = _write(tmp_path, edit(rows))
    with pytest.raises(EstimatesError) as e:
        score_estimates(tilt.truth(), read_estimates(p), source=str(p))
    assert message in str(e.value), str(e.value)


def test_malformed_file_structure_refused(tmp_path, tilt):
    p = tmp_path / "h.csv"
    p.write_text("name,value,unit\nbias_x,1,m/s^2\n")
    with pytest.raises(EstimatesError, match="header must be the four columns"):
        read_estimates(p)
    p.write_text("name,value,std_error,unit\nbias_x,1e-3,1e-4\n")
    with pytest.raises(EstimatesError, match="line 2: 3 fields"):
        read_estimates(p)
    p.write_text("name,value,std_error,unit\nbias_x,0,01,1e-4,m/s^2\n")
    with pytest.raises(EstimatesError, match="line 2: 5 fields"):
        read_estimates(p)
    j = tmp_path / "e.json"
    j.write_text(json.dumps({"parameters": [{"name": "bias_x", "value": None, "std_error": 1e-4, "unit": "m/s^2"}]}))
    with pytest.raises(EstimatesError, match="bias_x: value nan"):
        score_estimates(tilt.truth(), read_estimates(j), source="e.json")
    j.write_text("{not json")
    with pytest.raises(EstimatesError, match="not valid JSON"):
        read_estimates(j)


def test_score_cli_fails_with_exit_status_and_names_parameter(tilt_score, tilt_export, tmp_path, capsys):
    from imurig.cli.main import main

    _, truth_file = tilt_export
    rows = [(r["name"], repr(r["estimate"] + (6 * r["std_error"] if r["name"] == "sensitivity_z" else 0)),
             repr(r["std_error"]), r["unit"]) for r in tilt_score.rows]
    p = _write(tmp_path, rows, "est.csv")
    with pytest.raises(SystemExit) as e:
        main(["score", "--truth", str(truth_file), "--estimates", str(p)])
    assert e.value.code == 1
    out = capsys.readouterr().out
    assert "sensitivity_z: estimate" in out and "SE" in out and "FAIL" in out
    # malformed: the CLI's error names the problem (exit 2)
    assert main(["score", "--truth", str(truth_file), "--estimates", str(_write(tmp_path, rows[:-1], "m.csv"))]) == 2
    assert "missing parameters ['nonlinearity_z']" in capsys.readouterr().err


# -------------------------------------------------------------- out-of-process round trip
BLOCK_IMURIG = ("import sys, runpy\n"
                "class Block:\n"
                "    def find_spec(self, name, path=None, target=None):\n"
                "        if name == 'imurig' or name.startswith('imurig.'):\n"
                "            raise ImportError('the out-of-process example must not import imurig')\n"
                "sys.meta_path.insert(0, Block())\n"
                "sys.argv = sys.argv[1:]\n"
                "runpy.run_path(sys.argv[0], run_name='__main__')\n")


def test_out_of_process_round_trip(tilt_export, tilt_score, tmp_path):
    """Export -> a standalone numpy script in a subprocess (imurig imports blocked) fits the
    forward model -> estimates.csv -> imurig score. The script's own estimator passes the
    bound with honest standard errors and reaches the residual floor."""
    folder, truth_file = tilt_export
    script = ROOT / "examples" / "python" / "calibrate_triad.py"
    assert "import imurig" not in script.read_text() and "from imurig" not in script.read_text()
    est = tmp_path / "estimates.csv"
    r = subprocess.run([sys.executable, "-c", BLOCK_IMURIG, str(script), str(folder), "--out", str(est)],
                       check=False, capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert r.returncode == 0, r.stderr
    s = score_estimates(TruthSet.load(truth_file), read_estimates(est), estimator="example")
    assert s.passed, s.failure_message()
    assert 0.5 < s.rms_z < 2
    fm = s.residuals["forward_model"]
    assert all(fm["rms"][a] <= 1.05 * fm["floor_rms"][a] for a in "xyz")
    # a different estimator from the bench's (raw 1 kHz medians, forward model): not the same numbers
    assert max(abs(a["estimate"] - b["estimate"]) for a, b in zip(s.rows, tilt_score.rows)) > 0


@pytest.mark.skipif(shutil.which("octave-cli") is None and shutil.which("octave") is None,
                    reason="Octave is not installed (optional; the example is checked where it is)")
def test_octave_example_round_trip(tilt_export, tmp_path):
    folder, truth_file = tilt_export
    exe = shutil.which("octave-cli") or shutil.which("octave")
    est = tmp_path / "octave_estimates.csv"
    r = subprocess.run([exe, "--no-gui", "--quiet", str(ROOT / "examples" / "octave" / "calibrate_tilt_table.m"),
                        str(folder), str(est)], check=False, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    s = score_estimates(TruthSet.load(truth_file), read_estimates(est), estimator="octave")
    assert s.passed, s.failure_message()
    # the same least squares as the Python example: the same numbers to rounding
    py = tmp_path / "py.csv"
    subprocess.run([sys.executable, str(ROOT / "examples" / "python" / "calibrate_triad.py"), str(folder), "--out",
                    str(py)], check=True, capture_output=True, timeout=120)
    p = {e.name: e.value for e in read_estimates(py)}
    for e in read_estimates(est):
        assert e.value == pytest.approx(p[e.name], rel=1e-7, abs=1e-12)


# ------------------------------------------------------------------- pytest plugin
def test_pytest_plugin_in_a_user_suite(pytester):
    """The installed plugin (pytest11 entry point) gives a user's suite its fixtures with no
    conftest line; a biased calibrator's failure names the parameter and its miss in SE."""
    pytester.makepyfile(test_user=(
        "from imurig.scoring.baselines import TiltTableCalibrator\n\n"
        "class Mine(TiltTableCalibrator):\n"
        "    def fit(self, rec):\n"
        "        super().fit(rec)\n"
        "        self.estimates_[9]['estimate'] += 1e-3   # bias_x off by 1 mm/s^2\n"
        "        return self\n\n"
        "def test_bench(imurig_campaign, assert_calibrator_meets):\n"
        "    assert_calibrator_meets(TiltTableCalibrator(), imurig_campaign('tilt-table-quick', seed=1))\n\n"
        "def test_mine(imurig_campaign, assert_calibrator_meets):\n"
        "    assert_calibrator_meets(Mine(), imurig_campaign('tilt-table-quick', seed=1))\n"))
    r = pytester.runpytest_inprocess("-q", "-p", "no:cacheprovider")
    r.assert_outcomes(passed=1, failed=1)
    out = r.stdout.str()
    assert "bias_x: estimate" in out and "m/s^2" in out and "SE (SE" in out


# ------------------------------------------------------------------- navigation
def _trajectory(n=400):
    t = np.linspace(0, 40, n)
    r = np.column_stack([50 * np.sin(0.1 * t), 30 * t, -100 - 0.5 * t])
    v = np.column_stack([5 * np.cos(0.1 * t), np.full(n, 30.0), np.full(n, -0.5)])
    q = rotvec_to_quat(np.column_stack([0.05 * np.sin(0.2 * t), 0.02 * np.ones(n), 0.1 * t]))
    return NavSolution(time_s=t, r_N=r, v_N=v, q_NB=q)


def test_navigation_errors_closed_form():
    truth = _trajectory()
    k = truth.time_s.size
    dq = rotvec_to_quat(np.tile([0.0, 0.0, 1e-3], (k, 1)))
    sol = NavSolution(time_s=truth.time_s, r_N=truth.r_N + [1.0, -2.0, 0.5], v_N=truth.v_N + [0.0, 0.1, 0.0],
                      q_NB=quat_mul(dq, truth.q_NB))
    s = score_navigation(sol, truth)
    np.testing.assert_allclose(s["position"]["rms"], [1.0, 2.0, 0.5], rtol=1e-12)
    np.testing.assert_allclose(s["velocity"]["max_abs"], [0.0, 0.1, 0.0], atol=1e-12)
    np.testing.assert_allclose(s["attitude"]["rms"], [0.0, 0.0, 1e-3], atol=1e-12)


class GpsOnlyFilter:
    """A NavFilter that reports the GPS fixes as its position, with the GPS covariance scaled
    by ``claim`` (1: honest)."""

    def __init__(self, claim=1.0):
        self.claim = claim

    def fit(self, streams):
        g = streams.gps
        P = np.stack([np.diag(s) for s in np.square(g.sigma_pos_N)]) * self.claim
        self.solution_ = NavSolution(time_s=g.time_s, r_N=g.r_N, P_r=P)
        return self


def test_filter_consistency_nees():
    """An honest filter's average NEES lies in the chi-square interval; one claiming a 10x
    smaller covariance is flagged inconsistent."""
    from imurig.kernel.navdata import GpsFixes, ImuStream
    from imurig.scoring.interface import NavFilter, NavStreams
    from imurig.scoring.nav import score_filter

    truth = _trajectory()
    rng = np.random.default_rng(np.random.SeedSequence(8))
    sig = np.array([2.0, 2.0, 4.0])
    idx = np.arange(0, truth.time_s.size, 4)
    gps = GpsFixes(time_s=truth.time_s[idx], r_N=truth.r_N[idx] + rng.standard_normal((idx.size, 3)) * sig,
                   sigma_pos_N=sig)
    imu = ImuStream(time_s=truth.time_s, f_B=np.zeros((truth.time_s.size, 3)), w_IB_B=np.zeros((truth.time_s.size, 3)))
    streams = NavStreams(imu=imu, gps=gps)
    assert isinstance(GpsOnlyFilter(), NavFilter)
    ok = score_filter(GpsOnlyFilter(), streams, truth)["position"]
    lo, hi = nees_interval(idx.size)
    assert lo <= ok["anees"] <= hi and ok["consistent"]
    np.testing.assert_allclose(ok["rms"], sig, rtol=0.25)
    bad = score_filter(GpsOnlyFilter(claim=0.1), streams, truth)["position"]
    assert bad["anees"] == pytest.approx(10 * ok["anees"]) and not bad["consistent"]


# ------------------------------------------------------------------- units
@pytest.mark.parametrize("a, b, f", [("mg", "m/s^2", 9.80665e-3), ("mrad", "rad", 1e-3), ("deg/h", "rad/s", math.pi / 180 / 3600),
                                     ("mV/(deg/s)", "V/(rad/s)", 1e-3 * 180 / math.pi), ("ug/g^2", "1/(m/s^2)", 1e-6 / 9.80665),
                                     ("m_s2", "m/s^2", 1.0), ("nT", "T", 1e-9), ("ppm/degC", "1/K", 1e-6)])
def test_unit_conversion(a, b, f):
    assert conversion_factor(a, b) == pytest.approx(f, rel=1e-14)


def test_wrong_dimension_refused():
    with pytest.raises(UnitError, match="dimension"):
        conversion_factor("V/(rad/s)", "V/(m/s^2)")
    with pytest.raises(UnitError, match="unbalanced"):
        conversion_factor("V/(m/s^2", "V/(m/s^2)")


# ------------------------------------------------------------------- Monte-Carlo
def test_monte_carlo_scoring_on_the_distributed_engine():
    """The bench's calibrator through the Calibrator contract on the Monte-Carlo engine gives
    the engine's own rows run for run; a biased one shows its bias over the runs; the RMS
    never beats the Cramér-Rao bound beyond sampling noise."""
    from distributed import Client, LocalCluster

    from imurig.montecarlo.engine import run_study
    from imurig.scoring.montecarlo import score_monte_carlo

    params = {"theta_deg": [0, 30, 60, 90], "phi_deg": [0, 90, 180, 270], "dwell_s": 5.0}
    cluster = LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=":0")
    client = Client(cluster)
    try:
        n = 16
        mine = score_monte_carlo(TiltTableCalibrator(), n, master_seed=5, params=params, client=client)
        own = run_study("tilt-table", n, master_seed=5, params=params, client=client)
        biased = score_monte_carlo(BiasedTilt(), n, master_seed=5, params=params, client=client)
    finally:
        client.close()
        cluster.close()
    for i, rows in own.rows.items():
        got = {r["name"]: r for r in mine["study"].rows[i]}
        for r in rows:
            assert got[r["name"]]["estimate"] == r["estimate"] and got[r["name"]]["z"] == r["z"]
    st = {s["name"]: s for s in mine["parameters"]}
    for s in st.values():
        # N = 16 runs: the RMS's relative sampling sd is ~1/sqrt(2N) = 0.18
        assert s["rms_over_crlb"] > 1 - 4 * 0.18, s
        assert s["within_bound_fraction"] == 1.0
    b = {s["name"]: s for s in biased["parameters"]}["bias_y"]
    assert b["within_bound_fraction"] == 0.0
    assert b["bias"] == pytest.approx(st["bias_y"]["bias"] + 8 * b["mean_se"], rel=0.05)
