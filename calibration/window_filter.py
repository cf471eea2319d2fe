"""Low-pass and downsample only where a recording is analysed: the segments' acquisition windows.

:func:`imurig.calibration.preprocess.lowpass_downsample` with ``windows_only=True`` lands here.
Each window [start_s, stop_s), widened by ``pad_s`` on both sides (within its block), is filtered
on its own (its signals as the columns of one array) with the same zero-phase Butterworth
(``sosfiltfilt``) as the whole-block filter, and decimated on the block's grid (every k-th sample
from the block start). The filter's impulse response decays by e^-1 in ~ 1 / (2 pi f_c sin(pi / 2 order)) (10 ms at
50 Hz, order 5), so with a pad of 1 s the windowed result equals the whole-block one to rounding.
Outside the windows the samples are decimated without filtering (what a display needs). Truth
signals that are constant over a padded window (the table at rest) are taken as they are
(a low-pass leaves a constant unchanged). Memory: a few copies of one padded window's signals.
"""
from __future__ import annotations

import numpy as np
from scipy import signal

from imurig.kernel.recording import Recording, TimeFrame


def _windows(rec: Recording, block: slice, pad: int) -> list[tuple[int, int, int, int]]:
    """(filter start, filter stop, window start, window stop) sample indices of the segment windows
    inside ``block``."""
    out = []
    for s in rec.segment_slices():
        if s.start >= block.start and s.stop <= block.stop and s.stop > s.start:
            out.append((max(block.start, s.start - pad), min(block.stop, s.stop + pad), s.start, s.stop))
    return out


def _filter_into(dst: dict, src: dict, names: list, spans, sos, k: int, block: slice, offset: int,
                 skip_constant: bool) -> None:
    """Filter the signals ``names`` of ``src`` over each padded span, all at once as columns, and
    write their block-grid samples inside the window into ``dst`` (the decimated signals; ``offset``:
    their index of the block's first sample). With ``skip_constant`` a signal constant over the span
    keeps its raw (unchanged) samples."""
    for lo, hi, a, b in spans:
        first = a + (block.start - a) % k  # first grid sample at or after the window start
        if first >= b:
            continue
        cols = [n for n in names if not (skip_constant and np.all(src[n][lo:hi] == src[n][lo]))]
        if not cols:
            continue
        seg = np.stack([src[n][lo:hi] for n in cols], axis=1)
        padlen = min(3 * (2 * len(sos) + 1), seg.shape[0] - 1)
        y = signal.sosfiltfilt(sos, seg, axis=0, padlen=padlen)[first - lo:b - lo:k]
        i0 = offset + (first - block.start) // k
        for j, n in enumerate(cols):
            dst[n][i0:i0 + y.shape[0]] = y[:, j]


def lowpass_windows(rec: Recording, sos: np.ndarray, k: int, filtered: list, filtered_truth: list,
                    pad_s: float = 1.0) -> tuple[np.ndarray, dict, dict]:
    """Decimated indices (m,), channels and truth signals {name: (m,)}: every k-th sample of each
    block; the names in ``filtered`` (channels) and ``filtered_truth`` (truth signals) low-passed
    within the padded segment windows, everything else taken as sampled."""
    fs = rec.sample_rate_hz
    pad = int(round(pad_s * fs))
    blocks = rec.blocks()
    idx = np.concatenate([np.arange(b.start, b.stop, k) for b in blocks])
    offsets = np.cumsum([0] + [len(range(b.start, b.stop, k)) for b in blocks])
    chans = {n: rec.channels[n][idx] for n in rec.channels}
    truth = {n: rec.truth_signals[n][idx] for n in rec.truth_signals}
    for b, off in zip(blocks, offsets):
        spans = _windows(rec, b, pad)
        _filter_into(chans, rec.channels, filtered, spans, sos, k, b, off, skip_constant=False)
        _filter_into(truth, rec.truth_signals, filtered_truth, spans, sos, k, b, off, skip_constant=True)
    return idx, chans, truth


class WindowTap:
    """:func:`lowpass_windows` on a record that arrives in row pieces (a sink of
    :func:`imurig.sensors.stream.measure_stream`): the same decimated samples and the same filtered
    windows, in memory of the decimated record and one padded window.

    ``frame``: a Recording, or a :class:`imurig.kernel.recording.TimeFrame`, with the record's ``time_s`` and
    ``segments`` (only its blocks, sample rate and segment windows are used, and it may be dropped after
    construction); ``channels`` /
    ``truth``: the names in the order the decimated record lists them; ``filtered`` /
    ``filtered_truth``: those low-passed in the windows (truth constant over a padded window is kept
    as it is); ``quantum``: channels that arrive as converter codes, name -> volts per code."""

    def __init__(self, frame: Recording | TimeFrame, sos: np.ndarray, k: int, channels: list, filtered: list, truth: list,
                 filtered_truth: list, quantum: dict, pad_s: float = 1.0):
        self.sos, self.k, self.quantum = sos, k, dict(quantum)
        self.filtered, self.filtered_truth = list(filtered), list(filtered_truth)
        pad = int(round(pad_s * frame.sample_rate_hz))
        blocks = frame.blocks()
        self.idx = np.concatenate([np.arange(b.start, b.stop, k) for b in blocks])
        offsets = np.cumsum([0] + [len(range(b.start, b.stop, k)) for b in blocks])
        self.spans = [(lo, hi, a, b, blk.start, off) for blk, off in zip(blocks, offsets)
                      for lo, hi, a, b in _windows(frame, blk, pad)]
        self.spans.sort(key=lambda s: s[0])
        self._next_span, self._open = 0, {}
        m = self.idx.size
        self.time_s = np.empty(m)
        self.channels = {n: np.empty(m) for n in channels}
        self.truth = {n: np.empty(m) for n in truth}

    def _decode(self, name: str, x: np.ndarray) -> np.ndarray:
        q = self.quantum.get(name)
        return x.astype(np.float64) * q if q is not None else x

    def rows(self, a: int, b: int, time_s, channels: dict, codes: dict, truth: dict) -> None:
        """Take the samples [a, b) (set-point ``channels``, converter ``codes``, ``truth`` signals)."""
        src = {**channels, **codes}
        j0, j1 = np.searchsorted(self.idx, (a, b))
        r = self.idx[j0:j1] - a
        self.time_s[j0:j1] = time_s[r]
        for n, dst in self.channels.items():
            dst[j0:j1] = self._decode(n, src[n][r])
        for n, dst in self.truth.items():
            dst[j0:j1] = truth[n][r]
        while self._next_span < len(self.spans) and self.spans[self._next_span][0] < b:
            self._open[self._next_span] = ({n: [] for n in self.filtered}, {n: [] for n in self.filtered_truth})
            self._next_span += 1
        for i in sorted(self._open):
            lo, hi = self.spans[i][:2]
            s, e = max(lo, a), min(hi, b)
            pc, pt = self._open[i]
            if s < e:
                for n in pc:
                    pc[n].append(self._decode(n, src[n][s - a:e - a]))
                for n in pt:
                    pt[n].append(truth[n][s - a:e - a])
            if hi <= b:
                self._filter(self.spans[i], pc, self.channels, False)
                self._filter(self.spans[i], pt, self.truth, True)
                del self._open[i]

    def _filter(self, span, pieces: dict, dst: dict, skip_constant: bool) -> None:
        """One padded window's signals filtered together (:func:`_filter_into`)."""
        lo, hi, a, b, start, offset = span
        k = self.k
        first = a + (start - a) % k
        if first >= b:
            return
        sig = {n: np.concatenate(p) for n, p in pieces.items()}
        cols = [n for n in sig if not (skip_constant and np.all(sig[n] == sig[n][0]))]
        if not cols:
            return
        seg = np.stack([sig[n] for n in cols], axis=1)
        padlen = min(3 * (2 * len(self.sos) + 1), seg.shape[0] - 1)
        y = signal.sosfiltfilt(self.sos, seg, axis=0, padlen=padlen)[first - lo:b - lo:k]
        i0 = offset + (first - start) // k
        for j, n in enumerate(cols):
            dst[n][i0:i0 + y.shape[0]] = y[:, j]
