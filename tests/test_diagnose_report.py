"""The diagnosis report (issue 5, part 4): for every accepted effect its parameter with SE and
share of the residual variance, the fit before and after (sigma, R^2adj, BIC, AIC) in report.md
and diagnosis.json, residual plots before/after against the revealing variable, and an .rrd
that overlays recording, twin and corrected twin. The numbers are checked against each other
and against the data: the after-residual in diagnosis.json is the one the corrected twin in the
.rrd gives, the shares add up, the report's refit reproduces the engine's fit."""
from __future__ import annotations

import json

import numpy as np
import pytest
import rerun as rr

from imurig.cli.main import main
from imurig.diagnose.summary import check_schema
from imurig.reports.diagnosis import run
from imurig.concealed.suite import CASES, found_effects


def _case(rig, effect):
    return next(c for c in CASES if c.rig == rig and c.effect == effect)


def _rrd_series(path) -> dict:
    """{entity: (t, values)} of every temporal scalar entity in the .rrd, read back with rerun."""
    out = {}
    for chunk in rr.chunk.RrdReader(path).stream():
        if chunk.is_static:
            continue
        b = chunk.to_record_batch()
        col = next((n for n in b.schema.names if n.endswith("Scalars:scalars")), None)
        if col is None:
            continue
        t = b.column("time").cast("int64").to_numpy() * 1e-9
        v = np.array([x[0] for x in b.column(col).to_pylist()])
        t0, v0 = out.get(chunk.entity_path, (np.empty(0), np.empty(0)))
        out[chunk.entity_path] = (np.concatenate([t0, t]), np.concatenate([v0, v]))
    return {k: (t[np.argsort(t, kind="stable")], v[np.argsort(t, kind="stable")]) for k, (t, v) in out.items()}


def _check_fit_steps(e: dict) -> None:
    """The steps reproduce the engine's fits; shares add up; AIC and BIC are the same likelihood's."""
    st = e["fit_steps"]
    assert st[0]["after_effect"] is None and len(st) == len(e["findings"]) + 1
    for k in ("sigma_res", "r2_adj", "bic"):
        assert st[0][k] == pytest.approx(e["fit_before"][k], rel=1e-9)
        assert st[-1][k] == pytest.approx(e["fit_after"][k], rel=1e-9)
    for s in st:  # aic = bic - p ln n + 2 p (one Gaussian log-likelihood)
        assert s["aic"] == pytest.approx(s["bic"] - s["p"] * np.log(s["n"]) + 2 * s["p"], rel=1e-12)
    assert e["fit_after"]["aic"] == pytest.approx(st[-1]["aic"], rel=1e-9)
    shares = sum(s["variance_share"] for s in st[1:])
    assert shares == pytest.approx(1 - st[-1]["ss_res"] / st[0]["ss_res"], abs=1e-12)
    for s, f in zip(st[1:], e["findings"]):
        assert s["unique_variance_share"] > 0  # every accepted effect still explains something given the others
        if len(st) == 2:  # one effect: the engine's share is the step's share
            assert s["variance_share"] == pytest.approx(f["variance_share"], rel=1e-9)


def _diagnosed(tmp_path_factory, records, rig: str, effect: str):
    """(recording, diagnosis, report folder) of the suite case at its realistic size, seed 1
    (the record shared with the other files that use it)."""
    case = _case(rig, effect)
    rec = records.make(case, 1, case.realistic_size)
    out = tmp_path_factory.mktemp(effect) / "diag"
    return rec, run(rec, out), out


@pytest.fixture(scope="module")
def thermal(tmp_path_factory, concealed_records):
    return _diagnosed(tmp_path_factory, concealed_records, "thermal", "temperature_hysteresis")


def test_thermal_report_fields_and_numbers(thermal):
    _rec, d, out = thermal
    j = json.loads((out / "diagnosis.json").read_text())
    md = (out / "report.md").read_text()
    assert {("acc_x", "temperature_hysteresis")} <= found_effects(d)
    # the rig-free top level (docs/diagnosis-json.md): the same findings, with units and fits
    assert check_schema(j) == []
    assert {(f["channel"], f["effect"]) for f in j["findings"]} == {(c, f["effect"]) for c, e in j["channels"].items()
                                                                    for f in e["findings"]}
    top = next(f for f in j["findings"] if f["effect"] == "temperature_hysteresis")
    assert top["fit"]["after_rms"] < top["fit"]["before_rms"] and top["parameters"][0]["se"] > 0
    assert "temperature_hysteresis on acc_x" in j["verdict"]
    for f in ("fig_diagnosis.png", "fig_residuals.png", "diagnosis.rrd"):
        assert (out / f).stat().st_size > 1000
    for e in j["channels"].values():
        _check_fit_steps(e)
        rs = e["residuals"]
        y, tw, cor = (np.asarray(rs[k]) for k in ("recording", "twin", "corrected_twin"))
        # the residual the report states after the effects is recording - corrected twin
        assert np.sqrt(np.mean((y - cor) ** 2)) == pytest.approx(e["fit_steps"][-1]["residual_rms"], rel=1e-9)
        np.testing.assert_allclose(y - tw, rs["before"], rtol=0, atol=1e-15)
    # every accepted effect: parameter, SE and share in report.md and diagnosis.json
    e = j["channels"]["acc_x"]
    f = e["findings"][0]
    p = f["parameters"][0]
    assert p["std_error"] > 0 and 0 < f["variance_share"] < 1
    assert f"{p['estimate']:.4g} ± {p['std_error']:.2g}" in md
    assert "AIC before" in md and "R²adj before" in md and "share" in md
    # the hysteresis gap shows in the before residuals as a heating/cooling difference the after ones lack
    rs = e["residuals"]
    up = np.asarray(rs["heating"])
    gap = lambda r: np.mean(np.asarray(r)[up]) - np.mean(np.asarray(r)[~up])
    assert abs(gap(rs["after"])) < 0.2 * abs(gap(rs["before"]))
    # the .rrd overlays recording, twin and corrected twin, as in diagnosis.json
    series = _rrd_series(out / "diagnosis.rrd")
    _t, v = series["/signals/acc_x/step_bias/corrected_twin"]
    np.testing.assert_allclose(v, e["residuals"]["corrected_twin"], rtol=1e-12)
    assert {"/signals/acc_x/step_bias/recording", "/signals/acc_x/step_bias/twin"} <= set(series)


@pytest.fixture(scope="module")
def lever(tmp_path_factory, concealed_records):
    """The lever-arm case (dynamic protocol): position means and slews."""
    return _diagnosed(tmp_path_factory, concealed_records, "tilt_table", "lever_arm")


def test_tilt_report_positions_and_slews(lever):
    rec, d, out = lever
    assert found_effects(d) == {("acc", "lever_arm")}
    for f in ("fig_diagnosis.png", "fig_residuals.png", "fig_residuals_slews.png", "diagnosis.rrd"):
        assert (out / f).stat().st_size > 1000
    j = json.loads((out / "diagnosis.json").read_text())
    assert check_schema(j) == [] and [(f["channel"], f["effect"]) for f in j["findings"]] == [("acc", "lever_arm")]
    lv = j["findings"][0]
    assert {p["unit"] for p in lv["parameters"]} == {"m"} and lv["fit"]["after_rms"] < lv["fit"]["before_rms"]
    for a, e in j["axes"].items():  # null channels: before = after, "no effect accepted"
        _check_fit_steps(e)
        assert e["residuals"]["before"] == e["residuals"]["after"] and not e["residuals"]["variables"]
    dyn = j["dynamic"]
    _check_fit_steps(dyn)
    rs = dyn["residuals"]
    F, _tw, cor = (np.asarray(rs[k]) for k in ("recording", "twin", "corrected_twin"))
    np.testing.assert_allclose(F - cor, rs["after"], atol=1e-12)
    # the lever arm's effect term is what the corrected twin adds (up to the refitted nuisance)
    before, after = np.asarray(rs["before"]), np.asarray(rs["after"])
    assert np.sqrt(np.mean(after**2)) < 0.8 * np.sqrt(np.mean(before**2))
    # the report's own GLS refit of the slews gives the engine's lever arm (Frisch-Waugh-Lovell):
    # its contribution / the twin's kinematic columns reproduce dr
    f = dyn["findings"][0]
    dr = np.array([p["estimate"] for p in f["parameters"]])
    truth = np.asarray(rec.truth["sensors"]["accelerometers"]["position_C_m"])
    se = np.array([p["std_error"] for p in f["parameters"]])
    assert np.all(np.abs(dr - truth) < 4 * se)
    md = (out / "report.md").read_text()
    assert "acc slews (x, y, z stacked)" in md and "fig_residuals_slews.png" in md and "unique share" in md
    # the .rrd: positions and slews of every axis, recording / twin / corrected twin
    series = _rrd_series(out / "diagnosis.rrd")
    for a in "xyz":
        for obs in ("position_means", "slews"):
            assert {f"/signals/acc_{a}/{obs}/{k}" for k in ("recording", "twin", "corrected_twin")} <= set(series)
    _t, v = series["/signals/acc_y/slews/corrected_twin"]
    np.testing.assert_allclose(v, cor[:, 1], rtol=1e-12)
    _t, v = series["/signals/acc_x/position_means/twin"]
    np.testing.assert_allclose(v, j["axes"]["x"]["residuals"]["reference"], rtol=1e-12)


def test_turn_report_round_means(tmp_path, concealed_records):
    """Earth's rate left out of the twin: per gyro the on-axis steps' before residual sits at
    -Omega_E sin(lat) (the recording senses it, the twin's reference lacks it), the after residual
    at zero; the .rrd's corrected twin gives the after residual in diagnosis.json."""
    case = _case("turn_table", "earth_rate_left_out")
    rec = concealed_records.make(case, 1, 1.0)
    d = run(rec, tmp_path / "diag", twin={"earth_rate": False})
    j = json.loads((tmp_path / "diag" / "diagnosis.json").read_text())
    assert (tmp_path / "diag" / "fig_residuals.png").stat().st_size > 1000
    series = _rrd_series(tmp_path / "diag" / "diagnosis.rrd")
    omega = d["gyros"]["p"]["truth_hint"]["Omega_vertical_rad_s"]
    for g, e in j["gyros"].items():
        _check_fit_steps(e)
        rs = e["residuals"]
        on = np.asarray(rs["on_axis"])
        rec_, cor = series[f"/signals/gyro_{g}/round_means/recording"][1], series[f"/signals/gyro_{g}/round_means/corrected_twin"][1]
        assert np.sqrt(np.mean((cor - rec_) ** 2)) == pytest.approx(e["fit_steps"][-1]["residual_rms"], rel=1e-9)
        r0, r1 = np.asarray(rs["before"]), np.asarray(rs["after"])
        # the offset between on-axis and across-axis steps, before and after (bias instability: 4 SE)
        shift0 = np.mean(r0[on > 0]) - np.mean(r0[on == 0])
        shift1 = np.mean(r1[on > 0]) - np.mean(r1[on == 0])
        se = e["findings"][0]["parameters"][0]["std_error"]
        assert abs(shift0 + omega) < 4 * se, (g, shift0, omega, se)
        assert abs(shift1) < 4 * se


def test_null_tilt_positions_say_no_effect(tmp_path, small_records):
    """A null tilt record (nothing left out of the physical twin): the same plots, 'no effect accepted'."""
    from imurig.reports.diagnosis_figures_tilt import figure_tilt_positions
    from imurig.diagnose.tilt_table import diagnose_tilt_table
    from imurig.kernel.outputs import OutputFolder

    rec = small_records.get(2)     # the small tilt campaign: null_recording(case, 2) of a tilt case without its own null
    d = {"kind": "tilt_table", **diagnose_tilt_table(rec, np.random.default_rng(2), n_sim=200)}
    assert found_effects(d) == set()
    with OutputFolder(tmp_path / "f") as out:
        name = figure_tilt_positions(out, d)
    assert (tmp_path / "f" / name).stat().st_size > 1000
    for e in d["axes"].values():
        assert e["fit_steps"][0]["residual_rms"] == pytest.approx(np.sqrt(np.mean(np.square(e["residuals"]["before"]))))


def test_twin_model_choice_checked_against_the_rig(tmp_path, capsys):
    """--twin-model takes the magnetometer twins, and refuses a twin that does not fit the rig."""
    from imurig.concealed import magnetometer as MC
    from imurig.kernel.recording import save_h5

    rec = MC.null_recording(3, "nominal")
    path = save_h5(rec, tmp_path / "mag.h5")
    assert main(["diagnose", str(path), "--out", str(tmp_path / "a"), "--twin-model", "physical"]) == 2
    assert "does not fit a magnetometer recording" in capsys.readouterr().err
    assert not (tmp_path / "a").exists()
    assert main(["diagnose", str(path), "--out", str(tmp_path / "b"), "--twin-model", "calibrated"]) == 0
    assert json.loads((tmp_path / "b" / "diagnosis.json").read_text())["twin_model"] == "calibrated"
    assert main(["diagnose", str(path), "--out", str(tmp_path / "c"), "--twin-without-earth-rate"]) == 2
    assert "do not apply to a magnetometer recording" in capsys.readouterr().err
