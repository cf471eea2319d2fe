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

from imurig.kernel.recording import Recording


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
