"""``imurig reproduce``: the seed's published items beside imurig's, with tolerances and verdicts."""
from __future__ import annotations

import json

import pytest

from imurig.cli.main import main
from imurig.reports import reproduce as R


def test_the_swimmer_line_and_the_field_are_within_the_seeds_precision():
    rows = R.tab_4_1() + R.igrf_field()
    assert [r["verdict"] for r in rows] == ["within"] * 4
    b0, b1 = rows[0], rows[1]
    assert abs(b0["imurig"] - 11.2166) <= 5e-5 and abs(b1["imurig"] - 0.3958) <= 5e-5
    # the verdict can fail: a value off by more than the tolerance is 'outside'
    assert R._row("x", "q", "-", 1.0, 1.0 + 2e-5, 1e-5)["verdict"] == "outside"
    # the field's tolerance is the spread over the lab's unknown coordinates and the year: tens of nT, not 0
    assert 1.0 < rows[2]["tolerance"] < 100.0


def test_cli_writes_the_report_and_refuses_misuse(tmp_path, capsys):
    out = tmp_path / "rep"
    assert main(["reproduce", "tab_4_1", "--out", str(out)]) == 0
    rows = json.loads((out / "reproduce.json").read_text())
    assert {tuple(sorted(r)) for r in rows} == {("imurig", "item", "note", "quantity", "seed", "tolerance", "unit",
                                                  "verdict")}
    assert "Table 4.1" in (out / "reproduce.md").read_text()
    capsys.readouterr()
    assert main(["reproduce", "tab_4_1", "--out", str(out)]) == 2          # never overwritten silently
    assert "--overwrite" in capsys.readouterr().err
    assert main(["reproduce", "tab_9_9", "--out", str(tmp_path / "none")]) == 2
    err = capsys.readouterr().err
    assert "tab_9_9" in err and "tab_4_1" in err and not (tmp_path / "none").exists()


@pytest.mark.slow
def test_paper_table_1_from_the_gramian():
    rows = R.paper_table_1()
    assert {r["quantity"]: r["imurig"] for r in rows}["gyro biases observable"] == "yes"
    assert sum(r["verdict"] == "match" for r in rows) >= 5
