"""An imurig HDF5 recording read in row chunks, in memory bounded by the chunk, not the file:
the summary of ``imurig info`` and the lab-CSV export of ``imurig convert``.

The file is opened and checked as :func:`imurig.kernel.recording.load_h5` checks it (format,
JSON attributes, groups of 1-D numeric datasets of one length, time strictly increasing and
finite, channels finite, segments well formed), but the long datasets (``/time_s``,
``/channels/*``) are read ``CHUNK_ROWS`` rows at a time; the small ones (segments, events) whole.
Channels stored as integer codes with a ``quantum`` are scaled chunk by chunk exactly as
``load_h5`` scales them (``codes.astype(float64) * quantum``), so the CSV written here is the
same, byte for byte, as ``write_csv(load_h5(path))``.

The summary's sample rate is 1 / median(diff(time_s)), the median taken exactly from the counts
of the distinct sample intervals (a clock of a few periods has a handful; for a jittered clock with
more than ``MAX_DISTINCT_DT`` distinct intervals, exact order statistics in passes,
:class:`imurig.kernel.ranks.RankSearch`).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from imurig.kernel.errors import RecordingError
from imurig.kernel.outputs import atomic_write
from imurig.kernel.ranks import median_search
from imurig.kernel.recording import FORMAT_NAME, _float_attr, _json_attr
from imurig.kernel.units import from_si

#: rows read at a time (64 Ki rows: ~0.5 MB per float64 column)
CHUNK_ROWS = 1 << 16
#: distinct sample intervals counted for the exact median before searching it in passes instead
MAX_DISTINCT_DT = 1 << 16


class H5Recording:
    """An open, checked imurig HDF5 recording whose long datasets are read in chunks.

    ``meta``, ``truth`` (JSON), ``segments`` / ``segment_units`` and ``events`` (small, read
    whole); ``channels``: name -> (dataset path, unit, quantum or None, rows), in the file's order;
    ``n``: the number of samples. Use as a context manager (closes the file)."""

    def __init__(self, path):
        import h5py  # heavy: loaded when a file is read, not when the CLI starts

        self.path = path = Path(path)
        if not path.exists():
            raise RecordingError(f"{path} does not exist")
        try:
            self._f = f = h5py.File(path, "r")
        except OSError as e:
            raise RecordingError(f"{path} is not a readable HDF5 file ({e}); give an imurig .h5 recording or a "
                                 "lab .csv/.mat file") from e
        try:
            self._open(f, h5py)
        except RecordingError:
            f.close()
            raise
        except (OSError, KeyError, TypeError, ValueError, RuntimeError) as e:   # h5py's own errors
            f.close()
            raise self._damaged(e) from e

    def _damaged(self, e) -> RecordingError:
        return RecordingError(f"{self.path}: the HDF5 file is damaged or not laid out as imurig writes it "
                              f"({type(e).__name__}: {e}); write it again with imurig")

    def _open(self, f, h5py) -> None:
        path = self.path
        fmt = f.attrs.get("format")
        if (fmt.decode("utf-8", "replace") if isinstance(fmt, bytes) else fmt) != FORMAT_NAME:
            raise RecordingError(f"{path} is not an imurig recording (no format attribute '{FORMAT_NAME}')")
        self.meta = _json_attr(f.attrs, "meta", path, required=True)
        self.truth = _json_attr(f.attrs, "truth", path, required=False)
        for key in ("time_s", "channels", "segments"):
            if f.get(key) is None:
                raise RecordingError(f"{path}: '/{key}' is missing (or a dangling link); write the file with "
                                     "imurig (imurig convert)")
        self.channels = self._group(f["channels"], "channels", h5py)
        self.truth_signals = self._group(f["truth_signals"], "truth_signals", h5py) if "truth_signals" in f else {}
        segs = self._group(f["segments"], "segments", h5py, text=True)
        self.segments = {k: _whole(f[ds], q) for k, (ds, _, q, _) in segs.items()}
        self.segment_units = {k: u for k, (_, u, _, _) in segs.items()}
        evs = self._group(f["events"], "events", h5py) if "events" in f else {}
        self.events = {k: _whole(f[ds], q) for k, (ds, _, q, _) in evs.items()}
        ts = f["time_s"]
        if not isinstance(ts, h5py.Dataset) or ts.ndim != 1 or ts.dtype.kind not in "iuf":
            raise RecordingError(f"{path}: '/time_s' must be a 1-D numeric dataset")
        self._time = ts.name
        self.n = n = int(ts.shape[0])
        if n < 2:
            raise RecordingError(f"{path}: time_s must be a 1-D array with at least two samples")
        for name, (_, _, _, rows) in self.channels.items():      # truth signals: unchecked, as load_h5
            if rows != n:
                raise RecordingError(f"{path}: channel '{name}' has {rows} samples but time_s has {n}")
        self._check_segments()

    def _group(self, grp, where: str, h5py, text: bool = False) -> dict:
        """name -> (dataset, unit, quantum) of a group of 1-D datasets, checked as load_h5 checks them."""
        path = self.path
        if not isinstance(grp, h5py.Group):
            raise RecordingError(f"{path}: '/{where}' must be a group of datasets, found a {type(grp).__name__}; "
                                 "write the file with imurig (imurig convert) or fix its layout")
        out = {}
        for name in grp:
            ds = grp.get(name)
            if not isinstance(ds, h5py.Dataset):
                raise RecordingError(f"{path}: '/{where}/{name}' must be a dataset, found "
                                     f"{'a dangling or external link' if ds is None else type(ds).__name__}")
            if ds.ndim != 1:
                raise RecordingError(f"{path}: '/{where}/{name}' must be a 1-D array, it has shape {ds.shape}")
            kind = ds.dtype.kind
            if kind in "OS" and not text:
                raise RecordingError(f"{path}: '/{where}/{name}' holds text; it must hold numbers")
            if kind not in "OSbiuf":
                raise RecordingError(f"{path}: '/{where}/{name}' holds {ds.dtype} values; numbers (or text for "
                                     "segment labels) are needed")
            q = None
            if "quantum" in ds.attrs:
                q = _float_attr(ds.attrs["quantum"], path, f"/{where}/{name} quantum")
                if kind not in "biuf":
                    raise RecordingError(f"{path}: '/{where}/{name}' has a quantum but holds text")
            u = ds.attrs.get("unit", "")
            # kept by its path, not as an open handle: an h5py dataset held open across chunked
            # reads holds on to memory that grows with the rows read (measured: ~1.6 MB per
            # 64 Ki-row pass over 12 datasets); one looked up again for each chunk does not
            out[name] = (ds.name, u.decode("utf-8", "replace") if isinstance(u, bytes) else str(u), q,
                         int(ds.shape[0]))
        return out

    def _check_segments(self) -> None:
        path, seg = self.path, self.segments
        for k, v in seg.items():
            if v.dtype.kind == "f" and not np.all(np.isfinite(v)):
                raise RecordingError(f"{path}: segment column '{k}' has NaN/inf values")
        if not seg:
            return
        for col in ("start_s", "stop_s"):
            if col not in seg:
                raise RecordingError(f"{path}: segments table lacks '{col}'")
        m = len(seg["start_s"])
        for k, v in seg.items():
            if v.shape[0] != m:
                raise RecordingError(f"{path}: segment column '{k}' has {v.shape[0]} rows, expected {m}")
        if np.any(seg["stop_s"] <= seg["start_s"]):
            raise RecordingError(f"{path}: a segment ends before it starts; check start_s/stop_s")

    def __enter__(self) -> "H5Recording":
        return self

    def __exit__(self, *exc) -> None:
        self._f.close()

    # ------------------------------------------------------------------ chunks
    def row_chunks(self):
        """(start, stop) of each chunk of rows."""
        for a in range(0, self.n, CHUNK_ROWS):
            yield a, min(a + CHUNK_ROWS, self.n)

    def read(self, what, a: int, b: int) -> np.ndarray:
        """Rows [a, b) of ``/time_s`` (``what`` = "time_s") or of a ``channels`` entry, float64 SI."""
        try:
            if isinstance(what, str):
                return np.asarray(self._f[self._time][a:b], dtype=float)
            q = what[2]
            x = self._f[what[0]][a:b]              # looked up again: see _group
            return x.astype(np.float64) * q if q is not None else np.asarray(x, dtype=float)
        except (OSError, KeyError, TypeError, ValueError, RuntimeError) as e:   # damaged chunks
            raise self._damaged(e) from e

    def time_pass(self, marks: dict[str, np.ndarray] | None = None) -> dict[str, np.ndarray]:
        """One pass over ``/time_s``: check it (finite, strictly increasing) and return, for each
        array of times in ``marks``, ``searchsorted(time_s, marks, side="left")`` (global indices)."""
        marks = marks or {}
        out = {k: np.zeros(np.shape(v), dtype=np.int64) for k, v in marks.items()}
        last = None
        for a, b in self.row_chunks():
            t = self.read("time_s", a, b)
            if not np.all(np.isfinite(t)):
                i = a + int(np.flatnonzero(~np.isfinite(t))[0])
                raise RecordingError(f"{self.path}: time_s has non-finite values (first at sample {i}); "
                                     "remove those rows or fill in the time stamps")
            tt = t if last is None else np.concatenate(([last], t))
            d = np.diff(tt)
            if np.any(d <= 0):
                i = int(np.flatnonzero(d <= 0)[0])
                raise RecordingError(f"{self.path}: time_s must increase strictly; it does not at sample "
                                     f"{a + i + (0 if last is None else -1) + 1} ({tt[i]!r} -> {tt[i + 1]!r}); "
                                     "sort the rows or fix the clock")
            for k, v in marks.items():
                out[k] += np.searchsorted(t, v, side="left")
            last = t[-1]
        return out

    def first_last_time(self) -> tuple[float, float]:
        return float(self.read("time_s", 0, 1)[0]), float(self.read("time_s", self.n - 1, self.n)[0])

    def median_dt(self) -> float:
        """median(diff(time_s)), exact (see the module doc)."""
        counts: dict[float, int] = {}
        last = None
        stride = max(1, (self.n - 1) // MAX_DISTINCT_DT)
        sub = []
        for a, b in self.row_chunks():
            t = self.read("time_s", a, b)
            d = np.diff(t if last is None else np.concatenate(([last], t)))
            j0 = a if last is None else a - 1                 # the index of d's first interval
            sub.append(d[(-j0) % stride::stride].copy())
            last = t[-1]
            if counts is not None:
                vals, cnt = np.unique(d, return_counts=True)
                for v, c in zip(vals.tolist(), cnt.tolist()):
                    counts[v] = counts.get(v, 0) + c
                if len(counts) > MAX_DISTINCT_DT:       # a jittered clock: exact order statistics in passes
                    counts = None
        if counts is None:
            return self._median_dt_search(np.concatenate(sub))
        vals = np.array(sorted(counts))
        cum = np.cumsum([counts[v] for v in vals.tolist()])
        m = int(cum[-1])
        lo, hi = vals[np.searchsorted(cum, (m - 1) // 2 + 1)], vals[np.searchsorted(cum, m // 2 + 1)]
        return float(np.mean(np.array([lo, hi]))) if m % 2 == 0 else float(hi)

    def _median_dt_search(self, sample: np.ndarray) -> float:
        """median(diff(time_s)) by :class:`imurig.kernel.ranks.RankSearch` (passes over ``/time_s``)."""
        s = median_search(self.n - 1, sample, limit=MAX_DISTINCT_DT)
        while True:
            last = None
            for a, b in self.row_chunks():
                t = self.read("time_s", a, b)
                s.feed(np.diff(t if last is None else np.concatenate(([last], t))))
                last = t[-1]
            if s.end():
                return s.median()

    def count_gaps(self, limit_s: float) -> int:
        """How many sample intervals exceed ``limit_s``."""
        gaps, last = 0, None
        for a, b in self.row_chunks():
            t = self.read("time_s", a, b)
            gaps += int(np.count_nonzero(np.diff(t if last is None else np.concatenate(([last], t))) > limit_s))
            last = t[-1]
        return gaps


def _whole(ds, q) -> np.ndarray:
    """A small dataset read whole, as load_h5 reads it (text decoded, codes scaled)."""
    x = ds[()]
    if ds.dtype.kind in "OS":
        return np.array([v.decode("utf-8", "replace") if isinstance(v, bytes) else str(v) for v in x], dtype=str)
    return x.astype(np.float64) * q if q is not None else x


def h5_info(path) -> dict:
    """The ``imurig info`` summary of an HDF5 recording (the same keys and values as from the
    loaded Recording), from its metadata, shapes and chunked passes over ``/time_s``; channels
    are checked finite chunk by chunk, as loading checks them."""
    with H5Recording(path) as h:
        h.time_pass()
        _check_finite(h)
        dt = h.median_dt()
        t0, t1 = h.first_last_time()
        meta = h.meta
        return {"samples": h.n, "duration_s": float(t1 - t0), "sample_rate_hz": float(1.0 / dt),
                "blocks": h.count_gaps(1.5 * dt) + 1,
                "channels": {k: ent[1] for k, ent in h.channels.items()},
                "segments": int(len(h.segments.get("start_s", ()))), "segment_columns": sorted(h.segments),
                "meta_keys": sorted(meta), "has_truth": h.truth is not None,
                "inferred": meta.get("inferred", {}), "import_warnings": meta.get("import_warnings", [])}


def _check_finite(h: H5Recording) -> None:
    for name, ent in h.channels.items():
        bad, first = 0, None
        for a, b in h.row_chunks():
            x = h.read(ent, a, b)
            nb = np.flatnonzero(~np.isfinite(x))
            if nb.size and first is None:
                first = a + int(nb[0])
            bad += nb.size
        if bad:
            t = float(h.read("time_s", first, first + 1)[0])
            raise RecordingError(f"{h.path}: channel '{name}' has {bad} NaN/inf samples (first at t = {t:.6g} s, "
                                 f"sample {first}); drop or interpolate them before use, or remove the channel")


def h5_to_csv(src, dst, overwrite: bool = False) -> Path:
    """Write the HDF5 recording ``src`` as the lab CSV ``dst`` in row chunks: the same bytes as
    ``write_csv(load_h5(src), dst)`` (see :func:`imurig.kernel.labcsv.write_csv`), in memory
    bounded by the chunk."""
    from imurig.kernel.labcsv import _flatten, write_rows   # labcsv imports the recording; one writer of the head

    with H5Recording(src) as h:
        seg = h.segments
        nseg = int(len(seg.get("start_s", ())))
        events = {k: v for k, v in h.events.items() if not (k.startswith("true_") or k.endswith("_true"))}
        marks = {"lo": seg["start_s"], "hi": seg["stop_s"]} if nseg else {}
        idx = h.time_pass({**marks, **{"ev_" + k: v for k, v in events.items()}})
        _check_finite(h)
        ev_idx = {}
        for k in events:
            i = np.clip(idx["ev_" + k], 0, h.n - 1)
            if np.unique(i).size != i.size:
                raise RecordingError(f"events '{k}' are closer than one sample; the CSV cannot hold them")
            ev_idx[k] = i
        labels = _SegmentLabels(idx["lo"], idx["hi"], seg.get("run")) if nseg else None
        meta = dict(h.meta)
        meta["imurig_format"] = 1
        names = ["time_s"] + (["segment"] + (["run"] if "run" in seg else []) if nseg else [])
        fmts = ["%.6f"] + ["%d"] * (len(names) - 1)
        for name, (_, unit, _, _) in h.channels.items():
            names.append(f"{name}_{from_si(np.zeros(1), unit)[1]}")
            fmts.append("%.10g")
        names += [f"event_{k}_s" for k in events]
        fmts += ["%.9f"] * len(events)

        def writer(tmp: Path):
            with open(tmp, "w", encoding="utf-8", newline="\n") as fh:
                for k, v in _flatten(meta).items():
                    fh.write(f"# {k}: {json.dumps(v) if not isinstance(v, str) else v}\n")
                fh.write(",".join(names) + "\n")
                for a, b in h.row_chunks():
                    cols = [h.read("time_s", a, b)]
                    if labels is not None:
                        cols += labels.columns(a, b)
                    cols += [from_si(h.read(ent, a, b), ent[1])[0] for ent in h.channels.values()]
                    for k, ev in events.items():
                        col = np.full(b - a, np.nan)
                        j = (ev_idx[k] >= a) & (ev_idx[k] < b)
                        col[ev_idx[k][j] - a] = ev[j]
                        cols.append(col)
                    # straight to the file: a StringIO of one chunk's text peaks at ~200 MB (measured)
                    write_rows(fh, np.column_stack([np.asarray(c, dtype=float) for c in cols]), fmts)

        return atomic_write(Path(dst), writer, overwrite)


class _SegmentLabels:
    """The ``segment`` and ``run`` columns of write_csv for any rows [a, b), from the segments'
    global sample ranges [lo, hi): a row's segment is the last one holding it (-1 if none); its
    run is that segment's, and a row in no segment takes the run of the next row in one (the last
    such row's run after the last segment), as ``labcsv._fill_between``."""

    def __init__(self, lo: np.ndarray, hi: np.ndarray, run):
        self.lo, self.hi = lo, hi
        self.run = None if run is None else np.asarray(run).astype(int)
        full = np.flatnonzero(lo < hi)
        self._starts = np.unique(lo[full])                     # first rows of the covered stretches
        self._last = int(hi[full].max()) - 1 if full.size else -1
        self._start_runs = np.array([self._run_at(int(r)) for r in self._starts], dtype=np.int64)

    def _seg_at(self, row: int) -> int:
        hold = np.flatnonzero((self.lo <= row) & (row < self.hi))
        return int(hold[-1]) if hold.size else -1

    def _run_at(self, row: int) -> int:
        return int(self.run[self._seg_at(row)]) if self.run is not None else 0

    def columns(self, a: int, b: int) -> list[np.ndarray]:
        seg = np.full(b - a, -1, dtype=np.int64)
        run = np.zeros(b - a, dtype=np.int64)
        for i in np.flatnonzero((self.lo < b) & (self.hi > a) & (self.lo < self.hi)):
            s, e = max(int(self.lo[i]), a) - a, min(int(self.hi[i]), b) - a
            seg[s:e] = i
            if self.run is not None:
                run[s:e] = self.run[i]
        if self.run is None:
            return [seg]
        out = np.flatnonzero(seg < 0)
        if self._starts.size and out.size:
            k = np.searchsorted(self._starts, out + a, side="right")
            last_run = self._run_at(self._last)
            run[out] = np.where(k < self._starts.size, self._start_runs[np.minimum(k, self._starts.size - 1)],
                                last_run)
        return [seg, run]
