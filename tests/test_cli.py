"""The console command, as a user runs it."""
from __future__ import annotations

import json

import numpy as np
import pytest

from imurig.cli.main import main

ARGS = ["campaign", "tilt-table", "--theta", "0,45,90", "--phi", "0,90,180,270", "--dwell", "2", "--seed", "3"]


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    out = tmp_path_factory.mktemp("cli") / "tt"
    assert main(ARGS + ["--out", str(out)]) == 0
    return out


def test_campaign_writes_complete_report(report):
    names = {p.name for p in report.iterdir()}
    assert {"report.md", "summary.json", "recording.h5", "campaign.rrd", "fig_4_14_residuals.png",
            "fig_4_10_raw_theta40.png"} <= names
    assert not [n for n in names if n.startswith(".")]  # no temp leftovers
    s = json.loads((report / "summary.json").read_text())
    assert len(s["parameters"]) == 15
    for p in s["parameters"]:
        assert {"name", "unit", "injected", "estimate", "std_error"} <= set(p)
        assert abs(p["estimate"] - p["injected"]) <= 4 * p["std_error"], p
    assert len(s["coefficients"]) == 15  # 3 axes x (1, ax, ay, az, own square)
    for c in s["coefficients"]:
        assert c["injected"] is not None and abs(c["z"]) <= 4, c
    md = (report / "report.md").read_text()
    assert "Table 4.6" in md and "σ_res" in md


def test_rrd_opens_and_holds_rig_and_signals(report):
    import rerun as rr

    paths = set()
    for chunk in rr.chunk.RrdReader(str(report / "campaign.rrd")).stream():
        paths.add(str(chunk.entity_path))
    assert any(p.startswith("/world/pedestal/base/cradle/platform") for p in paths), sorted(paths)[:20]
    assert any("signals/raw/acc_x" in p for p in paths)
    assert any("signals/calibrated/f_z" in p for p in paths)
    # every logged entity in a view of the stored blueprint; residuals logged and shown
    from imurig.reports.rrd_layout import entities_in_rrd, uncovered, views_in_rrd

    ents = entities_in_rrd(report / "campaign.rrd")
    assert uncovered(ents, views_in_rrd(report / "campaign.rrd")) == []
    assert {"/signals/residuals/f_x", "/signals/truth/f_x", "/summary"} <= set(ents)


def test_second_run_refuses_to_overwrite(report, capsys):
    before = (report / "summary.json").read_bytes()
    assert main(ARGS + ["--out", str(report)]) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert (report / "summary.json").read_bytes() == before


def test_calibrate_own_csv_recording(report, tmp_path):
    """A lab CSV exported from a recording calibrates through the CLI like the original."""
    assert main(["convert", str(report / "recording.h5"), str(tmp_path / "lab.csv")]) == 0
    assert main(["calibrate", str(tmp_path / "lab.csv"), "--out", str(tmp_path / "cal")]) == 0
    s_csv = json.loads((tmp_path / "cal" / "summary.json").read_text())
    s_sim = json.loads((report / "summary.json").read_text())
    est_csv = np.array([p["estimate"] for p in s_csv["parameters"]])
    est_sim = np.array([p["estimate"] for p in s_sim["parameters"]])
    se = np.array([p["std_error"] for p in s_sim["parameters"]])
    assert np.all(np.abs(est_csv - est_sim) < 0.01 * se)
    assert all(p["injected"] is None for p in s_csv["parameters"])  # no truth in the lab CSV


def test_help_is_there(capsys):
    with pytest.raises(SystemExit):
        main(["campaign", "tilt-table", "--help"])
    assert "--theta" in capsys.readouterr().out


def test_simulate_gives_the_campaigns_recording(report):
    """One seed, one data set: TiltTableCampaign.simulate() with the command's settings holds the streamed
    recording.h5 of ``imurig campaign tilt-table``, bit for bit (time, volts, set-points, truth signals)."""
    from imurig.campaigns.tilt_table import TiltTableCampaign
    from imurig.kernel.recording import load_h5
    from imurig.rigs.tilt_table import TiltTableProtocol

    saved = load_h5(report / "recording.h5")
    camp = TiltTableCampaign(protocol=TiltTableProtocol(theta_deg=(0, 45, 90), phi_deg=(0, 90, 180, 270),
                                                        dwell_s=2), seed=3)
    rec = camp.simulate()
    assert json.loads(json.dumps(rec.meta["campaign"])) == saved.meta["campaign"]
    assert np.array_equal(rec.time_s, saved.time_s)
    assert sorted(rec.channels) == sorted(saved.channels) and sorted(rec.truth_signals) == sorted(saved.truth_signals)
    for k, v in rec.channels.items():
        assert v.dtype == saved.channels[k].dtype and np.array_equal(v, saved.channels[k]), k
    for k, v in rec.truth_signals.items():
        assert np.array_equal(v, saved.truth_signals[k]), k
    assert rec.units == saved.units and rec.truth_units == saved.truth_units


def test_apply_calibration_to_a_new_recording(report, tmp_path):
    """calibration.json from one campaign, applied to a new recording of the same IMU (same
    sensor errors, new noise and table settings): its per-position medians match the new
    reference to within the residual sigma of the original fit."""
    from imurig.calibration.preprocess import lowpass_downsample, segment_statistic
    from imurig.campaigns.tilt_table import TiltTableCampaign, tilt_table_reference
    from imurig.kernel.labcsv import write_csv
    from imurig.kernel.recording import load_h5
    from imurig.rigs.tilt_table import TiltTableProtocol

    old = load_h5(report / "recording.h5")
    camp = TiltTableCampaign(protocol=TiltTableProtocol(theta_deg=(20, 70), phi_deg=(45, 135, 225, 315), dwell_s=2),
                             seed=3)
    new = camp.simulate()
    for k in ("bias_m_s2", "k1_A_per_m_s2", "misalignment_rad", "k2_per_m_s2"):
        assert new.truth["sensors"]["accelerometers"][k] == old.truth["sensors"]["accelerometers"][k]
    write_csv(new, tmp_path / "new.csv")
    assert main(["apply", str(report / "calibration.json"), str(tmp_path / "new.csv"),
                 "--out", str(tmp_path / "new_cal.h5")]) == 0
    cal = load_h5(tmp_path / "new_cal.h5")
    rec100 = lowpass_downsample(cal)
    med = segment_statistic(rec100, ["acc_cal_x", "acc_cal_y", "acc_cal_z"])
    ref, _, _ = tilt_table_reference(lowpass_downsample(new))
    s = json.loads((report / "summary.json").read_text())
    sig = max(s["models"]["main"]["axes"][a]["sigma_res"] for a in "xyz")
    assert np.sqrt(np.mean((med - ref) ** 2)) < 2 * sig


def test_turn_table_campaign_cli(tmp_path):
    out = tmp_path / "tt"
    assert main(["campaign", "turn-table", "--rates", "20,40,80", "--min-window", "5", "--no-studies",
                 "--seed", "4", "--out", str(out)]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert len(s["parameters"]) == 15
    for p in s["parameters"]:
        assert {"name", "unit", "injected", "estimate", "std_error"} <= set(p)
        assert abs(p["estimate"] - p["injected"]) <= 4 * p["std_error"], p
    import rerun as rr

    paths = {str(c.entity_path) for c in rr.chunk.RrdReader(str(out / "campaign.rrd")).stream()}
    assert any("spindle" in p for p in paths) and any("signals/raw/gyro_p" in p for p in paths)
    from imurig.reports.rrd_layout import entities_in_rrd, uncovered, views_in_rrd

    ents = entities_in_rrd(out / "campaign.rrd")
    assert uncovered(ents, views_in_rrd(out / "campaign.rrd")) == []
    assert {"/signals/residuals/w_p", "/signals/reference/w_p", "/signals/pulses/pulse_true"} <= set(ents)
    assert (out / "fig_4_21_gyro_residuals.png").stat().st_size > 0


def test_simona_cli(tmp_path, capsys):
    assert main(["simona", "--out", str(tmp_path / "s")]) == 0
    assert (tmp_path / "s" / "fig_4_19_simona.png").stat().st_size > 0
    assert "virtual" in capsys.readouterr().out.lower()
