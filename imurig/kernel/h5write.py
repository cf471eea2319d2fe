"""An imurig HDF5 recording written row piece by row piece (the layout of
:func:`imurig.kernel.recording.save_h5`), in memory bounded by the piece.

The datasets are created at their full length (the number of samples is known before the first
piece), chunked (``CHUNK_ROWS`` rows) and gzip-compressed with the byte shuffle, and filled in order.
Each chunk is shuffled and deflated here, by worker threads (the compressor runs without the interpreter
lock, beside the simulation), and stored as it is (``write_direct_chunk``): a standard zlib stream of the
shuffled bytes, as HDF5's shuffle and deflate filters would store, read back by any HDF5 reader through
those filters. The deflater is ISA-L's (the ``isal`` package, level :data:`ISAL_LEVEL`): on the tilt
campaign's chunks 2.3x less CPU than zlib's fastest run-length deflate with stored blocks for the busy
bytes (the writer before it), the file 6 % smaller; without ``isal``, zlib (:data:`STRATEGY`). Either
stream inflates to the same bytes: the file's data do not depend on the deflater.
The root attributes (``meta``, ``truth``: JSON) are written at the end, when the sensor chain has
reported them. ADC channels are stored as their integer codes with the attribute ``quantum`` (one
LSB; volts = code * quantum), as ``save_h5`` stores channels on the converter's grid, so
:func:`imurig.kernel.recording.load_h5` and :mod:`imurig.kernel.h5stream` read the file as any other.
"""
from __future__ import annotations

import zlib
from collections import deque
from collections.abc import Mapping
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from imurig.kernel.outputs import to_json
from imurig.kernel.recording import FORMAT_NAME, FORMAT_VERSION, _write_group

#: rows per HDF5 chunk (the readers' chunk, :data:`imurig.kernel.h5stream.CHUNK_ROWS`)
CHUNK_ROWS = 1 << 16
#: gzip level of the datasets' filter (1: the fastest; the same as save_h5): what HDF5 uses for a later write
GZIP_LEVEL = 1
#: ISA-L's deflate level (0-3): 2 costs what 1 costs here and is 1 % smaller (measured on the tilt campaign)
ISAL_LEVEL = 2
#: without isal: zlib's run-length matches (Z_RLE) for the signals, 1.8-2x faster than the default at the
#: same size; the default for time_s, whose regularity is in longer matches
STRATEGY = zlib.Z_RLE
TIME_STRATEGY = zlib.Z_DEFAULT_STRATEGY
#: compressing threads, and chunks waiting to be stored at most (memory: that many chunks)
WORKERS = 2
MAX_PENDING = 48

try:
    from isal import isal_zlib
except ImportError:  # pragma: no cover - isal is a dependency; zlib gives the same file data, slower
    isal_zlib = None


def _deflate(x: np.ndarray, rows: int, strategy: int) -> bytes:
    """One chunk as HDF5 stores it with the shuffle and deflate filters: padded to ``rows`` rows, the
    bytes regrouped by significance (byte 0 of every value, then byte 1, ...), as one zlib stream
    (ISA-L's deflate, or zlib's with the deflate ``strategy`` where isal is missing; HDF5's filter inflates
    either to the same bytes)."""
    x = np.ascontiguousarray(x)
    if x.shape[0] < rows:
        x = np.concatenate((x, np.zeros(rows - x.shape[0], x.dtype)))
    shuffled = np.ascontiguousarray(x.view(np.uint8).reshape(-1, x.dtype.itemsize).T).reshape(-1)
    if isal_zlib is not None:
        return isal_zlib.compress(shuffled, ISAL_LEVEL)
    z = zlib.compressobj(GZIP_LEVEL, zlib.DEFLATED, 15, 8, strategy)
    return z.compress(shuffled) + z.flush()


class H5RowWriter:
    """Fill an open h5py File ``f`` (mode "w") with one recording of ``n`` samples, piece by piece.

    ``channels``: name -> (numpy dtype, unit, quantum or None) in the order they are to be listed;
    ``truth_units``: name -> unit of the truth signals; ``segments`` / ``segment_units``: the (small)
    segment table, written at once. Call :meth:`rows` for consecutive row ranges covering [0, n), then
    :meth:`finish`."""

    def __init__(self, f, n: int, channels: Mapping[str, tuple], truth_units: Mapping[str, str],
                 segments: Mapping[str, np.ndarray], segment_units: Mapping[str, str]):
        self.f, self.n, self._next = f, int(n), 0
        self._rows = min(CHUNK_ROWS, self.n)
        self._pool = ThreadPoolExecutor(WORKERS)
        self._pending: deque = deque()
        self._constant: dict = {}   # deflated constant chunks by (dtype, value, rows, strategy)
        f.attrs["format"] = FORMAT_NAME
        f.attrs["version"] = FORMAT_VERSION
        self._time = self._dataset(f, "time_s", np.float64)
        g = f.create_group("channels")
        self._chan = {}
        for name, (dtype, unit, q) in channels.items():
            ds = self._chan[name] = self._dataset(g, name, dtype)
            ds.attrs["unit"] = unit
            if q is not None:
                ds.attrs["quantum"] = q
        _write_group(f.create_group("segments"), segments, segment_units)
        g = f.create_group("truth_signals")
        self._truth = {}
        for name, unit in truth_units.items():
            ds = self._truth[name] = self._dataset(g, name, np.float64)
            ds.attrs["unit"] = unit
        f.create_group("events")

    def _dataset(self, grp, name: str, dtype):
        return grp.create_dataset(name, shape=(self.n,), dtype=dtype, chunks=(self._rows,), compression="gzip",
                                  compression_opts=GZIP_LEVEL, shuffle=True)

    def rows(self, a: int, b: int, time_s: np.ndarray, channels: Mapping[str, np.ndarray],
             codes: Mapping[str, np.ndarray], truth_signals: Mapping[str, np.ndarray]) -> None:
        """Rows [a, b) (the next ones) of time, every channel (from ``channels``, or its codes from ``codes``
        for a quantised one) and every truth signal; whole chunks (the last may be short). The arrays are
        read by the compressing threads after this returns: the caller must not change them."""
        if a != self._next or a % self._rows or ((b - a) % self._rows and b != self.n):
            raise ValueError(f"rows must come in order in whole chunks of {self._rows}: expected row {self._next}, "
                             f"got [{a}, {b})")
        self._put(self._time, a, b, time_s, TIME_STRATEGY)
        for name, ds in self._chan.items():
            self._put(ds, a, b, codes[name] if name in codes else channels[name])
        for name, ds in self._truth.items():
            self._put(ds, a, b, truth_signals[name])
        self._next = b

    def _put(self, ds, a: int, b: int, x: np.ndarray, strategy: int = STRATEGY) -> None:
        """Rows [a, b) of ``ds``: each chunk deflated by a worker, stored in order as the workers finish (``x``
        must not change afterwards: the workers read it)."""
        x = np.asarray(x, dtype=ds.dtype)
        for c in range(a, b, self._rows):
            piece = x[c - a:min(b, c + self._rows) - a]
            bits = piece.view(f"u{piece.dtype.itemsize}")   # compared bit for bit (0.0 is not -0.0)
            # a held value (or zeros): its bytes deflated once (the ends first: most chunks differ there)
            if piece.size and bits[-1] == bits[0] and np.all(bits == bits[0]):
                key = (piece.dtype.str, piece[:1].tobytes(), piece.size, strategy)
                if key not in self._constant:
                    self._constant[key] = self._pool.submit(_deflate, piece.copy(), self._rows, strategy)
                fut = self._constant[key]
            else:
                fut = self._pool.submit(_deflate, piece, self._rows, strategy)
            self._pending.append((ds, c, fut))
        self._store(MAX_PENDING)

    def _store(self, keep: int) -> None:
        """Store the finished chunks in order, waiting while more than ``keep`` are pending."""
        while self._pending and (len(self._pending) > keep or self._pending[0][2].done()):
            ds, c, fut = self._pending.popleft()
            ds.id.write_direct_chunk((c,), fut.result())

    def finish(self, meta: dict, truth: dict | None, drop_truth=(), events: Mapping[str, np.ndarray] | None = None) -> None:
        """Write the root attributes and the ``events`` (name -> time stamps, s); remove the truth signals
        ``drop_truth`` (e.g. disturbances that stayed zero, which the whole-record writer leaves out)."""
        if self._next != self.n:
            raise ValueError(f"{self._next} of {self.n} rows written")
        self._store(0)
        self.close()
        for name in drop_truth:
            del self.f["truth_signals"][name]
        _write_group(self.f["events"], events or {}, {k: "s" for k in events or {}})
        self.f.attrs["meta"] = to_json(meta)
        if truth is not None:
            self.f.attrs["truth"] = to_json(truth)

    def close(self) -> None:
        """Stop the compressing threads (after :meth:`finish`, or on an error: the chunks not yet stored
        are dropped with the unfinished file)."""
        self._pending.clear()
        self._pool.shutdown(cancel_futures=True)
