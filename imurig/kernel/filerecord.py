"""A recording on disk, read in row ranges: what a reader needs of a Recording without holding its
samples (``imurig diagnose`` on a long file).

:class:`FileRecord` opens an imurig HDF5 file (:class:`imurig.kernel.h5stream.H5Recording`: the
checks of ``load_h5``) and, in one pass over ``/time_s`` (checked finite and increasing), finds
what ``Recording`` derives from the whole time column: the sample rate 1 / median(diff(t)) (exact),
the blocks (a gap longer than 1.5 sample periods splits) and each segment's rows
(``searchsorted(t, start_s / stop_s, side="left")``). The channels stay on disk:
:meth:`FileRecord.read` gives rows [a, b) of one, in SI (codes scaled as ``load_h5`` scales them).

A lab CSV that declares its structure is converted to a temporary HDF5 file in row blocks first
(:func:`imurig.kernel.csvstream.csv_to_h5`, the same Recording as ``read_csv``); a file whose
structure must be inferred from whole columns is not opened (:func:`open_file_record` returns None:
the caller loads it whole, after :func:`check_memory`).

Memory: :func:`check_memory` estimates what a reader will hold (rows x columns x 8 bytes x a working
factor) against the available memory and refuses with a RecordingError before allocating.
"""
from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from imurig.kernel.csvstream import csv_to_h5
from imurig.kernel.errors import RecordingError
from imurig.kernel.h5stream import H5Recording
from imurig.kernel.import_lab import check_memory
from imurig.kernel.recording import Recording, load_h5

__all__ = ["FileRecord", "open_file_record", "check_memory"]


class FileRecord:
    """An imurig HDF5 recording whose channels are read in row ranges (module doc).

    ``meta``, ``truth``, ``units``, ``channel_quantum``, ``segments``, ``segment_units``, ``events``
    (small, in memory), ``channel_names`` (the file's order), ``n``, ``dt`` (median(diff(time_s))),
    ``sample_rate_hz``, ``t0`` (the first time), :meth:`blocks`, :meth:`segment_slices`, :meth:`require`;
    :meth:`read`, :meth:`read_time`, :meth:`rows_at`, :meth:`load` (the whole Recording, after a memory
    check). Use as a context manager."""

    def __init__(self, path, source=None, tmp=None):
        self.path = Path(path)
        self.source = Path(source) if source is not None else self.path
        self._tmp = tmp
        self._cache, self._chunk_rows = {}, {}
        self._h = h = H5Recording(self.path)
        try:
            self._setup(h)
        except BaseException:
            self.close()
            raise

    def _setup(self, h: H5Recording) -> None:
        self.meta, self.truth, self.events = h.meta, h.truth, h.events
        self.segments, self.segment_units = h.segments, h.segment_units
        self.channel_names = list(h.channels)
        self.units = {k: e[1] for k, e in h.channels.items()}
        self.channel_quantum = {k: e[2] for k, e in h.channels.items() if e[2] is not None}
        self.n = h.n
        seg = self.segments
        marks = {"lo": seg["start_s"], "hi": seg["stop_s"]} if seg else {}
        idx = h.time_pass(marks)
        self._seg = [slice(int(a), int(b)) for a, b in zip(idx["lo"], idx["hi"])] if seg else []
        self.dt = dt = h.median_dt()
        self.sample_rate_hz = float(1.0 / dt)
        cuts, last = [], None
        for a, b in h.row_chunks():
            t = h.read("time_s", a, b)
            d = np.diff(t if last is None else np.concatenate(([last], t)))
            cuts.extend((np.flatnonzero(d > 1.5 * dt) + (a if last is None else a - 1) + 1).tolist())
            last = t[-1]
        edges = [0, *cuts, self.n]
        self._blocks = [slice(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]
        self.t0 = float(h.read("time_s", 0, 1)[0])

    def __enter__(self) -> "FileRecord":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self._h._f.close()
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None

    @property
    def n_segments(self) -> int:
        return len(self._seg)

    def blocks(self) -> list[slice]:
        """Contiguous sample blocks, as :meth:`Recording.blocks`."""
        return list(self._blocks)

    def segment_slices(self) -> list[slice]:
        """Rows of each segment's window [start_s, stop_s), as :meth:`Recording.segment_slices`."""
        return list(self._seg)

    def _rows(self, what, a: int, b: int) -> np.ndarray:
        """Rows [a, b) of ``what`` (``"time_s"`` or a channel entry) through whole stored chunks: the
        last chunk read of each dataset is kept, so that pieces which do not start on a chunk's edge
        (a block's, a segment's) do not decompress a chunk twice."""
        key = what if isinstance(what, str) else what[0]
        rows = self._chunk_rows.get(key)
        if rows is None:
            ds = self._h._f[key]
            rows = self._chunk_rows[key] = int(ds.chunks[0]) if ds.chunks else 0
        if not rows or (a % rows == 0 and b - a >= rows):
            return self._h.read(what, a, b)
        parts = []
        for c in range(a // rows, (b - 1) // rows + 1):
            hit = self._cache.get(key)
            if hit is None or hit[0] != c:
                hit = self._cache[key] = (c, self._h.read(what, c * rows, min((c + 1) * rows, self.n)))
            parts.append(hit[1][max(a - c * rows, 0):b - c * rows])
        return parts[0].copy() if len(parts) == 1 else np.concatenate(parts)

    def read(self, name: str, a: int, b: int) -> np.ndarray:
        """Rows [a, b) of channel ``name`` (float64, SI), checked finite as loading checks them."""
        x = self._rows(self._h.channels[name], a, b)
        bad = np.flatnonzero(~np.isfinite(x))
        if bad.size:
            raise RecordingError(f"{self.source}: channel '{name}' has NaN/inf samples (first at sample "
                                 f"{a + int(bad[0])}); drop or interpolate them before use, or remove the channel")
        return x

    def read_time(self, a: int, b: int) -> np.ndarray:
        return self._rows("time_s", a, b)

    def rows_at(self, times) -> np.ndarray:
        """``searchsorted(time_s, times, side="left")`` in one pass over the time column."""
        return self._h.time_pass({"t": np.asarray(times, float)})["t"]

    def require(self, needed) -> None:
        """As :meth:`Recording.require`: each channel of ``needed`` (name -> SI unit) exists with that unit."""
        Recording(time_s=np.zeros(0), channels=dict.fromkeys(self.channel_names), units=dict(self.units),
                  meta=self.meta).require(needed)

    def row_pieces(self, rows: int):
        """(a, b) over all rows, ``rows`` at a time."""
        for a in range(0, self.n, rows):
            yield a, min(a + rows, self.n)

    def load(self) -> Recording:
        """The whole Recording (``load_h5``), after :func:`check_memory`."""
        n_cols = 1 + len(self.channel_names) + len(self._h.truth_signals)
        check_memory(self.n, n_cols, str(self.source))
        return load_h5(self.path)


def open_file_record(path, tmp_dir=None) -> FileRecord | None:
    """A :class:`FileRecord` of an ``.h5``/``.hdf5`` file, or of a lab ``.csv`` that declares its
    structure (through a temporary, uncompressed HDF5 file in ``tmp_dir``, default the system's
    temporary folder, deleted on close: 8 bytes per value on disk); None for any other file (the
    caller loads it whole)."""
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix in (".h5", ".hdf5"):
        return FileRecord(p)
    if suffix != ".csv":
        return None
    tmp = tempfile.TemporaryDirectory(prefix="imurig-", dir=tmp_dir)
    try:
        dst = csv_to_h5(p, Path(tmp.name) / (p.stem + ".h5"), compress=False)
    except BaseException:
        tmp.cleanup()
        raise
    if dst is None:
        tmp.cleanup()
        return None
    try:
        return FileRecord(dst, source=p, tmp=tmp)
    except RecordingError as e:
        raise RecordingError(str(e).replace(str(dst), str(p))) from None
