"""What the turn-table diagnosis needs of the record as logged, from memory or streamed from a file.

The diagnosis (:func:`imurig.diagnose.turn_table.diagnose_turn_table`) reads the 1 kHz record in a few
ways: the steps' whole-round windows (:func:`imurig.calibration.gyro.round_windows`) and the means of
the channels over them; the index pulse's edges (:func:`imurig.diagnose.pulse_timer.edge_times`); the
table-axis gyro's integrals at the pulses (:func:`imurig.diagnose.pulse_angle.chain_from`); each gyro's
fast residual by table angle in the windows (the slip-ring test); and each gyro's raw-sample tests
(saturation). :class:`InMemoryTurn` takes them from a loaded Recording, as before. :class:`StreamedTurn`
takes them from a :class:`imurig.kernel.filerecord.FileRecord` in memory of one window and a piece of
rows, whatever the record's length, with the same values:

- the windows' means: each window's rows as a one-segment Recording (the same samples, the same
  statistic, so the same bits);
- the pulse's edges: its 1st and 99.9th percentiles (np.percentile's linear interpolation between
  exact order statistics, :class:`imurig.kernel.ranks.RankSearch`) and, in a pass, the two samples of
  each threshold crossing; ``edge_times`` on those samples with the levels given is the whole
  channel's (the crossings alternate, so no other crossing appears between them);
- the gyro's integrals: the running trapezoid sums carried from piece to piece (a sequential sum
  continued, the same bits) and np.interp between the two samples around each pulse;
- the slip-ring test: :mod:`imurig.diagnose.slip_ring_stream`;
- the raw-sample tests: :class:`imurig.diagnose.raw_record.StreamedRaw` without its working record.
"""
from __future__ import annotations

import numpy as np

from imurig.calibration.gyro import round_windows, timer_pulses
from imurig.calibration.stream_filter import PIECE_ROWS
from imurig.diagnose.gyro_samples import GyroSamples
from imurig.diagnose.pulse_timer import edge_times
from imurig.diagnose.raw_record import StreamedRaw
from imurig.diagnose.samples import adc_step, raw_channel_tests
from imurig.diagnose.slip_ring_stream import streamed_slip_ring_test
from imurig.kernel.errors import RecordingError
from imurig.kernel.filerecord import FileRecord
from imurig.kernel.ranks import RankSearch
from imurig.kernel.recording import Recording
from imurig.sensors.effects import for_view
from imurig.sensors.effects.views import TurnSampleView

#: the pulse channel's levels: these percentiles (edge_times)
LEVELS_PERCENT = (1.0, 99.9)
#: values of the pulse channel kept, strided, to bracket its percentiles
SUBSAMPLE = 1 << 16
#: distinct values a percentile's search keeps before it narrows its bracket instead (kernel.ranks)
RANK_LIMIT = 1 << 16


class InMemoryTurn:
    """The turn-table diagnosis' reads of a loaded Recording ``rec`` (module doc)."""

    def __init__(self, rec: Recording):
        self.rec, self.meta, self.segments, self.events = rec, rec.meta, rec.segments, rec.events
        self.channels, self.sample_rate_hz = rec.channels, rec.sample_rate_hz

    @property
    def n_segments(self) -> int:
        return self.rec.n_segments

    def require(self, needed) -> None:
        self.rec.require(needed)

    def windows(self, timer: str):
        return round_windows(self.rec, timer)

    def timer_pulses(self, timer: str) -> np.ndarray:
        return timer_pulses(self.rec, timer)

    def per_window(self, rw: Recording, names, fn) -> np.ndarray:
        """fn(rw): one row per window (``names``: the channels fn reads)."""
        return fn(rw)

    @property
    def dt(self) -> float:
        return float(np.median(np.diff(self.rec.time_s)))

    def edges(self, threshold_V) -> dict:
        return edge_times(self.rec.time_s, self.rec.channels["pulse"], threshold_V)

    def gyro(self, ch: str, sign: float) -> GyroSamples:
        return GyroSamples(self.rec.time_s, sign * self.rec.channels[ch])

    def adc_step(self, ch: str) -> float:
        return adc_step(self.rec, ch)

    def window_samples(self, ch: str, spans):
        """(time, samples) of channel ``ch`` in each span (a, b) of times, rows searchsorted(t, (a, b))."""
        t = self.rec.time_s
        for a, b in spans:
            i0, i1 = np.searchsorted(t, [a, b])
            yield t[i0:i1], self.rec.channels[ch][i0:i1]

    def slip_ring_test(self, view: TurnSampleView, pieces) -> dict:
        """The TurnSampleView effects' tests on the windows' (angle, residual, signal, time), pooled."""
        parts = list(pieces())
        if not parts:
            return {"tested": False}
        cat = [np.concatenate([p[k] for p in parts]) for k in range(4)]
        win = np.concatenate([np.full(p[0].size, i) for i, p in enumerate(parts)])
        view = TurnSampleView(channel=view.channel, angle_rad=cat[0], residual_V=cat[1], alpha=view.alpha,
                              signal_V=cat[2], quantum_V=view.quantum_V, window=win, time_s=cat[3])
        out = {"tested": True}
        for cls in for_view(TurnSampleView.kind):
            out.update(cls().test(view))
        return out

    def raw_tests(self, ch: str, alpha: float) -> dict:
        return raw_channel_tests(self.rec, ch, alpha)


class StreamedTurn:
    """The turn-table diagnosis' reads of a :class:`FileRecord` ``f``, streamed (module doc)."""

    piece = PIECE_ROWS

    def __init__(self, f: FileRecord):
        self.f, self.meta, self.segments, self.events = f, f.meta, f.segments, f.events
        self.channels = dict.fromkeys(f.channel_names)
        self.sample_rate_hz, self.dt = f.sample_rate_hz, f.dt
        self._raw = None
        self._adc = None
        self._tp = np.zeros(0)

    @property
    def n_segments(self) -> int:
        return self.f.n_segments

    def require(self, needed) -> None:
        self.f.require(needed)

    def _skeleton(self, events=None) -> Recording:
        """A Recording of the segments, events and metadata, without samples: what the windows and the
        steps' covariance read (the blocks from ``meta["block_start_s"]``)."""
        f = self.f
        starts = [float(f.read_time(b.start, b.start + 1)[0]) for b in f.blocks()]
        meta = dict(f.meta)
        meta.setdefault("block_start_s", starts)
        return Recording(time_s=np.array(starts), channels={}, units={}, segments=dict(f.segments),
                         segment_units=dict(f.segment_units), meta=meta,
                         events=dict(f.events if events is None else events))

    def timer_pulses(self, timer: str) -> np.ndarray:
        return self._adc_pulses() if timer == "adc" else timer_pulses(self._skeleton(), timer)

    def windows(self, timer: str):
        if timer != "adc":
            return round_windows(self._skeleton(), timer)
        key = "_streamed_adc"                 # the ADC's edges as a timer's events of the skeleton
        try:
            return round_windows(self._skeleton({**self.f.events, "pulse_" + key: self._adc_pulses()}), key)
        except RecordingError as e:
            raise RecordingError(str(e).replace(key, "adc")) from None

    def _adc_pulses(self) -> np.ndarray:
        """:func:`imurig.calibration.gyro.pulse_edges` of the 'pulse' channel, streamed."""
        if self._adc is None:
            f = self.f
            if "pulse" not in self.channels:
                raise RecordingError("no 'pulse' channel: record the table's index pulse on an ADC channel "
                                     "(CSV column 'pulse_V'), or use a timer's events")
            thr = f.meta.get("pulse_threshold_V")
            if thr is None:
                thr = 0.5 * max(float(np.max(f.read("pulse", a, b))) for a, b in f.row_pieces(self.piece))
            gaps = {b.start for b in f.blocks()[1:]}
            rises = [i for i, _ in self._crossings(thr) if i + 1 not in gaps and _ == "rise"]
            self._adc = np.array([float(f.read_time(i + 1, i + 2)[0]) for i in rises])
        return self._adc

    def _crossings(self, thr: float):
        """(i, 'rise' | 'fall') of each crossing between samples i and i + 1 (the rows as one array), in order."""
        last = None
        for a, b in self.f.row_pieces(self.piece):
            x = self.f.read("pulse", a, b)
            xx, off = (x, a) if last is None else (np.concatenate(([last], x)), a - 1)
            above = xx >= thr
            r = np.flatnonzero(~above[:-1] & above[1:])
            fl = np.flatnonzero(above[:-1] & ~above[1:])
            for i, kind in sorted([(int(i) + off, "rise") for i in r] + [(int(i) + off, "fall") for i in fl]):
                yield i, kind
            last = x[-1]

    def per_window(self, rw: Recording, names, fn) -> np.ndarray:
        """fn of each window's rows (channels ``names``) as a one-segment Recording, stacked."""
        f = self.f
        seg = rw.segments
        k = len(seg["start_s"])
        rows = f.rows_at(np.concatenate([seg["start_s"], seg["stop_s"]]))
        out = []
        for i in range(k):
            i0, i1 = int(rows[i]), int(rows[k + i])
            one = Recording(time_s=f.read_time(i0, i1), channels={c: f.read(c, i0, i1) for c in names},
                            units={c: f.units[c] for c in names}, segments={c: v[i:i + 1] for c, v in seg.items()},
                            segment_units=dict(rw.segment_units), meta=rw.meta,
                            channel_quantum={c: q for c, q in f.channel_quantum.items() if c in names})
            out.append(fn(one)[0])
        return np.array(out)

    def edges(self, threshold_V) -> dict:
        lo, hi = self._percentiles("pulse", LEVELS_PERCENT)
        thr = 0.5 * (lo + hi) if threshold_V is None else threshold_V
        idx = [i for i, _ in self._crossings(thr)]
        rows = np.array([(i, i + 1) for i in idx], dtype=np.int64).reshape(-1)
        t = np.array([self.f.read_time(int(i), int(i) + 1)[0] for i in rows])
        x = np.array([self.f.read("pulse", int(i), int(i) + 1)[0] for i in rows])
        out = edge_times(t, x, thr, levels=(lo, hi))
        self._tp = np.asarray(out["time_s"], float)
        return out

    def _percentiles(self, ch: str, percents) -> tuple[float, ...]:
        """np.percentile(channel, percents) (linear), from exact order statistics."""
        f, n = self.f, self.f.n
        q = np.true_divide(np.asarray(percents, float), 100)
        virtual = (n - 1) * q
        below = np.floor(virtual).astype(np.int64)
        above = np.minimum(below + 1, n - 1)
        stride = max(1, n // SUBSAMPLE)
        # copies: a strided view would keep its whole piece
        sub = np.concatenate([f.read(ch, a, b)[(-a) % stride::stride].copy() for a, b in f.row_pieces(self.piece)])
        # a search per percentile: one bracket around both would keep every value between them
        todo = [RankSearch(n, (i, j), sub, limit=RANK_LIMIT) for i, j in zip(below, above)]
        done = list(todo)
        while todo:
            for a, b in f.row_pieces(self.piece):
                x = f.read(ch, a, b)
                for s in todo:
                    s.feed(x)
            todo = [s for s in todo if not s.end()]
        val = {r: v for s in done for r, v in zip(s.ranks, s.result)}
        lo_v, hi_v = np.array([val[int(i)] for i in below]), np.array([val[int(i)] for i in above])
        gamma = virtual - below
        d = hi_v - lo_v                               # numpy's _lerp
        out = np.where(gamma >= 0.5, hi_v - d * (1 - gamma), lo_v + d * gamma)
        return tuple(float(v) for v in out)

    def gyro(self, ch: str, sign: float) -> "StreamedGyro":
        """The gyro's reads, the rows of the segments' ends and of the last edges found in one pass (the
        windows :func:`imurig.diagnose.pulse_angle.chain_from` asks for)."""
        g = StreamedGyro(self.f, ch, sign, self.piece)
        seg = self.segments
        g.rows(np.concatenate([seg.get("start_s", np.zeros(0)), seg.get("stop_s", np.zeros(0)), self._tp]))
        return g

    def _stats(self) -> StreamedRaw:
        if self._raw is None:
            self._raw = StreamedRaw(self.f, triad=tuple(c for c in self.f.channel_names if c.startswith("gyro_")),
                                    working=False)
        return self._raw

    def adc_step(self, ch: str) -> float:
        return self._stats().adc_step(ch)

    def window_samples(self, ch: str, spans):
        spans = list(spans)
        rows = self.f.rows_at(np.array(spans, float).reshape(-1)) if spans else np.zeros(0, np.int64)
        for i in range(len(spans)):
            i0, i1 = int(rows[2 * i]), int(rows[2 * i + 1])
            yield self.f.read_time(i0, i1), self.f.read(ch, i0, i1)

    def slip_ring_test(self, view: TurnSampleView, pieces) -> dict:
        effects = tuple(for_view(TurnSampleView.kind))
        if len(effects) != 1:
            # a guard for the library's next angle-sample effect, not a user error (as StreamedRaw's)
            raise RuntimeError("an angle-sample effect other than the slip rings is in the library; the streamed "
                               "turn record (StreamedTurn.slip_ring_test) knows the slip-ring test only: add its passes")
        return streamed_slip_ring_test(effects[0](), view, pieces)

    def raw_tests(self, ch: str, alpha: float) -> dict:
        return self._stats().raw_tests(ch, alpha)


class StreamedGyro:
    """:class:`imurig.diagnose.gyro_samples.GyroSamples` of a file's channel ``ch`` times ``sign``, in row pieces."""

    def __init__(self, f: FileRecord, ch: str, sign: float, piece: int):
        self.f, self.ch, self.sign, self.piece, self.dt = f, ch, float(sign), piece, f.dt
        self._rows: dict[float, int] = {}

    def _u(self, a: int, b: int) -> np.ndarray:
        return self.sign * self.f.read(self.ch, a, b)

    def rows(self, times) -> None:
        """Find the rows of ``times`` in one pass (the windows asked for later)."""
        times = np.asarray(times, float)
        self._rows.update(zip(times.tolist(), self.f.rows_at(times).tolist()))

    def _row(self, t: float) -> int:
        if t not in self._rows:
            self.rows([t])
        return self._rows[t]

    def window(self, a: float, b: float) -> np.ndarray:
        i0, i1 = self._row(float(a)), self._row(float(b))
        return self._u(i0, i1) if i1 > i0 else np.zeros(0)

    def integrals(self, tp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        tp = np.asarray(tp, float)
        out = np.full((2, tp.size), np.nan)
        carry, prev = np.zeros(2), None
        for a, b in self.f.row_pieces(self.piece):
            t, u = self.f.read_time(a, b), self._u(a, b)
            if prev is None:
                d1 = 0.5 * (u[1:] + u[:-1]) * np.diff(t)
                d2 = 0.5 * (u[1:] ** 2 + u[:-1] ** 2) * np.diff(t)
                tl = t
            else:
                tl = np.concatenate(([prev[0]], t))
                ul = np.concatenate(([prev[1]], u))
                d1 = 0.5 * (ul[1:] + ul[:-1]) * np.diff(tl)
                d2 = 0.5 * (ul[1:] ** 2 + ul[:-1] ** 2) * np.diff(tl)
            G1 = np.cumsum(np.concatenate(([carry[0]], d1)))      # G at tl: a sequential sum, continued
            G2 = np.cumsum(np.concatenate(([carry[1]], d2)))
            m = (tp >= tl[0]) & (tp <= tl[-1]) & np.isnan(out[0])
            if m.any():
                out[0, m], out[1, m] = np.interp(tp[m], tl, G1), np.interp(tp[m], tl, G2)
            carry = np.array([G1[-1], G2[-1]])
            prev = (t[-1], u[-1])
        first, last = float(self.f.read_time(0, 1)[0]), prev[0]
        out[:, tp < first] = 0.0
        out[0, tp > last], out[1, tp > last] = carry[0], carry[1]
        return out[0], out[1]

    def sums(self, tp: np.ndarray, h: int) -> np.ndarray:
        n = self.f.n
        idx = np.clip(self.f.rows_at(tp), h, n - h)
        want = np.concatenate([idx + h, idx - h])
        order = np.argsort(want, kind="stable")
        got = np.empty(want.size)
        carry, j = 0.0, 0
        for a, b in self.f.row_pieces(self.piece):
            cs = np.cumsum(np.concatenate(([carry], self._u(a, b))))   # cs[k] = sum of u[0 .. a + k - 1]
            while j < want.size and want[order[j]] <= b:
                got[order[j]] = cs[want[order[j]] - a]
                j += 1
            carry = cs[-1]
        return got[:idx.size] - got[idx.size:]


def as_turn(rec) -> InMemoryTurn | StreamedTurn:
    """The turn-table diagnosis' reads of a Recording (in memory) or a FileRecord (streamed); reads are kept."""
    if isinstance(rec, (InMemoryTurn, StreamedTurn)):
        return rec
    return StreamedTurn(rec) if isinstance(rec, FileRecord) else InMemoryTurn(rec)
