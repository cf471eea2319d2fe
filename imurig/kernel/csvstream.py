"""A lab CSV that declares its structure (a ``segment`` column or a ``# setpoints:`` line, as
``imurig convert`` writes it) converted to HDF5 in row blocks, in memory bounded by the block:
``imurig convert REC.csv REC.h5``.

Each block of ``BLOCK_ROWS`` rows is parsed and converted to SI as the whole-file import does
(:func:`imurig.kernel.import_lab.columns_to_channels`) and appended to resizable, chunked,
gzip-compressed datasets laid out as :func:`imurig.kernel.recording.save_h5` lays them out. The
segments table is built on the way, as :func:`imurig.kernel.labcsv.read_csv` builds it: a segment
is a run of rows of one ``segment`` id >= 0 (or of unchanged set-points), from its first row's time
to its last row's time plus the median sample interval, its set-points the median over its rows,
its ``run`` the run column at its first row. Loading the result gives the same Recording as
loading ``save_h5(read_csv(path))``.

A file whose structure must be inferred from whole columns (a minimal lab file), one that names its
site (``# site: delft``), or one with ADC counts is converted by the whole-file import (the caller's
fallback: :func:`csv_to_h5` returns None); so is any file the checks refuse, so that the refusal is
the whole-file import's own message.
"""
from __future__ import annotations

from itertools import islice
from pathlib import Path

import numpy as np

from imurig.kernel.errors import RecordingError
from imurig.kernel.import_lab import columns_to_channels, is_minimal
from imurig.kernel.labcsv import _nest, _read_head
from imurig.kernel.outputs import atomic_write, to_json
from imurig.kernel.recording import FORMAT_NAME, FORMAT_VERSION

#: rows parsed at a time (16 Ki: with 64 Ki-line blocks of text the peak still crept up by ~10 MB
#: over the first million rows, measured; with 16 Ki it stays within ~1 MB)
BLOCK_ROWS = 1 << 14


class _Refused(Exception):
    """The block checks found what the whole-file import refuses: let it say so."""


def csv_to_h5(src, dst, overwrite: bool = False, compress: bool = True) -> Path | None:
    """Convert the lab CSV ``src`` to the HDF5 recording ``dst`` in row blocks (module doc); None
    when the file needs the whole-file import (nothing written). ``compress=False``: the long
    datasets stored without gzip (a temporary file read once more: less CPU, more disk)."""
    import h5py  # heavy: loaded when a file is written

    path = Path(src)
    if not path.exists():
        raise RecordingError(f"{path} does not exist")
    meta_flat, header, n_head = _read_head(path)
    meta = _nest(meta_flat)
    if ("time_s" not in header or is_minimal(header, meta) or isinstance(meta.get("site"), str)
            or any(h.endswith("_counts") for h in header)):
        return None
    setpoints = meta.get("setpoints", [])
    if isinstance(setpoints, str):
        setpoints = meta["setpoints"] = [s.strip() for s in setpoints.split(",") if s.strip()]
    if not isinstance(setpoints, list) or not all(isinstance(s, str) for s in setpoints):
        return None
    meta.setdefault("source", path.name)

    def writer(tmp: Path):
        with h5py.File(tmp, "w") as f, open(path, encoding="utf-8") as fh:
            for _ in range(n_head):
                next(fh)
            seg, events, units = _stream_rows(f, fh, header, meta, setpoints, str(path), compress)
            f.attrs["format"], f.attrs["version"], f.attrs["meta"] = FORMAT_NAME, FORMAT_VERSION, to_json(meta)
            sg = f.create_group("segments")
            for k, v in seg.items():
                sg.create_dataset(k, data=v).attrs["unit"] = {"start_s": "s", "stop_s": "s", "run": "1"}.get(k) \
                    or units[k]
            f.create_group("truth_signals")
            eg = f.create_group("events")
            for k, v in events.items():
                kw = dict(compression="gzip", compression_opts=1, shuffle=True) if v.size > 4096 else {}
                eg.create_dataset(k, data=v, **kw).attrs["unit"] = "s"

    try:
        return atomic_write(Path(dst), writer, overwrite)
    except _Refused:
        return None


def _append(f, name: str, x: np.ndarray, unit: str | None = None, compress: bool = True) -> None:
    if name not in f:
        kw = dict(compression="gzip", compression_opts=1, shuffle=True) if compress else {}
        ds = f.create_dataset(name, shape=(0,), maxshape=(None,), dtype=float, chunks=(16384,), **kw)
        if unit is not None:
            ds.attrs["unit"] = unit
    ds = f[name]
    n = ds.shape[0]
    ds.resize((n + x.size,))
    ds[n:] = x


def _stream_rows(f, fh, header, meta, setpoints, where, compress: bool = True):
    """Blocks of rows to /time_s and /channels; returns the segments table, the events and the units."""
    seg = _Segments("segment" in header, "run" in header, setpoints)
    events: dict[str, list] = {}
    units, last_t, n, dts = {}, None, 0, {}
    while True:
        lines = list(islice(fh, BLOCK_ROWS))
        if not lines:
            break
        try:
            data = np.loadtxt(lines, delimiter=",", ndmin=2, dtype=float)
        except ValueError:
            raise _Refused() from None
        if data.size == 0:
            continue
        if data.shape[1] != len(header):
            raise _Refused()
        cols = {h: data[:, i] for i, h in enumerate(header)}
        try:
            channels, u, ev, _ = columns_to_channels(cols, meta, where)
        except RecordingError:
            raise _Refused() from None
        t = cols["time_s"]
        tt = t if last_t is None else np.concatenate(([last_t], t))
        d = np.diff(tt)
        if not np.all(np.isfinite(t)) or np.any(d <= 0) or not all(np.all(np.isfinite(x)) for x in channels.values()):
            raise _Refused()
        vals, cnt = np.unique(d, return_counts=True)
        for v, c in zip(vals.tolist(), cnt.tolist()):
            dts[v] = dts.get(v, 0) + c
        if not units and any(s not in channels for s in setpoints):
            raise _Refused()                     # a set-point without its column
        units = units or u
        _append(f, "time_s", t, compress=compress)
        for k, x in channels.items():
            _append(f, f"channels/{k}", x, u[k], compress)
        for k, x in ev.items():
            events.setdefault(k, []).append(x)
        seg.add(t, cols.get("segment"), cols.get("run"), [channels[s] for s in setpoints])
        last_t, n = t[-1], n + t.size
    if n < 2:
        raise _Refused()
    table = seg.table(_median(dts), units)
    return table, {k: np.sort(np.concatenate(v)) for k, v in events.items()}, units


def _median(counts: dict) -> float:
    """The median of values given as {value: count}, as np.median takes it."""
    vals = np.array(sorted(counts))
    cum = np.cumsum([counts[v] for v in vals.tolist()])
    m = int(cum[-1])
    lo, hi = vals[np.searchsorted(cum, (m - 1) // 2 + 1)], vals[np.searchsorted(cum, m // 2 + 1)]
    return float(np.mean(np.array([lo, hi]))) if m % 2 == 0 else float(hi)


class _Segments:
    """The segments table of labcsv._segments_from_columns, built block by block: runs of rows of
    one key (the segment id, or a count of set-point changes) and validity (id >= 0)."""

    def __init__(self, has_id: bool, has_run: bool, setpoints: list[str]):
        self.has_id, self.has_run, self.setpoints = has_id, has_run, setpoints
        self.cur = None          # (key, valid, start time, run at start, [set-point pieces], last time)
        self.done: list[tuple] = []
        self.last_sp = None
        self.changes = 0

    def add(self, t, seg_id, run, sp: list[np.ndarray]) -> None:
        if not self.has_id and not self.setpoints:
            return
        if self.has_id:
            if not np.all(np.isfinite(seg_id)) or np.any(seg_id != np.round(seg_id)):
                raise _Refused()
            key, valid = seg_id, seg_id >= 0
        else:
            s = np.stack(sp, axis=1)
            prev = s[:1] if self.last_sp is None else self.last_sp
            change = np.any(np.diff(np.concatenate((prev, s)), axis=0) != 0, axis=1)
            key = self.changes + np.cumsum(change)
            self.changes, self.last_sp = int(key[-1]), s[-1:]
            valid = np.ones(t.size, bool)
        brk = np.flatnonzero((np.diff(key) != 0) | (np.diff(valid.astype(int)) != 0)) + 1
        starts, stops = np.concatenate(([0], brk)), np.concatenate((brk, [t.size]))
        for a, b in zip(starts, stops):
            if self.cur is not None and a == 0 and self.cur[0] == key[0] and self.cur[1] == bool(valid[0]):
                self.cur[4].append([x[a:b] for x in sp])         # the run goes on from the last block
                self.cur[5] = t[b - 1]
                continue
            self._close()
            r = run[a] if run is not None else None
            self.cur = [key[a], bool(valid[a]), t[a], r, [[x[a:b] for x in sp]], t[b - 1]]

    def _close(self) -> None:
        if self.cur is not None and self.cur[1]:
            key, _, t0, r, pieces, t1 = self.cur
            if self.has_run and not np.isfinite(r):
                raise _Refused()
            med = [np.median(np.concatenate([p[j] for p in pieces])) for j in range(len(self.setpoints))]
            self.done.append((t0, t1, r, med))
        self.cur = None

    def table(self, dt: float, units: dict) -> dict:
        self._close()
        if not self.has_id and not self.setpoints:
            return {}
        d = self.done
        seg = {"start_s": np.array([x[0] for x in d], float), "stop_s": np.array([x[1] for x in d], float) + dt}
        if self.has_run:
            seg["run"] = np.array([x[2] for x in d], float).astype(int)
        for j, s in enumerate(self.setpoints):
            seg[s] = np.array([x[3][j] for x in d], float)
        return seg
