"""The tilt-table diagnosis from a file read in row ranges (imurig.kernel.filerecord,
imurig.diagnose.raw_record): the chunked zero-phase filter against the whole-block filter, exact
order statistics in passes, runs across pieces, the same findings as from the loaded recording,
memory that does not grow with the record beyond its 100 Hz working record, and a clear refusal
where the memory a reader needs is not available."""
from __future__ import annotations

import tracemalloc

import numpy as np
import pytest
from independent_lab import tilt
from independent_lab.lab import write_csv
from scipy import signal

from imurig.calibration.preprocess import filter_design
from imurig.calibration.stream_filter import filtfilt_decimated, settle_length
from imurig.diagnose.position_noise import code_histogram
from imurig.diagnose.raw_record import InMemoryRaw, StreamedRaw, _RunTracker
from imurig.diagnose.tilt_table import diagnose_tilt_table
from imurig.kernel import import_lab
from imurig.kernel.errors import RecordingError
from imurig.kernel.filerecord import FileRecord, open_file_record
from imurig.kernel.files import load
from imurig.kernel.outputs import clean_json
from imurig.kernel.ranks import median_search
from imurig.kernel.recording import Recording, save_h5
from imurig.sensors.effects.saturation import _runs

EPS = np.finfo(float).eps


def _signal(n: int, rng: np.random.Generator) -> np.ndarray:
    """Three columns: a random walk, a slow sine with white noise, and steps (a table's moves)."""
    t = np.arange(n)
    return np.column_stack([np.cumsum(rng.normal(size=n)), 5 * np.sin(t / 300) + rng.normal(size=n),
                            np.repeat(rng.normal(size=n // 1000 + 1) * 10, 1000)[:n]])


@pytest.mark.parametrize("fs", [200.0, 1000.0, 1024.0])
@pytest.mark.parametrize("piece", [997, 4096])
def test_chunked_filter_is_the_whole_block_filter(fs, piece):
    """sosfiltfilt(..)[::k] of a block read in pieces equals the whole-block filter to rounding: the
    forward pass carries its state (the same recursion), the backward pass restarts from the steady
    state L = settle_length samples beyond each stretch, where the start error has decayed to
    eps^2. Bound: 16 eps of the signal's scale (the three sections' own roundings, a few per sample
    and section). With an overlap of one sample the restart error is visible (the bound can fail)."""
    k, sos, _ = filter_design(fs)
    x = _signal(40_000, np.random.default_rng(int(fs)))
    padlen = min(3 * (2 * len(sos) + 1), x.shape[0] - 1)
    whole = signal.sosfiltfilt(sos, x, axis=0, padlen=padlen)[::k]
    got = filtfilt_decimated(lambda a, b: x[a:b], x.shape[0], sos, k, padlen, piece=piece)
    assert got.shape == whole.shape
    scale = np.max(np.abs(whole), axis=0)
    assert np.all(np.max(np.abs(got - whole), axis=0) <= 16 * EPS * scale)
    short = filtfilt_decimated(lambda a, b: x[a:b], x.shape[0], sos, k, padlen, piece=piece, overlap=1)
    assert np.max(np.abs(short - whole) / scale) > 1e-6
    # the overlap: the filter's impulse response has decayed below eps^2 of its peak after L samples
    L = settle_length(sos)
    h = signal.sosfilt(sos, np.r_[1.0, np.zeros(2 * L)])
    assert np.max(np.abs(h[L:])) <= EPS ** 2 * np.max(np.abs(h)) * L


@pytest.mark.parametrize("kind", ["continuous", "codes", "outliers", "periodic"])
@pytest.mark.parametrize("limit", [1 << 20, 40])
def test_rank_search_gives_numpys_median(kind, limit):
    """The median found in passes is np.median's value, bit for bit, whether the first bracket holds
    the ranks or must be narrowed (a limit of 40 distinct values) or widened (a periodic sequence
    whose strided subsample misses the median's values)."""
    rng = np.random.default_rng(7)
    x = {"continuous": rng.normal(size=100_001), "codes": np.round(rng.normal(size=100_000) * 0.7) * 1.5e-4,
         "outliers": np.concatenate([rng.normal(size=50_000), [1e12, -1e12, 3e11]]),
         "periodic": np.tile(np.arange(37.0), 2000)}[kind]
    search = median_search(x.size, x[::37], limit=limit)
    for _ in range(12):
        for a in range(0, x.size, 6000):
            search.feed(x[a:a + 6000])
        if search.end():
            break
    assert search.result is not None and search.median() == np.median(x)


def test_runs_across_pieces():
    """Runs of True fed in pieces: the same (start, length) of the runs of >= 2 as over the whole mask."""
    rng = np.random.default_rng(3)
    mask = rng.random(20_000) < 0.7
    st, ln = _runs(mask)
    tr = _RunTracker()
    for a in range(0, mask.size, 333):
        tr.feed(mask[a:a + 333], a)
    tr.close()
    s2, l2 = tr.result()
    keep = ln >= 2
    assert np.array_equal(s2, st[keep]) and np.array_equal(l2, ln[keep])


def _same(a, b, path="", rtol=1e-9, atol=1e-12) -> list:
    """Paths where two JSON-like trees differ: text, keys or lengths at all, numbers beyond
    atol + rtol |value|. The working records differ by the filter's rounding (16 eps of the signal,
    above); through the position fits that is ~1e-14 m/s^2 on residuals of ~1e-4 m/s^2 (up to 4e-10
    of them, measured) and ~4e-11 on a BIC of -600; atol 1e-12 (SI) and rtol 1e-9 hold those and
    nothing a finding could turn on."""
    if isinstance(a, dict):
        if set(a) != set(b):
            return [(path, sorted(set(a) ^ set(b)))]
        return [d for k in a for d in _same(a[k], b[k], f"{path}/{k}", rtol, atol)]
    if isinstance(a, list):
        if len(a) != len(b):
            return [(path, "length")]
        return [d for i, (x, y) in enumerate(zip(a, b)) for d in _same(x, y, f"{path}[{i}]", rtol, atol)]
    if isinstance(a, (int, float)) and not isinstance(a, bool) and isinstance(b, (int, float)):
        return [] if abs(a - b) <= atol + rtol * max(abs(a), abs(b)) else [(path, a, b)]
    return [] if a == b else [(path, a, b)]


def _streamed(path, monkeypatch, piece: int) -> dict:
    monkeypatch.setattr(StreamedRaw, "piece", piece)
    with open_file_record(path) as f:
        return clean_json(diagnose_tilt_table(f, np.random.default_rng(4), n_sim=100, dynamics=False))


def test_streamed_raw_statistics_of_a_simulated_record(small_records, tmp_path, monkeypatch):
    """The small protocol at 1 kHz with the loose cable (two mountings: two blocks; spikes on acc_y),
    saved and read from the file in pieces of 8 Ki rows (the chunked filter, the passes and the
    order-statistic searches all run): everything the diagnosis takes of the record (the working
    record, each channel's step and rails, the positions' moments and dither, the flat-top test) is
    what the loaded recording gives: the working record to the filter's rounding (16 eps of the
    signal, as above), the rest to rounding of sums over pieces. (The whole diagnosis through both:
    the next test, and the CLI's below.)"""
    rec = small_records.get(5, loose_cable=True)
    path = save_h5(rec, tmp_path / "small.h5")
    monkeypatch.setattr(StreamedRaw, "piece", 1 << 13)
    rec = load(path)                      # the file's recording (its metadata through JSON)
    mem = InMemoryRaw(rec)
    w0 = mem.working()
    with FileRecord(path) as f:
        assert len(f.blocks()) == len(rec.blocks()) == 2
        assert f.segment_slices() == rec.segment_slices() and f.sample_rate_hz == rec.sample_rate_hz
        raw = StreamedRaw(f)
        w1 = raw.working()
        assert raw.decimated and mem.decimated
        assert np.array_equal(w0.time_s, w1.time_s) and w0.meta == w1.meta and list(w0.channels) == list(w1.channels)
        for c, x in w0.channels.items():
            assert np.max(np.abs(w1.channels[c] - x)) <= 16 * EPS * np.max(np.abs(x)), c
        medians = np.linspace(-5, 5, 11)
        for c in rec.channels:
            if rec.units[c] == "V":
                assert raw.adc_step(c) == mem.adc_step(c)
                assert np.array_equal(raw.at_rail(c, medians), mem.at_rail(c, medians))
        for c in raw.triad:
            for u, v in zip(raw.segment_moments(c), mem.segment_moments(c)):
                assert np.array_equal(u, v), c
            q = raw.adc_step(c)     # the dither's codes per position (dither_sd_from is one function for both)
            x = rec.channels[c] / q
            for h0, h1 in zip([code_histogram(x[s]) for s in rec.segment_slices()], raw._moments[c][3]):
                assert all(np.array_equal(u, v) for u, v in zip(h0, h1))
            assert _same(mem.raw_tests(c, 0.01), raw.raw_tests(c, 0.01)) == []
            assert np.array_equal(raw.segment_samples(c, 3), mem.segment_samples(c, 3))


def test_streamed_diagnosis_of_a_clipped_lab_record(tmp_path, monkeypatch):
    """A numpy-made lab record (the independent generator: 50 Hz, 12-bit, acc_z clipped, no scan
    order): the working record is the record as logged, the leak sources' rails, the clipped mean,
    the converter's dither and the clip's limit come from the file; the same diagnosis, with the
    saturation finding."""
    cols, steps, _ = tilt.record(11, "saturation", 50.0, "12bit_10V", dwell_s=4.0)
    csv = tmp_path / "clipped.csv"
    write_csv(csv, {"rig": "tilt_table", "site": "delft"}, cols, steps)
    rec = load(csv)
    path = save_h5(rec, tmp_path / "clipped.h5")
    whole = clean_json(diagnose_tilt_table(rec, np.random.default_rng(4), n_sim=100, dynamics=False))
    assert [f["effect"] for f in whole["axes"]["z"]["findings"]] == ["saturation"]
    assert _same(whole, _streamed(path, monkeypatch, 1000)) == []


def _synthetic(path, n: int, rng: np.random.Generator, quantum: bool = True):
    """A 1 kHz record of n rows: three 16-bit channels at a level held for 10 s at a time (a position)
    with noise of 2 steps, one segment per level."""
    t = np.arange(n) / 1000.0
    q = 10.0 / 2 ** 16
    ch = {f"acc_{a}": np.round((0.5 * np.sin(np.floor(t / 10.0) + i) + rng.normal(0, 2 * q, n)) / q) * q
          for i, a in enumerate("xyz")}
    start = np.arange(1.0, t[-1] - 10.0, 10.0)
    rec = Recording(time_s=t, channels=ch, units=dict.fromkeys(ch, "V"),
                    channel_quantum=dict.fromkeys(ch, q) if quantum else {},
                    segments={"start_s": start, "stop_s": start + 8.0}, segment_units={"start_s": "s", "stop_s": "s"},
                    meta={"rig": "tilt_table"})
    return save_h5(rec, path)


@pytest.mark.parametrize("max_distinct", [1 << 21, 100])
def test_step_from_the_values_streamed(tmp_path, monkeypatch, max_distinct):
    """A channel whose step neither the file nor its metadata give: the step estimated from its
    distinct values, gathered piece by piece (or, past ``max_distinct`` of them, from the channel
    read whole), is the loaded record's."""
    import imurig.diagnose.raw_record as rr

    path = _synthetic(tmp_path / "f.h5", 60_000, np.random.default_rng(1), quantum=False)
    monkeypatch.setattr(rr, "MAX_DISTINCT", max_distinct)
    mem = InMemoryRaw(load(path))
    with FileRecord(path) as f:
        raw = StreamedRaw(f)
        assert raw.adc_step("acc_x") == mem.adc_step("acc_x") > 0


def _peak_bytes(path) -> int:
    tracemalloc.start()
    try:
        with FileRecord(path) as f:
            raw = StreamedRaw(f)
            raw.working()
            raw.segment_moments("acc_x")
            raw.raw_tests("acc_x", 0.01)
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_memory_does_not_grow_with_the_record(tmp_path):
    """Peak traced memory of the streamed raw statistics on a record and on one 4 x longer: it grows by
    at most twice the working record's growth (n / 10 rows x 4 columns x 8 bytes) plus 2 MB, where the
    loaded record alone grows by 3 n x 8 bytes x 3 channels (the test can fail: with the
    second differences' subsample kept as views, which hold every piece, it grows by 11 MB here)."""
    rng = np.random.default_rng(0)
    n = 100_000
    small, big = _synthetic(tmp_path / "a.h5", n, rng), _synthetic(tmp_path / "b.h5", 4 * n, rng)
    growth = _peak_bytes(big) - _peak_bytes(small)
    working = 3 * n // 10 * 4 * 8
    assert growth <= 2 * working + 2e6, growth


def test_refused_before_allocating(tmp_path, monkeypatch, small_records):
    """Where the available memory cannot hold the working record (or the whole record, for a reader
    that needs it), a RecordingError says how much is needed, before anything record-sized is read."""
    path = save_h5(small_records.get(5, loose_cable=True), tmp_path / "small.h5")
    monkeypatch.setattr(import_lab, "available_memory_bytes", lambda: 10_000)
    with FileRecord(path) as f:
        with pytest.raises(RecordingError, match="working record.*GB are available"):
            StreamedRaw(f).working()
        with pytest.raises(RecordingError, match="GB to import"):
            f.load()


def test_cli_diagnoses_a_declared_lab_csv_from_the_file(tmp_path, monkeypatch, capsys):
    """`imurig diagnose REC.csv` on a lab CSV that declares its structure (as `imurig convert` writes
    it) reads it through a FileRecord on a temporary HDF5 file beside the report folder (removed
    afterwards) and writes its
    report, with the clip found (the same diagnosis as from the loaded record: the test above)."""
    import json

    from imurig.cli import recordings
    from imurig.cli.main import main
    from imurig.kernel.labcsv import write_csv as write_lab_csv

    cols, steps, _ = tilt.record(11, "saturation", 50.0, "12bit_10V", dwell_s=4.0)
    write_csv(tmp_path / "minimal.csv", {"rig": "tilt_table", "site": "delft"}, cols, steps)
    csv = write_lab_csv(load(tmp_path / "minimal.csv"), tmp_path / "declared.csv")
    opened = []

    def spy(path, **kw):
        opened.append(open_file_record(path, **kw))
        return opened[-1]
    monkeypatch.setattr(recordings, "open_file_record", spy)
    assert main(["diagnose", str(csv), "--out", str(tmp_path / "s")]) == 0
    assert len(opened) == 1 and isinstance(opened[0], FileRecord) and not opened[0].path.exists()
    assert opened[0].path.parent.parent == tmp_path          # beside the report folder, not in /tmp
    streamed = json.loads((tmp_path / "s" / "diagnosis.json").read_text())
    assert [f["effect"] for f in streamed["findings"]] == ["saturation"]
    assert capsys.readouterr().out.strip().splitlines()[-1] == f"verdict: {streamed['verdict']}"
