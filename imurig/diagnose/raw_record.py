"""What the tilt-table diagnosis needs of the record as logged, from memory or streamed from a file.

The diagnosis works on the 100 Hz working record (:func:`imurig.diagnose.samples.working_record`)
and takes a few statistics of the raw channels: each channel's ADC step, lowest and highest value
(a converter's rail), each position's mean, sd and code histogram (the position noise model), the
flat-top test of :mod:`imurig.sensors.effects.saturation` and, for a clip it finds, the clipped
positions' samples. :class:`InMemoryRaw` takes them from a loaded Recording (the functions of
:mod:`imurig.diagnose.samples` and :mod:`imurig.diagnose.position_noise`, as before);
:class:`StreamedRaw` from a :class:`imurig.kernel.filerecord.FileRecord`, in memory of the working
record, a piece of rows and one position, with the same values:

- one pass over the rows builds the working record (the block's zero-phase low-pass from row
  pieces, :func:`imurig.calibration.stream_filter.filtfilt_decimated`, equal to the whole-block
  filter to rounding) and takes the extremes, the distinct values of a channel whose step the
  metadata do not give, and a strided subsample of the accelerometers' second differences;
- one pass over the positions' rows takes their means, sds and code histograms (each position's
  samples as one array: the same numbers to the bit);
- the flat-top test's noise needs the median of the second differences, the median of their
  absolute deviation from it and their mean square inside the cut: exact order statistics in a
  pass each (:class:`imurig.kernel.ranks.RankSearch`) and a pass for the sum; the runs at the
  extremes are taken in the first of them.
The working record carries no truth signals (the diagnosis uses none).
"""
from __future__ import annotations

import numpy as np

from imurig.calibration.preprocess import filter_design
from imurig.calibration.stream_filter import PIECE_ROWS, filtfilt_decimated
from imurig.diagnose.position_noise import code_histogram, dither_sd, dither_sd_from
from imurig.diagnose.samples import adc_range, adc_step, rail_positions, raw_channel_tests, working_record
from imurig.kernel.filerecord import FileRecord, check_memory
from imurig.kernel.ranks import LIMIT, median_search
from imurig.kernel.recording import Recording
from imurig.sensors.effects import for_view
from imurig.sensors.effects.adc_quantisation import step_of
from imurig.sensors.effects.saturation import (Saturation, _runs, flat_tolerance, flat_top_result, noise_cut,
                                               noise_from_moments)
from imurig.sensors.effects.views import RawChannelView

#: distinct values of a channel kept to estimate its step; beyond, the channel is read whole (after a memory check)
MAX_DISTINCT = 1 << 21
#: the second differences' subsample that brackets their order statistics
SUBSAMPLE = 1 << 17
#: distinct values an order-statistic search keeps before it narrows its bracket instead (kernel.ranks)
RANK_LIMIT = LIMIT


class InMemoryRaw:
    """The raw statistics of a loaded Recording ``rec`` (module doc)."""

    def __init__(self, rec: Recording):
        self.rec, self.meta, self.units, self.channels = rec, rec.meta, rec.units, rec.channels
        self.n, self.sample_rate_hz = rec.n, rec.sample_rate_hz

    def working(self) -> Recording:
        rec100 = working_record(self.rec)
        self.decimated = rec100 is not self.rec          # the working record is not the record as logged
        return rec100

    def adc_step(self, ch: str) -> float:
        return adc_step(self.rec, ch)

    def at_rail(self, ch: str, medians: np.ndarray) -> np.ndarray:
        x = np.asarray(self.rec.channels[ch], float)
        if x.size == 0:
            return np.zeros(np.shape(medians), bool)
        return rail_positions(float(x.min()), float(x.max()), self.adc_step(ch), medians)

    def segment_moments(self, ch: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Each position's (mean, sd with ddof 1 or 0 below two samples, samples)."""
        x = np.asarray(self.rec.channels[ch], float)
        sl = self.rec.segment_slices()
        return (np.array([x[s].mean() for s in sl]),
                np.array([x[s].std(ddof=1) if s.stop - s.start > 1 else 0.0 for s in sl]),
                np.array([s.stop - s.start for s in sl]))

    def dither(self, ch: str, q: float) -> float | None:
        return dither_sd(np.asarray(self.rec.channels[ch], float), self.rec.segment_slices(), q)

    def segment_samples(self, ch: str, i: int) -> np.ndarray:
        return np.asarray(self.rec.channels[ch], float)[self.rec.segment_slices()[i]]

    def raw_tests(self, ch: str, alpha: float) -> dict:
        return raw_channel_tests(self.rec, ch, alpha)

    def full(self) -> Recording:
        return self.rec


class StreamedRaw:
    """The raw statistics of a :class:`FileRecord` ``f``, streamed (module doc). ``triad``: the
    channels that get the position and flat-top statistics."""

    #: rows read at a time
    piece = PIECE_ROWS

    def __init__(self, f: FileRecord, triad=("acc_x", "acc_y", "acc_z"), working: bool = True):
        self.f, self.meta, self.units = f, f.meta, f.units
        self._with_working = working            # False: the statistics' pass reads the triad only (no working record)
        self.channels = dict.fromkeys(f.channel_names)          # names only, in the file's order
        self.n, self.sample_rate_hz = f.n, f.sample_rate_hz
        self.triad = [c for c in triad if c in self.channels]
        self._rec100 = None
        self._moments, self._tests, self._steps = {}, {}, {}

    # ------------------------------------------------------------------ the pass over the rows
    def working(self) -> Recording:
        if self._rec100 is None:
            self._main_pass()
        return self._rec100

    def _begin_stats(self, names) -> None:
        f = self.f
        self._need_values = [c for c in names if step_of(f.meta, c, None, f.channel_quantum) == 0.0]
        self._distinct = {c: np.zeros(0) for c in self._need_values}
        self._ext = {c: (np.inf, -np.inf) for c in names}
        self._sub = {c: [] for c in self.triad}
        self._stride = max(1, (self.n - 2) // SUBSAMPLE)
        self._tail = {c: np.zeros(0) for c in self.triad}
        self._next = 0

    def _end_stats(self, names) -> None:
        self._steps = {c: None if c in self._distinct and self._distinct[c] is None else   # too many: adc_step
                       step_of(self.f.meta, c, self._distinct.get(c), self.f.channel_quantum) for c in names}

    def _stats(self) -> None:
        """The rows' statistics (extremes, steps, the second differences' subsample): in the working
        record's pass, or (``working=False``) in a pass over the triad's rows alone."""
        if self._steps:
            return
        if self._with_working:
            self.working()
            return
        self._begin_stats(self.triad)
        for a, b in self.f.row_pieces(self.piece):
            self._feed({c: self.f.read(c, a, b) for c in self.triad}, a)
        self._end_stats(self.triad)

    def _main_pass(self) -> None:
        f, names = self.f, self.f.channel_names
        fs = self.sample_rate_hz
        k = int(np.floor(fs / 100.0 + 1e-9))           # as working_record
        rows = sum(len(range(b.start, b.stop, max(k, 1))) for b in f.blocks())
        check_memory(rows, len(names) + 1, f"{f.source} (the working record)")
        setpoints = set(f.meta.get("setpoints", []))
        filtered = [c for c in names if c not in setpoints] if k >= 2 else []
        self._begin_stats(names)
        time_s = np.empty(rows)
        raw = {c: np.empty(rows) for c in names if c not in filtered}      # decimated as logged
        low = np.empty((len(filtered), rows))        # low-passed, then decimated (one contiguous row per channel)

        def take(a: int, b: int, cols: dict, block: slice, off: int) -> None:
            """Rows [a, b) of every channel: their statistics (once per row, in order) and the decimated samples."""
            if a <= self._next < b:
                self._feed({c: x[self._next - a:] for c, x in cols.items()}, self._next)
                self._next = b
            r = np.arange(a + (-(a - block.start)) % max(k, 1), b, max(k, 1))
            j = off + (r - block.start) // max(k, 1)
            time_s[j] = f.read_time(a, b)[r - a]
            for c, dst in raw.items():
                dst[j] = cols[c][r - a]

        off = 0
        for blk in f.blocks():
            m = blk.stop - blk.start

            def read(a, b, blk=blk, off=off):
                cols = {c: f.read(c, blk.start + a, blk.start + b) for c in names}
                take(blk.start + a, blk.start + b, cols, blk, off)
                return np.stack([cols[c] for c in filtered], axis=1) if filtered else np.zeros((b - a, 0))

            if k >= 2:
                _, sos, _ = filter_design(fs, fs / k, 50.0)
                filtfilt_decimated(read, m, sos, k, min(3 * (2 * len(sos) + 1), m - 1), piece=self.piece,
                                   out=low[:, off:off + len(range(0, m, k))].T)
            else:
                for a, b in ((a, min(a + self.piece, m)) for a in range(0, m, self.piece)):
                    read(a, b)
            off += len(range(0, m, max(k, 1)))
        channels = {c: low[filtered.index(c)] if c in filtered else raw[c] for c in names}
        self._end_stats(names)
        meta = f.meta
        if k >= 2:                                   # as preprocess._decimated: the rate reached and the log
            _, _, log = filter_design(fs, fs / k, 50.0)
            meta = {**f.meta, "sample_rate_hz": log["to_hz"],
                    "preprocessing": list(f.meta.get("preprocessing", [])) + [log]}
        rec = Recording(time_s=time_s, channels=channels, units=dict(f.units), segments=dict(f.segments),
                        segment_units=dict(f.segment_units), meta=meta, truth=f.truth,
                        channel_quantum=dict(f.channel_quantum) if k < 2 else {},
                        events=dict(f.events) if k < 2 else {})
        self._rec100, self.decimated = rec, k >= 2

    def _feed(self, cols: dict, a: int) -> None:
        for c, x in cols.items():
            if x.size:
                lo, hi = self._ext[c]
                self._ext[c] = (min(lo, float(x.min())), max(hi, float(x.max())))
        for c in self._need_values:
            if self._distinct[c] is not None:
                u = np.union1d(self._distinct[c], cols[c])
                self._distinct[c] = u if u.size <= MAX_DISTINCT else None
        for c in self.triad:
            xx = np.concatenate((self._tail[c], cols[c]))
            d2 = np.diff(xx, 2)
            j0 = a + cols[c].size - d2.size                    # index of d2's first value (d2[i] ends at row i + 2)
            self._sub[c].append(d2[(-j0) % self._stride::self._stride].copy())     # a copy: a view keeps the piece
            self._tail[c] = xx[-2:]

    def adc_step(self, ch: str) -> float:
        self._stats()
        if self._steps.get(ch) is None and ch in self._distinct:      # too many values kept: the whole channel
            check_memory(self.n, 2, f"{self.f.source} (channel '{ch}' whole, for its ADC step)")
            self._steps[ch] = step_of(self.meta, ch, self.f.read(ch, 0, self.n), self.f.channel_quantum)
        return self._steps[ch]

    def at_rail(self, ch: str, medians: np.ndarray) -> np.ndarray:
        self._stats()
        lo, hi = self._ext[ch]
        return rail_positions(lo, hi, self.adc_step(ch), medians)

    # ------------------------------------------------------------------ the positions' rows
    def segment_moments(self, ch: str):
        if ch not in self._moments:
            self._segment_pass()
        return self._moments[ch][:3]

    def dither(self, ch: str, q: float) -> float | None:
        if ch not in self._moments:
            self._segment_pass()
        return dither_sd_from(self._moments[ch][3], q)

    def _segment_pass(self) -> None:
        out = {c: ([], [], [], []) for c in self.triad}
        qs = {c: self.adc_step(c) for c in self.triad}
        for s in self.f.segment_slices():
            for c in self.triad:
                x = self.f.read(c, s.start, s.stop) if s.stop > s.start else np.zeros(0)
                mean, sd, n, hist = out[c]
                mean.append(x.mean() if x.size else np.nan)
                sd.append(x.std(ddof=1) if s.stop - s.start > 1 else 0.0)
                n.append(s.stop - s.start)
                hist.append(code_histogram(x / qs[c]) if qs[c] > 0 else None)
        self._moments = {c: (np.array(v[0]), np.array(v[1]), np.array(v[2]), v[3]) for c, v in out.items()}

    def segment_samples(self, ch: str, i: int) -> np.ndarray:
        s = self.f.segment_slices()[i]
        return self.f.read(ch, s.start, s.stop)

    # ------------------------------------------------------------------ the flat-top test
    def raw_tests(self, ch: str, alpha: float) -> dict:
        if ch not in self._tests:
            self._flat_top_passes(alpha)
        q, res = self._tests[ch]
        out = {"adc_step_V": q}
        res = dict(res)
        finding = res.pop("finding", None)
        out.update(res)
        if finding is not None:
            out[Saturation.finding_key] = finding
        return out

    def _d2_pass(self, fn) -> None:
        """fn(channel, x piece, its first row, d2 piece) over all rows of the triad."""
        tail = {c: np.zeros(0) for c in self.triad}
        for a, b in self.f.row_pieces(self.piece):
            for c in self.triad:
                x = self.f.read(c, a, b)
                xx = np.concatenate((tail[c], x))
                fn(c, x, a, np.diff(xx, 2))
                tail[c] = xx[-2:]

    def _flat_top_passes(self, alpha: float) -> None:
        if tuple(for_view(RawChannelView.kind)) != (Saturation,):
            # a guard for the library's next raw-sample effect, not a user error: the streamed passes below
            # are the saturation test's, so another effect needs its own passes here (or the whole-record path)
            raise RuntimeError("a raw-sample effect other than saturation is in the library; the streamed raw "
                               "tests (StreamedRaw._flat_top_passes) know the saturation test only: add its passes")
        self._stats()
        m = self.n - 2
        cs = [c for c in self.triad if self.n >= 10]
        q = {c: self.adc_step(c) for c in self.triad}
        ext = {c: (self._ext[c][1], self._ext[c][0]) for c in cs}          # (max, min), as the test
        runs = {c: {L: _RunTracker() for L in ext[c]} for c in cs}
        sub = {c: np.concatenate(self._sub[c]) for c in cs}
        med = {c: median_search(m, sub[c], limit=RANK_LIMIT) for c in cs}

        def first(c, x, a):
            for L, tr in runs[c].items():
                tr.feed(np.abs(x - L) <= flat_tolerance(L, q[c]), a)
        self._search(med, lambda c, d2: d2, first)
        for c in cs:
            for tr in runs[c].values():
                tr.close()
        centre = {c: med[c].median() for c in cs}
        mad = {c: median_search(m, np.abs(sub[c] - centre[c]), limit=RANK_LIMIT) for c in cs}
        self._search(mad, lambda c, d2: np.abs(d2 - centre[c]))
        cut = {c: noise_cut(mad[c].median(), q[c]) for c in cs}
        sums = {c: [0.0, 0] for c in cs}

        def moments(c, x, a, d2):
            inner = d2[np.abs(d2 - centre[c]) <= cut[c]] if cut[c] > 0 else d2
            sums[c][0] += float(np.sum((inner - centre[c]) ** 2))
            sums[c][1] += inner.size
        self._d2_pass(lambda c, x, a, d2: moments(c, x, a, d2) if c in cs else None)
        rng_V = adc_range(self)                     # from the metadata
        for c in self.triad:
            if c not in cs:
                self._tests[c] = (q[c], {})
                continue
            s, sigma = noise_from_moments(sums[c][0], sums[c][1], q[c])
            view = RawChannelView(channel=c, samples=np.zeros(0), time_s=np.zeros(0), quantum_V=q[c],
                                  range_V=rng_V, alpha=alpha)
            self._tests[c] = (q[c], flat_top_result(view, self.n, s, sigma, ext[c],
                                                    {L: tr.result() for L, tr in runs[c].items()},
                                                    lambda i: float(self.f.read_time(i, i + 1)[0])))

    def _search(self, searches: dict, value_of, first=None) -> None:
        """Passes until every RankSearch in ``searches`` has its values: each pass feeds the unfinished
        ones value_of(channel, d2 piece); ``first(channel, x piece, its first row)`` runs in the first pass."""
        todo, once = set(searches), first

        def fn(c, x, a, d2):
            if once is not None:
                once(c, x, a)
            if c in todo:
                searches[c].feed(value_of(c, d2))
        while todo:
            self._d2_pass(lambda c, x, a, d2: fn(c, x, a, d2) if c in searches else None)
            todo, once = {c for c in todo if not searches[c].end()}, None

    def full(self) -> Recording:
        return self.f.load()


class _RunTracker:
    """Runs of True in a mask that arrives in pieces: (starts, lengths) of those of >= 2 samples."""

    def __init__(self):
        self.starts, self.lengths, self.open = [], [], None

    def feed(self, mask: np.ndarray, a: int) -> None:
        st, ln = _runs(mask)
        st = st + a
        if self.open is not None:
            if st.size and st[0] == a:
                self.open[1] += int(ln[0])
                st, ln = st[1:], ln[1:]
                if not st.size and self.open[0] + self.open[1] == a + mask.size:
                    return
            self._close_open()
        if st.size and st[-1] + ln[-1] == a + mask.size:
            self.open = [int(st[-1]), int(ln[-1])]
            st, ln = st[:-1], ln[:-1]
        keep = ln >= 2
        self.starts += st[keep].tolist()
        self.lengths += ln[keep].tolist()

    def _close_open(self) -> None:
        if self.open is not None and self.open[1] >= 2:
            self.starts.append(self.open[0])
            self.lengths.append(self.open[1])
        self.open = None

    def close(self) -> None:
        self._close_open()

    def result(self) -> tuple[np.ndarray, np.ndarray]:
        return np.array(self.starts, dtype=np.int64), np.array(self.lengths, dtype=np.int64)


def as_raw(rec) -> InMemoryRaw | StreamedRaw:
    """The raw statistics of a Recording (in memory) or a FileRecord (streamed)."""
    return StreamedRaw(rec) if isinstance(rec, FileRecord) else InMemoryRaw(rec)
