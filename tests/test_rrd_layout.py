"""The .rrd recordings show what they log: every logged entity lies in a view (of the kind that
draws it) of the blueprint stored in the same file, both read back with rerun's RrdReader; the
roles (measured, calibrated, truth, twin, corrected twin, residuals) have their own legend names
and colours. The campaign writers of the tilt and turn tables and of the flight are checked on the
recordings tests/test_cli.py and tests/test_flight_cli.py already write (and every writer warns,
an error under pytest, when it logs outside its blueprint)."""
from __future__ import annotations

import numpy as np
import pytest
import rerun as rr

from imurig.reports import diagnosis_rrd, montecarlo_rrd, viz
from imurig.reports.rrd_layout import _rules, _shows, entities_in_rrd, readable, uncovered, views_in_rrd


def check_rrd(path) -> dict[str, set[str]]:
    """Assert a blueprint is stored and shows every logged entity; returns the entities."""
    ents, views = entities_in_rrd(path), views_in_rrd(path)
    assert views, f"{path}: no blueprint stored"
    assert uncovered(ents, views) == [], path
    return ents


def legends(path) -> dict[str, tuple[str, tuple]]:
    """{entity: (legend name, rgba)} of every SeriesLines / SeriesPoints in the recording."""
    out = {}
    for chunk in rr.chunk.RrdReader(str(path)).stream():
        b = chunk.to_record_batch()
        for arch in ("SeriesLines", "SeriesPoints"):
            if f"{arch}:names" in b.schema.names:
                name = b.column(f"{arch}:names").to_pylist()[-1][0]
                colors = b.column(f"{arch}:colors").to_pylist()[-1] if f"{arch}:colors" in b.schema.names else None
                out[str(chunk.entity_path)] = (name, tuple(colors) if colors else None)
    return out


def test_view_contents_follow_the_viewers_rule():
    """The example of rerun's ViewContents documentation: most specific rule wins."""
    rules = _rules("/", ["+ /world/**", "- /world", "- /world/car/**", "+ /world/car/driver"])
    assert _shows(rules, "/world/car/driver") and _shows(rules, "/world/house")
    assert not _shows(rules, "/world/car/hood") and not _shows(rules, "/world") and not _shows(rules, "/road")
    assert _shows(_rules("/signals", "$origin/**"), "/signals/raw/acc_x")
    assert not _shows(_rules("/signals", "$origin/**"), "/signalsx")


def test_an_entity_outside_every_view_is_reported(tmp_path):
    """The one layout every recording had: a diagnosis' overlays and field-space points are in
    no view; the writer warns and the file read back says which (and which kind of view)."""
    out = tmp_path / "old.rrd"
    t = np.arange(5.0)
    with pytest.warns(viz.RrdLayoutWarning, match="step_bias/recording"):
        with viz.RrdWriter(out) as w:  # the former default blueprint: rig, raw, calibrated, summary
            viz.log_scalars(w, "signals/raw", t, {"acc_x": t})
            viz.log_scalars(w, "signals/acc_x/step_bias", t, {"recording": t})
            viz.log_points(w, "field_space/measured", np.zeros((3, 3)))
            viz.log_text(w, "summary", "x")
    assert uncovered(entities_in_rrd(out), views_in_rrd(out)) == [
        "/field_space/measured (3D)", "/signals/acc_x/step_bias/recording (TimeSeries)"]


def test_readable_units():
    assert readable([1e-3, -2e-3], "m/s^2") == (1e3, "mm/s^2")
    assert readable([3e-6], "rad/s") == (1e6, "µrad/s")
    assert readable([0.5, 30.0], "nT") == (1.0, "nT")
    assert readable([2e-4], "1") == (1e3, "10⁻³ 1")


def test_diagnosis_recording_shows_overlays_and_residuals(tmp_path):
    """Per (channel, observable): recording, twin and corrected twin, then the residuals before
    (recording − twin) and after (recording − corrected twin), each with its own name and colour."""
    rng = np.random.default_rng(1)
    t = np.linspace(0.0, 3600.0, 12)
    twin = 9.81 * np.cos(np.linspace(0, 3, 12))
    rec = twin + 2e-3 + rng.normal(0, 1e-4, 12)
    overlays = [("signals/acc_x/position_means", t, {"recording": rec, "twin": twin, "corrected_twin": twin + 2e-3},
                 "m/s^2"),
                ("signals/acc_y/slews", t, {"recording": rec, "twin": twin, "corrected_twin": twin}, "m/s^2"),
                ("signals/mag_x/field", t, {"recording": 1e4 + t, "twin": 1e4 + t, "corrected_twin": 1e4 + t}, "nT")]
    out = tmp_path / "diagnosis.rrd"
    diagnosis_rrd.write(out, overlays, "# Diagnosis\n\n- none")
    ents = check_rrd(out)
    for prefix, *_ in overlays:
        ch = prefix[len("signals/"):]
        assert {f"/{prefix}/{k}" for k in ("recording", "twin", "corrected_twin")} <= set(ents)
        assert {f"/residuals/{ch}/before", f"/residuals/{ch}/after"} <= set(ents)
    lg = legends(out)
    four = [lg[f"/signals/acc_x/position_means/{k}"] for k in ("recording", "twin", "corrected_twin")] + \
        [lg["/residuals/acc_x/position_means/before"]]
    assert len({n for n, _ in four}) == 4 and len({c for _, c in four}) == 4
    assert lg["/residuals/acc_x/position_means/before"][0] == "before: recording − twin [mm/s^2]"
    # the residual read back: (recording − twin) in mm/s^2
    for chunk in rr.chunk.RrdReader(str(out)).stream():
        if chunk.entity_path == "/residuals/acc_x/position_means/before" and not chunk.is_static:
            v = np.array([x[0] for x in chunk.to_record_batch().column("Scalars:scalars").to_pylist()])
            np.testing.assert_allclose(v, (rec - twin) * 1e3, rtol=1e-12)
            break
    else:
        pytest.fail("no residual series in the recording")


class _Study:
    """What montecarlo_rrd reads of a study: ``rows`` {run: [parameter rows]}."""

    def __init__(self, n: int, rng: np.random.Generator):
        self.rows = {}
        for i in range(n):
            z = rng.normal(size=2)
            self.rows[i] = [{"name": "bias_x", "unit": "m/s^2", "injected": 0.01, "std_error": 1e-4,
                             "estimate": 0.01 + 1e-4 * z[0], "z": z[0], "crlb": 1e-4},
                            {"name": "sensitivity_x", "unit": "1", "injected": 1.0, "std_error": 1e-5,
                             "estimate": 1.0 + 1e-5 * z[1], "z": z[1], "crlb": 1e-5}]


def test_montecarlo_recording_shows_z_and_errors_per_unit(tmp_path):
    out = tmp_path / "study.rrd"
    montecarlo_rrd.write_rrd(out, _Study(6, np.random.default_rng(2)), "| parameter |\n|---|\n| bias_x |")
    ents = check_rrd(out)
    assert {"/z/bias_x", "/z/sensitivity_x", "/z_band/upper", "/error/m_per_s2/bias_x",
            "/error/1/sensitivity_x"} <= set(ents)
    assert len(views_in_rrd(out)) == 4  # z, one error view per unit (two), the statistics
    assert legends(out)["/error/m_per_s2/bias_x"][0] == "bias_x [mm/s^2]"


def test_thermal_campaign_recording(tmp_path):
    """A short thermal campaign (one cycle -20..40 degC, 10 min soaks): rig, temperatures, biases
    against the twin's, residuals of the temperature model, all in views."""
    from imurig.campaigns.thermal import ThermalCampaign, analyse
    from imurig.reports import thermal_rrd
    from imurig.rigs.thermal_chamber import ThermalProfile

    profile = ThermalProfile(low_C=-20, high_C=40, step_C=20, cycles=1, soak_s=600, attitude_dwell_s=20)
    rec = ThermalCampaign(profile=profile, seed=1).simulate()
    out = tmp_path / "thermal.rrd"
    thermal_rrd.write_rrd(out, rec, analyse(rec))
    ents = check_rrd(out)
    assert {"/signals/twin/acc_bias/x", "/signals/calibrated/acc_bias/x", "/signals/residuals/acc_bias/x",
            "/signals/temperature/T_air"} <= set(ents)
    lg = legends(out)
    assert lg["/signals/twin/acc_bias/x"] != lg["/signals/calibrated/acc_bias/x"]


@pytest.mark.slow
def test_magnetometer_campaign_recording(tmp_path):
    """A short magnetometer campaign: field space (measured ellipsoid, calibrated points, IGRF
    sphere) in a 3-D view of its own; |B| against IGRF and its residual."""
    from imurig.campaigns.magnetometer import MagnetometerCampaign, analyse
    from imurig.reports import magnetometer_rrd
    from imurig.rigs.mag_rig import CompassSwing, LevelCircle, Tumble

    camp = MagnetometerCampaign(seed=1, circle=LevelCircle(turns=1, rate_dps=30, wobble_deg=0.0),
                                tumble=Tumble(duration_s=60.0), swing=CompassSwing(dwell_s=3.0),
                                validation=LevelCircle(turns=1, rate_dps=30, start_heading_deg=17, wobble_deg=0.0,
                                                       name="validation_circle"))
    rec = camp.simulate()
    out = tmp_path / "mag.rrd"
    magnetometer_rrd.write_rrd(out, rec, analyse(rec))
    ents = check_rrd(out)
    assert {"/field_space/measured", "/field_space/calibrated", "/field_space/igrf_sphere",
            "/signals/residuals/norm", "/signals/truth/norm"} <= set(ents)
    assert any(c == "3D" and o == "/field_space" for c, o, _ in views_in_rrd(out))


def test_flight_recording(tmp_path):
    """The flight writer on a synthetic two-minute straight flight: routes in 3-D, the errors of
    both runs with their 3σ; each run its own colour."""
    from types import SimpleNamespace as NS

    from imurig.kernel.outputs import OutputFolder
    from imurig.reports import flight_rrd

    rng = np.random.default_rng(3)
    t = np.arange(0.0, 120.0, 0.04)
    lat = np.radians(52.0) + 1e-6 * t
    truth = NS(lat_rad=lat, lon_rad=np.full_like(t, np.radians(4.4)), h_m=np.full_like(t, 300.0), rate_hz=25.0)
    gps = NS(lat_rad=lat[::25], lon_rad=truth.lon_rad[::25], h_m=truth.h_m[::25])
    runs = {}
    for name in ("uncalibrated", "calibrated"):
        res = NS(lat_rad=lat, lon_rad=truth.lon_rad, h_m=truth.h_m, time_s=t, meta={"nav_rate_hz": 25.0},
                 P_diag=np.full((t.size, 15), 1e-4))
        err = {k: rng.normal(0, 1e-3, t.size) for k in ("roll_rad", "pitch_rad", "heading_rad", "nees")}
        err["pos_N_m"] = rng.normal(0, 1.0, (t.size, 3))
        runs[name] = (res, err, None)
    with OutputFolder(tmp_path / "f") as folder:
        flight_rrd.write_rrd(folder, truth, runs, gps, "# Flight")
    out = tmp_path / "f" / "flight.rrd"
    ents = check_rrd(out)
    assert {"/world/truth_route", "/world/gps_fixes", "/world/ekf_calibrated", "/errors/calibrated/nees",
            "/errors/uncalibrated/heading_3sigma_deg"} <= set(ents)
    lg = legends(out)
    assert lg["/errors/calibrated/roll_err_deg"][1] != lg["/errors/uncalibrated/roll_err_deg"][1]
    assert lg["/errors/calibrated/roll_err_deg"][0] != lg["/errors/uncalibrated/roll_err_deg"][0]


def test_rrd_follows_the_umask(tmp_path):
    """A lab group shares its outputs: the .rrd gets 0666 less the umask (not mkstemp's 0600)."""
    import os

    old = os.umask(0o022)
    try:
        with viz.RrdWriter(tmp_path / "u.rrd", blueprint=None) as w:
            viz.log_text(w, "summary", "x")
    finally:
        os.umask(old)
    assert (tmp_path / "u.rrd").stat().st_mode & 0o777 == 0o644


def test_lines_break_at_gaps():
    """A NaN in the middle of each gap longer than 5 sample intervals (the viewer breaks the line
    there); nothing else changes."""
    t = np.concatenate([np.arange(0.0, 1.0, 0.1), np.arange(5.0, 6.0, 0.1)])
    t2, s2 = viz.break_gaps(t, {"a": np.arange(t.size, dtype=float)})
    assert t2.size == t.size + 1 and t2[10] == pytest.approx(0.5 * (0.9 + 5.0)) and np.isnan(s2["a"][10])
    np.testing.assert_array_equal(np.delete(s2["a"], 10), np.arange(t.size))
    t3, s3 = viz.break_gaps(np.arange(0.0, 1.0, 0.1), {"a": np.ones(10)})
    assert t3.size == 10 and not np.isnan(s3["a"]).any()
