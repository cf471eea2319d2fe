"""An imurig HDF5 recording written row piece by row piece (the layout of
:func:`imurig.kernel.recording.save_h5`), in memory bounded by the piece.

The datasets are created at their full length (the number of samples is known before the first
piece), chunked (``CHUNK_ROWS`` rows) and gzip-compressed with the byte shuffle, and filled in order;
the root attributes (``meta``, ``truth``: JSON) are written at the end, when the sensor chain has
reported them. ADC channels are stored as their integer codes with the attribute ``quantum`` (one
LSB; volts = code * quantum), as ``save_h5`` stores channels on the converter's grid, so
:func:`imurig.kernel.recording.load_h5` and :mod:`imurig.kernel.h5stream` read the file as any other.
"""
from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from imurig.kernel.outputs import to_json
from imurig.kernel.recording import FORMAT_NAME, FORMAT_VERSION, _write_group

#: rows per HDF5 chunk (the readers' chunk, :data:`imurig.kernel.h5stream.CHUNK_ROWS`)
CHUNK_ROWS = 1 << 16
#: gzip level (1: the fastest; the same as save_h5)
GZIP_LEVEL = 1


class H5RowWriter:
    """Fill an open h5py File ``f`` (mode "w") with one recording of ``n`` samples, piece by piece.

    ``channels``: name -> (numpy dtype, unit, quantum or None) in the order they are to be listed;
    ``truth_units``: name -> unit of the truth signals; ``segments`` / ``segment_units``: the (small)
    segment table, written at once. Call :meth:`rows` for consecutive row ranges covering [0, n), then
    :meth:`finish`."""

    def __init__(self, f, n: int, channels: Mapping[str, tuple], truth_units: Mapping[str, str],
                 segments: Mapping[str, np.ndarray], segment_units: Mapping[str, str]):
        self.f, self.n, self._next = f, int(n), 0
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
        chunk = min(CHUNK_ROWS, self.n)
        return grp.create_dataset(name, shape=(self.n,), dtype=dtype, chunks=(chunk,), compression="gzip",
                                  compression_opts=GZIP_LEVEL, shuffle=True)

    def rows(self, a: int, b: int, time_s: np.ndarray, channels: Mapping[str, np.ndarray],
             codes: Mapping[str, np.ndarray], truth_signals: Mapping[str, np.ndarray]) -> None:
        """Rows [a, b) (the next ones) of time, every channel (from ``channels``, or its codes from ``codes``
        for a quantised one) and every truth signal."""
        if a != self._next:
            raise ValueError(f"rows must come in order: expected row {self._next}, got {a}")
        self._time[a:b] = time_s
        for name, ds in self._chan.items():
            ds[a:b] = codes[name] if name in codes else channels[name]
        for name, ds in self._truth.items():
            ds[a:b] = truth_signals[name]
        self._next = b

    def finish(self, meta: dict, truth: dict | None, drop_truth=()) -> None:
        """Write the root attributes; remove the truth signals ``drop_truth`` (e.g. disturbances that
        stayed zero, which the whole-record writer leaves out)."""
        if self._next != self.n:
            raise ValueError(f"{self._next} of {self.n} rows written")
        for name in drop_truth:
            del self.f["truth_signals"][name]
        self.f.attrs["meta"] = to_json(meta)
        if truth is not None:
            self.f.attrs["truth"] = to_json(truth)
