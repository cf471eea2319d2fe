"""The turn-table diagnosis from a file read in row ranges (imurig.diagnose.turn_record,
imurig.diagnose.slip_ring_stream): each read the diagnosis makes of the 1 kHz record equals the
loaded record's (pulse edges, percentiles, the gyro's integrals and running sums, the windows and
their means, the raw tests) bit for bit, read in pieces that cut the pulses and windows anywhere; the
diagnosis' findings and numbers equal the loaded record's to the rounding of reordered sums; and its
memory does not grow with the record's length."""
from __future__ import annotations

import json
import math
import tracemalloc

import numpy as np
import pytest
from independent_lab import write_recording

from imurig.calibration.triad import indicated
from imurig.calibration.gyro import SPEC
from imurig.diagnose.raw_record import StreamedRaw
from imurig.diagnose.turn_record import InMemoryTurn, StreamedTurn
from imurig.diagnose.turn_table import _slip_rings, diagnose_turn_table
from imurig.kernel.filerecord import FileRecord
from imurig.kernel.files import load
from imurig.kernel.outputs import clean_json
from imurig.kernel.recording import Recording, save_h5

#: sums of up to N = 1e6 terms in another order differ by at most N eps relative (2.2e-10): the bound
#: on the diagnosis' numbers, streamed against loaded (p-values on the log scale)
REORDERED = 1e6 * np.finfo(float).eps


@pytest.fixture(scope="module")
def timer_record(tmp_path_factory):
    """The independent lab's 200 Hz timer record (one mounting, gyro_r on the table axis, plateaus
    inferred from the dial): loaded, and saved as an imurig .h5 file."""
    d = tmp_path_factory.mktemp("turn")
    rec = load(write_recording(d / "timer.csv", "turn_table", "timer_quantisation", 11002))
    return rec, save_h5(rec, d / "timer.h5")


@pytest.fixture
def pieces(monkeypatch):
    """Pieces of 997 rows: every pulse, window and block is cut somewhere; the sample interval's median
    searched in passes (the CSV's clock has more than 64 distinct intervals)."""
    from imurig.kernel import h5stream
    monkeypatch.setattr(StreamedTurn, "piece", 997)
    monkeypatch.setattr(StreamedRaw, "piece", 997)
    monkeypatch.setattr(h5stream, "MAX_DISTINCT_DT", 64)


def test_streamed_reads_are_the_loaded_records(timer_record, pieces):
    rec, path = timer_record
    mem = InMemoryTurn(rec)
    with FileRecord(path) as f:
        st = StreamedTurn(f)
        assert st.dt == mem.dt
        assert st._percentiles("pulse", (1.0, 99.9)) == tuple(np.percentile(rec.channels["pulse"], [1.0, 99.9]))
        for thr in (None, 1.3):
            a, b = mem.edges(thr), st.edges(thr)
            assert set(a) == set(b) and all(np.array_equal(a[k], b[k]) for k in a)
        tp = a["time_s"]
        assert tp.size > 40
        probe = np.concatenate([[rec.time_s[0] - 1.0], tp, [rec.time_s[-1] + 1.0]])
        for sign in (1.0, -1.0):
            g, h = mem.gyro("gyro_r", sign), st.gyro("gyro_r", sign)
            assert all(np.array_equal(x, y) for x, y in zip(g.integrals(probe), h.integrals(probe)))
            assert np.array_equal(g.sums(tp, 10), h.sums(tp, 10))
            assert all(np.array_equal(g.window(x, y), h.window(x, y)) for x, y in zip(tp[:-1], tp[1:]))
        for timer in ("channel", "adc"):
            (rw1, r1), (rw2, r2) = mem.windows(timer), st.windows(timer)
            assert np.array_equal(r1, r2)
            assert all(np.array_equal(rw1.segments[k], rw2.segments[k]) for k in rw1.segments)
        fn = lambda r: indicated(r, SPEC, "mean")[0]      # noqa: E731
        assert np.array_equal(mem.per_window(rw1, SPEC.channels, fn), st.per_window(rw2, SPEC.channels, fn))
        for ch in ("gyro_p", "gyro_r"):
            assert clean_json(mem.raw_tests(ch, 0.01)) == clean_json(st.raw_tests(ch, 0.01))


def _close(a, b, path=""):
    """Equal structure and strings; numbers within REORDERED (relative; p-values on the log scale)."""
    if isinstance(a, dict):
        assert set(a) == set(b), path
        for k in a:
            _close(a[k], b[k], f"{path}/{k}")
    elif isinstance(a, list):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            _close(x, y, f"{path}[{i}]")
    elif isinstance(a, float) and isinstance(b, float):
        if "p_value" in path and a > 0 and b > 0:
            a, b = math.log(a), math.log(b)
        assert abs(a - b) <= REORDERED * max(abs(a), abs(b)), (path, a, b)
    else:
        assert a == b, path


def test_streamed_diagnosis_has_the_loaded_records_findings(timer_record, pieces):
    rec, path = timer_record
    timer = rec.meta["timer"]
    want = clean_json(diagnose_turn_table(rec, np.random.default_rng(0), timer=timer))
    with FileRecord(path) as f:
        got = clean_json(diagnose_turn_table(f, np.random.default_rng(0), timer=timer))
    assert want["table_rate"]["timer"]["method"] == "gyro angle"       # the gyro's integrals were used
    assert all(want["gyros"][a]["scatter"]["tested"] for a in "pqr")   # the slip-ring test ran
    _close(json.loads(json.dumps(want)), json.loads(json.dumps(got)))


def _repeated(rec: Recording, times: int) -> Recording:
    """The record played ``times`` times end to end (one sample period between copies)."""
    span = rec.time_s[-1] - rec.time_s[0] + float(np.median(np.diff(rec.time_s)))
    off = [i * span for i in range(times)]
    seg = {k: (np.concatenate([v + o for o in off]) if k in ("start_s", "stop_s") else np.tile(v, times))
           for k, v in rec.segments.items()}
    return Recording(time_s=np.concatenate([rec.time_s + o for o in off]),
                     channels={k: np.tile(v, times) for k, v in rec.channels.items()}, units=dict(rec.units),
                     segments=seg, segment_units=dict(rec.segment_units), meta=dict(rec.meta),
                     events={k: np.concatenate([v + o for o in off]) for k, v in rec.events.items()},
                     channel_quantum=dict(rec.channel_quantum))


def _peaks(path, timer: str) -> dict[str, int]:
    """Peak traced bytes each streamed read of the diagnosis adds (all but the angle timer test's algebra)."""
    out = {}
    tracemalloc.start()

    def stage(name, fn):
        tracemalloc.reset_peak()
        base = tracemalloc.get_traced_memory()[0]
        got = fn()
        out[name] = tracemalloc.get_traced_memory()[1] - base
        return got
    try:
        with stage("open", lambda: FileRecord(path)) as f:
            st = StreamedTurn(f)
            rw, _ = stage("windows", lambda: st.windows(timer))
            stage("means", lambda: st.per_window(rw, SPEC.channels, lambda r: indicated(r, SPEC, "mean")[0]))
            tp = stage("edges", lambda: st.edges(None))["time_s"]
            g = st.gyro("gyro_r", 1.0)
            stage("gyro", lambda: (g.integrals(tp), g.sums(tp, 10), g.window(tp[0], tp[3])))
            stage("slip rings", lambda: _slip_rings(st, rw, timer, "gyro_r", 0.01))
            stage("raw tests", lambda: st.raw_tests("gyro_r", 0.01))
        return out
    finally:
        tracemalloc.stop()


@pytest.mark.slow
def test_memory_does_not_grow_with_the_record(timer_record, tmp_path, monkeypatch):
    """Peak traced memory of each streamed read on the record and on it played three times, with the
    caps small (pieces of 4096 rows, subsamples of 1024 values, searches of 1024 distinct values, 256
    per angle bin): nothing record-sized is held, so the peak grows by less than one float64 per row
    of the shorter record (n x 8 bytes; the rows, pulses and windows counted per piece, pulse and step),
    where the loaded record grows by 2 n x 8 bytes x 6 columns. The test can fail: with the percentiles'
    subsample kept as views (each holds its piece), or a window read from the first pulse to the last,
    it grows by 1-3 MB; with the slip-ring residuals pooled, by about 10 MB. About 10 CPU-s under
    tracemalloc: marked slow."""
    from imurig.diagnose import raw_record, slip_ring_stream, turn_record
    from imurig.kernel import h5stream
    for mod, name in ((raw_record, "SUBSAMPLE"), (raw_record, "RANK_LIMIT"), (turn_record, "SUBSAMPLE"),
                      (turn_record, "RANK_LIMIT"), (slip_ring_stream, "LIMIT")):
        monkeypatch.setattr(mod, name, 1024)
    monkeypatch.setattr(slip_ring_stream, "THIN", 256)
    monkeypatch.setattr(h5stream, "CHUNK_ROWS", 4096)
    monkeypatch.setattr(h5stream, "MAX_DISTINCT_DT", 1024)
    monkeypatch.setattr(StreamedTurn, "piece", 4096)
    monkeypatch.setattr(StreamedRaw, "piece", 4096)
    rec, path = timer_record
    big = save_h5(_repeated(rec, 3), tmp_path / "x3.h5")
    timer = rec.meta["timer"]
    small, large = _peaks(path, timer), _peaks(big, timer)
    growth = {k: large[k] - small[k] for k in small}
    assert max(growth.values()) <= rec.n * 8, growth
