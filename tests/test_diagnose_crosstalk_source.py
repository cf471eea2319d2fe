"""Crosstalk on a tilt table whose file gives no scan order (the independent lab's minimal CSV):
every logged channel outside the triad is tried as the leak source, the choice counted in the
threshold. Truth from the independent generator's manifest: its logger converts acc_x, mag_x,
acc_y, mag_y, acc_z, mag_z, and each accelerometer keeps c = 2e-4 of the channel before it."""
from __future__ import annotations

import json

import numpy as np
import pytest

import independent_lab as lab
from imurig.diagnose.summary import findings
from imurig.diagnose.tilt_table import diagnose_tilt_table
from imurig.kernel.files import load


def _diagnosed(tmp_path, seed: int, converter: str):
    path = lab.write_recording(tmp_path / f"xt-{seed}.csv", "tilt_table", "adc_crosstalk", seed, fs_hz=50.0,
                               converter=converter)
    truth = json.loads(path.with_suffix(".json").read_text())
    rec = load(str(path))
    assert "adc_scan_list" in rec.meta["inferred"]        # the import only guessed the order from the columns
    d = {"kind": "tilt_table", **diagnose_tilt_table(rec, np.random.default_rng(seed))}
    return d, truth


@pytest.mark.parametrize("seed", [11, 12])
def test_the_leak_source_is_named_and_c_lies_within_3_se(tmp_path, seed):
    d, truth = _diagnosed(tmp_path, seed, "24bit_10V")
    scan = truth["scan_list"]
    c_true = next(e for e in truth["effects"] if e["effect"] == "adc_crosstalk")["parameters"]["c"]
    found = findings(d)
    assert sorted((f["channel"], f["effect"]) for f in found) == [
        ("acc_x", "adc_crosstalk"), ("acc_y", "adc_crosstalk"), ("acc_z", "adc_crosstalk")]
    for f in found:
        source = scan[scan.index(f["channel"]) - 1]          # the channel converted before it
        assert f["source_channel"] == source
        (p,) = f["parameters"]
        assert p["name"] == "c" and abs(p["estimate"] - c_true[f["channel"]]) < 3 * p["se"]
    assert d["adc_scan_order"]["crosstalk_sources_tested"] == ["mag_x", "mag_y", "mag_z"]


def test_a_source_clipped_at_the_rail_is_not_tested(tmp_path):
    # 0.08 V/uT on a 48.6 uT field is 3.9 V: the +-2.5 V converter clips every magnetometer axis
    d, _ = _diagnosed(tmp_path, 13, "18bit_2V5")
    order = d["adc_scan_order"]
    assert order["crosstalk_sources_tested"] == []
    assert set(order["crosstalk_sources_clipped"]["positions_at_rail"]) == {"mag_x", "mag_y", "mag_z"}
    assert not any(f["effect"] == "adc_crosstalk" for f in findings(d))
