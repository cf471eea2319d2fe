"""Recording I/O (HDF5 lossless, lab CSV) and refusal of bad input, with nothing half-written."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from imurig.calibration.accelerometer import indicated
from imurig.campaigns.tilt_table import calibrate
from imurig.kernel.errors import OutputExistsError, RecordingError
from imurig.kernel.labcsv import read_csv, write_csv
from imurig.kernel.recording import Recording, TimeFrame, load_h5, save_h5


def test_hdf5_round_trip_is_bit_exact(small_recording, tmp_path):
    p = save_h5(small_recording, tmp_path / "r.h5")
    back = load_h5(p)
    assert np.array_equal(back.time_s, small_recording.time_s)
    for k, v in small_recording.channels.items():
        assert np.array_equal(back.channels[k], v), k
        assert back.units[k] == small_recording.units[k]
    for k, v in small_recording.truth_signals.items():
        assert np.array_equal(back.truth_signals[k], v), k
    for k, v in small_recording.segments.items():
        assert np.array_equal(back.segments[k], v), k
    assert back.truth == small_recording.truth or _json_equal(back.truth, small_recording.truth)
    assert back.meta["site"] == small_recording.meta["site"]


def _json_equal(a, b):
    import json

    from imurig.kernel.outputs import to_json

    return json.loads(to_json(a)) == json.loads(to_json(b))


def test_hdf5_refuses_to_overwrite(small_recording, tmp_path):
    p = save_h5(small_recording, tmp_path / "r.h5")
    before = p.read_bytes()
    with pytest.raises(OutputExistsError, match="overwrite"):
        save_h5(small_recording, p)
    assert p.read_bytes() == before
    save_h5(small_recording, p, overwrite=True)


def test_csv_round_trip_and_calibration_equal(small_recording, tmp_path):
    """Export to the lab CSV, read it back: same channels (to the CSV's 10 digits), same
    segments, and the same calibration as from the original."""
    rec = small_recording
    p = write_csv(rec, tmp_path / "r.csv")
    text = p.read_text().splitlines()
    assert text[0].startswith("# ")
    header = next(line for line in text if not line.startswith("#"))
    assert header.startswith("time_s,segment,run,theta_deg,phi_deg,acc_x_V")
    back = read_csv(p)
    assert set(back.channels) == set(rec.channels)
    for k in rec.channels:
        np.testing.assert_allclose(back.channels[k], rec.channels[k], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(back.segments["theta"], rec.segments["theta"], atol=1e-12)
    np.testing.assert_allclose(back.segments["start_s"], rec.segments["start_s"], atol=1e-6)
    assert back.truth is None  # the lab format never carries the truth
    u0, _ = indicated(rec)
    u1, _ = indicated(back)
    np.testing.assert_allclose(u1, u0, rtol=1e-8)
    c0 = calibrate(rec, model="linear")
    c1 = calibrate(back, model="linear")
    for a in "xyz":
        np.testing.assert_allclose(c1.results_[a].coef_, c0.results_[a].coef_, rtol=1e-6, atol=1e-9)


CSV = """# rig: tilt_table
# setpoints: ["theta", "phi"]
# acc_nominal_sensitivity_V_per_m_s2: [0.1, 0.1, 0.1]
time_s,segment,theta_deg,phi_deg,acc_x_V,acc_y_V,acc_z_V
0.00,0,0,0,0.001,0.002,0.981
0.01,0,0,0,0.001,0.002,0.981
0.02,-1,0,0,0.001,0.002,0.981
0.03,1,90,0,-0.981,0.002,0.001
0.04,1,90,0,-0.981,0.002,0.001
"""


def test_csv_example_parses(tmp_path):
    p = tmp_path / "lab.csv"
    p.write_text(CSV)
    rec = read_csv(p)
    assert rec.n_segments == 2
    np.testing.assert_allclose(rec.segments["theta"], [0, np.pi / 2])
    assert rec.units["theta"] == "rad" and rec.units["acc_x"] == "V"
    np.testing.assert_allclose(rec.segments["stop_s"], [0.02, 0.05])


@pytest.mark.parametrize("edit, msg", [
    (lambda s: s.replace("0.01,0,0,0,0.001", "0.01,0,0,0,nan"), "NaN"),
    (lambda s: s.replace("acc_y_V", "acc_y_deg"), r"come in different units \['V', 'rad'\]"),
    (lambda s: s.replace(",acc_z_V", ",acc_q_V"), "lacks channel"),
    (lambda s: s.replace("acc_x_V", "acc_x_furlongs"), "known unit suffix"),
    (lambda s: s.replace("0.04,1", "0.03,1"), "increase strictly"),
    (lambda s: s.replace("# acc_nominal_sensitivity_V_per_m_s2: [0.1, 0.1, 0.1]\n", ""), "nominal_sensitivity"),
])
def test_bad_csv_is_refused_with_a_clear_message(tmp_path, edit, msg):
    p = tmp_path / "bad.csv"
    p.write_text(edit(CSV))
    with pytest.raises(RecordingError, match=msg):
        indicated(read_csv(p))


def test_recording_without_segments_is_refused(tmp_path):
    p = tmp_path / "noseg.csv"
    p.write_text("# acc_nominal_sensitivity_V_per_m_s2: 0.1\ntime_s,acc_x_V,acc_y_V,acc_z_V\n0,0,0,1\n0.01,0,0,1\n")
    with pytest.raises(RecordingError, match="no segments"):
        indicated(read_csv(p))


def test_cli_bad_input_writes_nothing(tmp_path, capsys):
    from imurig.cli.main import main

    p = tmp_path / "bad.csv"
    p.write_text(CSV.replace("0.01,0,0,0,0.001", "0.01,0,0,0,nan"))
    out = tmp_path / "report"
    assert main(["calibrate", str(p), "--out", str(out)]) == 2
    assert "NaN" in capsys.readouterr().err
    assert not out.exists()
    assert [q.name for q in tmp_path.iterdir()] == ["bad.csv"]


def test_validate_catches_shape_and_unit_errors():
    t = np.arange(5.0)
    with pytest.raises(RecordingError, match="has 4 samples"):
        Recording(t, {"a": np.zeros(4)}, {"a": "V"}).validate()
    with pytest.raises(RecordingError, match="no unit"):
        Recording(t, {"a": np.zeros(5)}, {}).validate()


def test_readme_csv_example_parses(tmp_path):
    """The example in the README is a valid lab CSV."""
    from pathlib import Path

    readme = (Path(__file__).parents[1] / "README.md").read_text()
    blocks = readme.split("## The lab CSV format")[1].split("```")
    block = next(b for b in blocks[1::2] if "table_survey" in b)  # the full file (the minimal one comes first)
    p = tmp_path / "example.csv"
    p.write_text(block.strip() + "\n")
    rec = read_csv(p)
    assert rec.meta["table_survey"]["phi_zero_rad"]["z_down"] == 0.0233
    assert rec.meta["setpoints"] == ["theta", "phi"]
    assert rec.units["temp_box"] == "V" and rec.n_segments == 1


def test_time_frame_gives_the_recordings_rate_blocks_and_windows():
    """TimeFrame (the median step found once) gives what a Recording of the same time and segments gives:
    the rate to the bit, the blocks (two gaps, one of them short of the 1.5-period threshold) and the
    segment windows."""
    dt = 1e-3
    t = np.concatenate([np.arange(0, 2000) * dt, 2.5 + np.arange(0, 1500) * dt,
                        2.5 + (1499 + 1.4) * dt + np.arange(800) * dt])
    t = t + 1e-7 * np.random.default_rng(3).standard_normal(t.size)   # jitter: the median is a sample's
    seg = {"start_s": np.array([0.2, 2.6, 4.1]), "stop_s": np.array([1.0, 3.0, 4.7])}
    rec = Recording(time_s=t, channels={}, units={}, segments=seg)
    frame = TimeFrame(t, seg)
    assert frame.sample_rate_hz == rec.sample_rate_hz
    assert frame.n == rec.n
    for factor in (1.5, 1.3):
        assert frame.blocks(factor) == rec.blocks(factor)
    assert len(frame.blocks()) == 2 and len(frame.blocks(1.3)) == 3
    assert frame.segment_slices() == rec.segment_slices()


@settings(max_examples=60, deadline=None)
@given(st.integers(4096, 30_000), st.integers(0, 2**32 - 1), st.sampled_from(["grid", "jitter", "two", "gaps", "nan"]))
def test_median_step_is_numpys_median(n, seed, kind):
    """The median time step found from a subsample and checked by counts is np.median's, bit for bit, on
    grids with rounding, jitter, two values in near-equal shares, gaps and NaNs."""
    from imurig.kernel.recording import median_step

    rng = np.random.default_rng(seed)
    if kind == "grid":
        dt = np.diff(np.arange(n + 1) * 1e-3 + rng.uniform(0, 1e4))
    elif kind == "jitter":
        dt = 1e-3 + rng.normal(0, 1e-6, n)
    elif kind == "two":
        dt = np.where(rng.random(n) < 0.5, 1e-3, 2e-3)
    elif kind == "gaps":
        dt = np.diff(np.arange(n + 1) * 1e-3)
        dt[rng.integers(0, n, 5)] = 900.0
    else:
        dt = np.full(n, 1e-3)
        dt[rng.integers(0, n)] = np.nan
    want, got = np.median(dt), median_step(dt)
    assert (np.isnan(want) and np.isnan(got)) or got == want
    assert type(got) is np.float64
