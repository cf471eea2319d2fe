"""`imurig concealed`: the concealed-effect suite written as recordings and diagnosed through
`imurig diagnose`'s own path (the file names its twin)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from imurig.cli.main import main
from imurig.concealed import cases
from imurig.concealed import suite
from imurig.reports.diagnosis import TWIN_OPTIONS
from imurig.kernel.errors import ConfigError
from imurig.kernel.files import load


def test_every_case_names_a_twin_the_diagnose_command_can_rebuild():
    for c in suite.CASES:
        for twin in (c.twin, c.null_twin or {}):
            assert set(twin) <= TWIN_OPTIONS[c.rig], (c.rig, c.effect, twin)
    assert len(set(cases.case_names())) == len(suite.CASES)


def test_unknown_or_ambiguous_case_is_refused_with_the_choices():
    with pytest.raises(ConfigError, match="imurig concealed list"):
        cases.find_case("tilt_table:no_such_effect")
    with pytest.raises(ConfigError, match="ambiguous; name the rig"):
        cases.find_case("temperature_drift")     # tilt table and magnetometer
    assert cases.find_case("magnetometer:temperature_drift").rig == "magnetometer"


def test_written_case_carries_its_twin_and_truth_and_is_reproducible(tmp_path, capsys):
    out = tmp_path / "misalignment.h5"
    main(["concealed", "write", "tilt_table:axis_misalignment", "--out", str(out), "--seed", "3"])
    assert "imurig diagnose" in capsys.readouterr().out
    rec = load(out)
    assert rec.meta["diagnose_twin"] == {"dynamics": False, "twin_model": "own_axis"}
    info = rec.meta["concealed_case"]
    assert info["expected"] == ["x:axis_misalignment", "y:axis_misalignment", "z:axis_misalignment"]
    case = cases.find_case("tilt_table:axis_misalignment")
    assert info["truth_parameter"] == case.truth_param(rec) != 0.0
    again = cases.case_recording(case, 3)
    assert all(np.array_equal(again.channels[k], rec.channels[k]) for k in rec.channels)
    before = out.read_bytes()
    assert main(["concealed", "write", "tilt_table:axis_misalignment", "--out", str(out)]) == 2
    assert "exists" in capsys.readouterr().err and out.read_bytes() == before  # never overwritten unasked


def test_concealed_all_diagnoses_the_files_as_the_benchmark_does(tmp_path):
    """Two cheap cases and their nulls through `imurig concealed all`: the files are written,
    each is diagnosed through `imurig diagnose`'s path with the twin the file names, and the
    findings equal those of the benchmark's direct diagnosis (suite.diagnose_case) of the same
    recording. The hard iron is found and its estimate lies within 4 SE of the injected truth."""
    out = tmp_path / "run"
    specs = ["rate_table_rows:instrument_range_change", "magnetometer:hard_iron"]
    main(["concealed", "all", "--out", str(out), "--cases", ",".join(specs)])
    summary = json.loads((out / "summary.json").read_text())
    assert summary["n_records"] == 4
    for r in summary["cases"] + summary["nulls"]:
        case = cases.find_case(r["case"])
        rec = load(out / "records" / f"{r['record']}.h5")
        direct = suite.diagnose_case(case, rec, r["seed"], null=r["null"])
        assert r["found"] == sorted(f"{ch}:{e}" for ch, e in suite.found_effects(direct)), r
        assert (out / "diagnoses" / r["record"] / "diagnosis.json").exists()
    by = {r["record"]: r for r in summary["cases"]}
    hard = by["magnetometer-hard_iron-s1"]
    assert hard["expected"] == ["mag:hard_iron"] and hard["correct"], hard
    assert abs(hard["z"]) < 4.0
    assert "voltmeter:instrument_range_change" in by["rate_table_rows-instrument_range_change-s1"]["found"]


def test_an_effect_named_indistinguishable_at_its_realistic_size_scores_as_right():
    """A wrong local gravity (standard instead of Delft's g) cannot be identified: the diagnosis
    claims nothing and names it as indistinguishable from the scale factors, which is right at the
    realistic size; the same silence at another size is not."""
    case = cases.find_case("tilt_table:wrong_local_gravity")
    rec = cases.case_recording(case, 1)
    d = suite.diagnose_case(case, rec, 1)
    s = cases.score(case, rec, d)
    assert s["found"] == [] and s["indistinguishable_reported"] and s["correct"]
    rec.meta["concealed_case"]["size"] = 2 * case.realistic_size      # the same data, claimed at another size
    assert not cases.score(case, rec, d)["correct"]
