"""The zero-phase low-pass of :func:`imurig.calibration.preprocess.lowpass_downsample` over a block
that is read in row pieces (from a file), in memory of the decimated output and a few pieces.

The whole-block filter is scipy's ``sosfiltfilt(sos, x, axis=0, padlen=p)[::k]``:

    e = [2 x_0 - x_p..x_1,  x,  2 x_{n-1} - x_{n-2}..x_{n-1-p}]        (odd extension, p rows each side)
    f = sosfilt(sos, e, zi = z x e_0)                                   (forward, z = sosfilt_zi(sos))
    y = reverse(sosfilt(sos, reverse(f), zi = z x f_last))[p:-p]        (backward)

Here the forward pass runs piece by piece with its state carried from one piece to the next: the
same recursion in the same order, so f is the same to the bit. The backward pass needs f from the
block's end; it is run over each finished stretch of f plus ``overlap`` further samples, started
from the steady state z x f at the stretch's far end instead of the true state there. The start's
error decays as r^j after j samples, r the largest pole radius of the filter, so with an overlap
of L = log(eps^2) / log(r) samples (:func:`settle_length`; 740 samples for the seed's 5th-order
50 Hz Butterworth at 1 kHz, r = 0.905) the kept outputs equal the whole-block filter's to rounding.
The last stretch starts from the true end state: its outputs are the same to the bit.
"""
from __future__ import annotations

from typing import Callable

import numpy as np
from scipy import signal

#: rows read at a time
PIECE_ROWS = 1 << 16


def settle_length(sos: np.ndarray, tol: float = np.finfo(float).eps ** 2) -> int:
    """Samples after which a start error of the filter ``sos`` has decayed below ``tol`` (relative):
    log(tol) / log(r), r the largest pole radius (at least 64 samples)."""
    r = max(float(np.max(np.abs(np.roots(s[3:])))) if np.any(s[4:]) else 0.0 for s in np.asarray(sos))
    if r <= 0.0:
        return 64
    if r >= 1.0:
        raise ValueError("the filter is not stable (a pole on or outside the unit circle)")
    return max(64, int(np.ceil(np.log(tol) / np.log(r))))


def filtfilt_decimated(read: Callable[[int, int], np.ndarray], n: int, sos: np.ndarray, k: int, padlen: int,
                       piece: int = PIECE_ROWS, overlap: int | None = None, out: np.ndarray | None = None) -> np.ndarray:
    """``sosfiltfilt(sos, x, axis=0, padlen=padlen)[::k]`` of a block x of ``n`` rows given by
    ``read(a, b)`` (rows [a, b) as an (b - a, m) float array; read in increasing order, once, but
    for the first and last padlen + 1 rows), module doc. A block of at most 2 pieces is filtered whole."""
    if n <= 2 * piece or n <= padlen + 1:
        return signal.sosfiltfilt(sos, read(0, n), axis=0, padlen=padlen)[::k]
    L = settle_length(sos) if overlap is None else int(overlap)
    z = signal.sosfilt_zi(sos)[:, :, None]                     # (sections, 2, 1): the steady state per unit input
    head, tail = read(0, padlen + 1), read(n - padlen - 1, n)
    left = 2 * head[:1] - head[padlen:0:-1]
    right = 2 * tail[-1:] - tail[-2:-(padlen + 2):-1]
    E = n + 2 * padlen                                        # the extended block's length
    out = np.empty((len(range(0, n, k)), head.shape[1])) if out is None else out

    def keep(e0: int, yb: np.ndarray) -> None:
        """Backward outputs yb at extended rows e0.. into ``out`` (block rows i = e - padlen, i % k == 0)."""
        i0 = max(e0 - padlen, 0)
        i0 += (-i0) % k
        i1 = min(e0 + yb.shape[0] - padlen, n)
        if i1 > i0:
            out[i0 // k:(i1 - 1) // k + 1] = yb[i0 + padlen - e0:i1 + padlen - e0:k]

    def pieces():
        yield left
        for a in range(0, n, piece):
            yield read(a, min(a + piece, n))
        yield right

    state = z * left[:1]
    buf, start, pos = [], 0, 0                                 # forward outputs [start, pos) not yet finished
    for x in pieces():
        f, state = signal.sosfilt(sos, x, axis=0, zi=state)
        buf.append(f)
        pos += f.shape[0]
        if pos < E and pos - start >= piece + L:
            F = np.concatenate(buf)
            done = pos - L
            yb = signal.sosfilt(sos, F[::-1], axis=0, zi=z * F[-1:])[0][::-1]
            keep(start, yb[:done - start])
            buf, start = [F[done - start:]], done
    F = np.concatenate(buf)
    keep(start, signal.sosfilt(sos, F[::-1], axis=0, zi=z * F[-1:])[0][::-1])
    return out
