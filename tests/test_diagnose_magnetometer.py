"""Mismatch discovery on magnetometer-calibration recordings: concealed installation errors, a
local field anomaly and a temperature drift are found, named and fitted within their standard
errors; null records come back clean; a disturbance outside the library is reported as an
unexplained structured residual, not forced onto a name."""
from __future__ import annotations

import json

import numpy as np
import pytest

from imurig.concealed import magnetometer as MC
from imurig.diagnose import magnetometer as M
from imurig.concealed.suite import CASES, diagnose_case, found_effects
from imurig.kernel.errors import ConfigError, RecordingError

Z_BOUND = 4.0  # |estimate - injected| <= 4 standard errors
MAG_CASES = {c.effect: c for c in CASES if c.rig == "magnetometer"}


def _check_case(effect, seed, size=None):
    case = MAG_CASES[effect]
    rec = case.make(seed, case.realistic_size if size is None else size)
    d = diagnose_case(case, rec, seed)
    assert found_effects(d) == case.expected, (effect, seed, found_effects(d))
    est, se = case.found_param(d)
    truth = case.truth_param(rec)
    assert abs(est - truth) <= Z_BOUND * se, (effect, est, truth, se)
    return d


@pytest.mark.parametrize("effect", ["hard_iron", "soft_iron", "misalignment", "local_field_anomaly",
                                    "temperature_drift", "time_delay"])
def test_concealed_effect_found_named_and_fitted(effect):
    d = _check_case(effect, seed=5)
    # what is left after the effect is at the noise model's level on every axis
    for a, v in d["per_axis"].items():
        assert v["sigma_after_nT"] < 1.3 * v["sigma_predicted_nT"], (a, v)


def test_installation_errors_named_together():
    """The campaign's drawn installation (hard and soft iron, a general non-orthogonality): the
    nominal twin finds all three; the hard iron matches the injected one."""
    d = _check_case("installation", seed=6)
    notes = [n["effects"] for n in d["indistinguishable"]]
    assert ["misalignment", "soft_iron"] in notes


@pytest.mark.parametrize("twin_model", ["nominal", "calibrated"])
def test_null_records_clean(twin_model):
    rec = MC.null_recording(7, twin_model)
    d = M.diagnose_magnetometer(rec, np.random.default_rng(7), twin_model=twin_model)
    assert not MC.found_effects(d)
    # the noise model: the fluxgate's 5 nT (plus the DAQ's share) from the samples themselves
    sig = np.array(d["noise"]["sample_sigma_nT"])
    assert np.all((sig > 4.8) & (sig < 5.6)), sig


def test_outside_the_library_is_unexplained():
    """A periodic disturbance (8 nT, 47 s period, x only) that no library effect describes."""
    rec = MC.null_recording(4, "calibrated")
    s = rec.meta["mag_nominal_sensitivity_V_per_T"][0]
    rec.channels["mag_x"] = rec.channels["mag_x"] + 8e-9 * s * np.sin(2 * np.pi * rec.time_s / 47.0)
    d = M.diagnose_magnetometer(rec, np.random.default_rng(4), twin_model="calibrated")
    assert MC.found_effects(d) == {("mag", "unexplained_residual")}
    u = d["unexplained_finding"]
    assert u["axes"] == ["x"]
    # the block series has gaps between manoeuvres: the peak sits within a few bins of 1/47 Hz
    assert abs(u["signature"]["x"]["spectral_peak_hz"] - 1 / 47.0) < 2e-3
    assert min(u["rms_over_noise_by_manoeuvre"]["x"].values()) > 5


def test_same_seed_same_data_and_report(tmp_path):
    a = MC.case_recording("hard_iron", 3, 50.0)
    b = MC.case_recording("hard_iron", 3, 50.0)
    for c in M.MAG:
        np.testing.assert_array_equal(a.channels[c], b.channels[c])
    from imurig.reports.diagnosis import _findings_rows, run

    d = run(a, tmp_path / "diag", seed=1)
    assert d["kind"] == "magnetometer"
    assert [r[1] for r in _findings_rows(d)] == ["hard_iron"]
    for f in ("report.md", "diagnosis.json", "fig_diagnosis.png", "diagnosis.rrd"):
        assert (tmp_path / "diag" / f).stat().st_size > 0
    j = json.loads((tmp_path / "diag" / "diagnosis.json").read_text())
    assert j["magnetometer"]["findings"][0]["effect"] == "hard_iron"
    assert "hard_iron" in (tmp_path / "diag" / "report.md").read_text()


def test_bad_input_refused():
    rec = MC.null_recording(3, "nominal")
    with pytest.raises(ConfigError, match="twin model"):
        M.diagnose_magnetometer(rec, np.random.default_rng(0), twin_model="physical")
    short = rec.replace(time_s=rec.time_s[:-5], channels={k: v[:-5] for k, v in rec.channels.items()})
    with pytest.raises(RecordingError, match="time base"):
        M.diagnose_magnetometer(short, np.random.default_rng(0))
    no_plan = rec.replace(meta={k: v for k, v in rec.meta.items() if k != "manoeuvres"})
    with pytest.raises(RecordingError, match="manoeuvres"):
        M.diagnose_magnetometer(no_plan, np.random.default_rng(0))
    bad = rec.replace(channels={**rec.channels, "mag_y": np.where(np.arange(rec.n) == 10, np.nan, rec.channels["mag_y"])})
    with pytest.raises(RecordingError, match="NaN"):
        M.diagnose_magnetometer(bad, np.random.default_rng(0))


def test_twin_attitude_reproduces_the_field():
    """The TRIAD attitude of the twin maps the IGRF field onto the gimbal's field to rounding."""
    rec = MC.null_recording(3, "nominal")
    tw = M.build_twin(rec)
    B = np.einsum("nij,j->ni", tw.R_CW, tw.B_W)
    B_true = np.column_stack([rec.truth_signals[f"B_C_{a}"] for a in "xyz"]) * 1e9
    assert np.max(np.abs(B - B_true)) < 1e-6 * np.linalg.norm(tw.B_W)


@pytest.mark.slow
@pytest.mark.parametrize("effect", sorted(MAG_CASES))
def test_concealed_effects_over_seeds(effect):
    """Detection and parameter error over several seeds (the benchmark's realistic sizes)."""
    z = []
    for seed in range(20, 26):
        case = MAG_CASES[effect]
        rec = case.make(seed, case.realistic_size)
        d = diagnose_case(case, rec, seed)
        assert found_effects(d) == case.expected, (effect, seed, found_effects(d))
        est, se = case.found_param(d)
        z.append((est - case.truth_param(rec)) / se)
    assert np.max(np.abs(z)) <= Z_BOUND, z
