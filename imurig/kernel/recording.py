"""One kind of object for simulated and measured data: the Recording.

A Recording holds
- ``time_s`` (n,): sample times in seconds, strictly increasing; gaps are allowed
  (e.g. between two runs when the IMU is remounted) and split the record into blocks;
- ``channels``: name -> (n,) float64 array in SI, with ``units[name]`` its SI unit;
- ``segments``: a small table (one row per experiment position / rate / step) with
  ``start_s`` and ``stop_s`` (the acquisition window) and the set-points of that
  row (e.g. ``theta``, ``phi`` in rad, ``run``); units in ``segment_units``;
- ``meta``: rig, site, start time, sample rate, seed, lab settings (JSON-like);
- ``truth`` (simulation only): every injected parameter, JSON-like, and
  ``truth_signals``: name -> (n,) SI arrays (e.g. true specific force);
- ``events``: name -> sorted time stamps (s) of discrete events, e.g. the turn table's
  once-per-round pulses as time-tagged by a counter (``pulse_hp6700``); names starting
  with ``true_`` or ending in ``_true`` are truth and are dropped by ``without_truth``.

Storage: HDF5 (h5py), see :func:`save_h5`; lab exchange: CSV with ``# key: value``
metadata lines, see :mod:`imurig.kernel.labcsv`; either by its suffix:
:func:`imurig.kernel.files.load`.
"""
from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from imurig.kernel.errors import RecordingError
from imurig.kernel.outputs import atomic_write, to_json

FORMAT_NAME = "imurig-recording"
FORMAT_VERSION = 1


@dataclass
class Recording:
    """Time series of named SI channels, their set-points, metadata and (simulated) truth."""

    time_s: np.ndarray
    channels: dict[str, np.ndarray]
    units: dict[str, str]
    segments: dict[str, np.ndarray] = field(default_factory=dict)
    segment_units: dict[str, str] = field(default_factory=dict)
    meta: dict[str, Any] = field(default_factory=dict)
    truth: dict[str, Any] | None = None
    truth_signals: dict[str, np.ndarray] = field(default_factory=dict)
    truth_units: dict[str, str] = field(default_factory=dict)
    channel_quantum: dict[str, float] = field(default_factory=dict)
    events: dict[str, np.ndarray] = field(default_factory=dict)

    # ------------------------------------------------------------------ checks
    def __post_init__(self):
        self.time_s = np.asarray(self.time_s, dtype=float)
        self.channels = {k: np.asarray(v, dtype=float) for k, v in self.channels.items()}
        self.segments = {k: np.asarray(v) for k, v in self.segments.items()}
        self.events = {k: np.asarray(v, dtype=float) for k, v in self.events.items()}

    @property
    def n(self) -> int:
        return int(self.time_s.shape[0])

    @property
    def n_segments(self) -> int:
        return int(len(self.segments.get("start_s", ())))

    def validate(self) -> "Recording":
        """Check shapes, units, finiteness and time order; raise RecordingError with a fix."""
        t = self.time_s
        if t.ndim != 1 or t.size < 2:
            raise RecordingError("time_s must be a 1-D array with at least two samples")
        if not np.all(np.isfinite(t)):
            bad = np.flatnonzero(~np.isfinite(t))
            raise RecordingError(f"time_s has {bad.size} non-finite values (first at sample {bad[0]}); "
                                 "remove those rows or fill in the time stamps")
        if np.any(np.diff(t) <= 0):
            i = int(np.flatnonzero(np.diff(t) <= 0)[0])
            raise RecordingError(f"time_s must increase strictly; it does not at sample {i + 1} "
                                 f"({t[i]!r} -> {t[i + 1]!r}); sort the rows or fix the clock")
        for name, x in self.channels.items():
            if x.shape != t.shape:
                raise RecordingError(f"channel '{name}' has {x.shape[0]} samples but time_s has {t.size}")
            if name not in self.units:
                raise RecordingError(f"channel '{name}' has no unit; give it one (e.g. name the CSV column "
                                     f"'{name}_V')")
            if not np.all(np.isfinite(x)):
                bad = np.flatnonzero(~np.isfinite(x))
                raise RecordingError(
                    f"channel '{name}' has {bad.size} NaN/inf samples (first at t = {t[bad[0]]:.6g} s, "
                    f"sample {bad[0]}); drop or interpolate them before use, or remove the channel")
        if self.segments:
            for col in ("start_s", "stop_s"):
                if col not in self.segments:
                    raise RecordingError(f"segments table lacks '{col}'")
            m = self.n_segments
            for k, v in self.segments.items():
                if v.shape[0] != m:
                    raise RecordingError(f"segment column '{k}' has {v.shape[0]} rows, expected {m}")
            if np.any(self.segments["stop_s"] <= self.segments["start_s"]):
                raise RecordingError("a segment ends before it starts; check start_s/stop_s")
        return self

    def require(self, needed: Mapping[str, str]) -> None:
        """Check that each channel in ``needed`` (name -> SI unit) exists with that unit.

        Raises RecordingError naming the missing or mislabelled channel and the fix. A channel the
        import found in physical units (``meta["physical_unit_channels"]``: name -> SI unit, e.g.
        m/s^2 from a maker-scaled logger) meets a "V" requirement: it stands for volts with an
        effective sensitivity of 1 V per SI unit, which the import writes into the nominal
        sensitivity metadata.
        """
        physical = self.meta.get("physical_unit_channels", {}) if isinstance(self.meta, dict) else {}
        missing = [k for k in needed if k not in self.channels]
        if missing:
            raise RecordingError(
                f"recording lacks channel(s) {missing}; it has {sorted(self.channels)}. "
                f"Add them (CSV columns such as '{missing[0]}_V') or rename the existing columns")
        for k, unit in needed.items():
            if self.units[k] != unit and not (unit == "V" and physical.get(k) == self.units[k]):
                raise RecordingError(
                    f"channel '{k}' is in {self.units[k]} but {unit} is needed; if the data are really "
                    f"in {unit}, fix the unit suffix of the CSV column, otherwise convert them")

    # --------------------------------------------------------------- helpers
    def blocks(self, max_gap_factor: float = 1.5) -> list[slice]:
        """Contiguous sample blocks: a gap longer than ``max_gap_factor`` sample periods splits."""
        dt = np.diff(self.time_s)
        return time_blocks(dt, float(median_step(dt)), self.n, max_gap_factor)

    @property
    def sample_rate_hz(self) -> float:
        return float(1.0 / median_step(np.diff(self.time_s)))

    def segment_slices(self) -> list[slice]:
        """Sample index range of each segment's acquisition window [start_s, stop_s)."""
        lo = np.searchsorted(self.time_s, self.segments["start_s"], side="left")
        hi = np.searchsorted(self.time_s, self.segments["stop_s"], side="left")
        return [slice(int(a), int(b)) for a, b in zip(lo, hi)]

    def stack(self, names) -> np.ndarray:
        """Channels ``names`` as an (n, len(names)) array."""
        return np.stack([self.channels[k] for k in names], axis=1)

    def replace(self, **changes) -> "Recording":
        return dataclasses.replace(self, **changes)

    def without_truth(self) -> "Recording":
        """A copy that holds no truth (what an outside estimator may see)."""
        return self.replace(truth=None, truth_signals={}, truth_units={},
                            events={k: v for k, v in self.events.items()
                                    if not (k.startswith("true_") or k.endswith("_true"))})


class TimeFrame:
    """A record's time grid and segments without its signals: what a windowed filter reads of a
    :class:`Recording` (``sample_rate_hz``, :meth:`blocks`, :meth:`segment_slices`), the same values,
    with the median time step found once (on a long record each ``Recording`` call sorts its n steps)."""

    def __init__(self, time_s: np.ndarray, segments: Mapping[str, np.ndarray]):
        self.time_s, self.segments = time_s, segments
        dt = np.diff(time_s)
        median = median_step(dt)
        self.sample_rate_hz = float(1.0 / median)
        self._dt, self._median = dt, float(median)

    @property
    def n(self) -> int:
        return int(self.time_s.shape[0])

    def blocks(self, max_gap_factor: float = 1.5) -> list[slice]:
        return time_blocks(self._dt, self._median, self.n, max_gap_factor)

    segment_slices = Recording.segment_slices


def median_step(dt: np.ndarray) -> np.float64:
    """np.median(dt), the same value, without sorting a copy of all n time steps where one value holds the
    middle (a record's steps repeat the sample period and a few rounding neighbours; np.median copies and
    partitions them: 0.1 s for a 7.4 M-sample record).

    A subsample's median c is the median if the sorted steps' middle element(s), ranks (n-1)//2 and n//2,
    are among those equal to c: #{dt < c} <= (n-1)//2 < n//2 < #{dt <= c} (np.median's mean of two equal
    middles is c). Else, or with NaNs, np.median itself."""
    dt = np.asarray(dt)
    n = dt.size
    if n < 4096 or dt.dtype.kind != "f":
        return np.median(dt)
    c = np.median(dt[:: n // 2048])
    below, upto = np.count_nonzero(dt < c), np.count_nonzero(dt <= c)
    if upto + np.count_nonzero(dt > c) == n and below <= (n - 1) // 2 and n // 2 < upto:
        return np.float64(c)
    return np.median(dt)


def time_blocks(dt: np.ndarray, nominal_s: float, n: int, max_gap_factor: float = 1.5) -> list[slice]:
    """The contiguous blocks of a record of ``n`` samples whose time steps are ``dt`` = diff(time_s) and
    whose sample period is ``nominal_s`` (the median step): a step longer than ``max_gap_factor`` periods
    splits (:meth:`Recording.blocks`)."""
    cuts = np.flatnonzero(dt > max_gap_factor * nominal_s) + 1
    edges = np.concatenate(([0], cuts, [n]))
    return [slice(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]


# ---------------------------------------------------------------------- HDF5
def _write_group(grp, arrays: Mapping[str, np.ndarray], units: Mapping[str, str],
                 quantum: Mapping[str, float] | None = None):
    for name, x in arrays.items():
        x = np.asarray(x)
        if x.dtype.kind in "US":
            import h5py  # heavy: loaded when a file is written, not when the CLI starts

            ds = grp.create_dataset(name, data=x.astype(str).astype(object), dtype=h5py.string_dtype())
            ds.attrs["unit"] = units.get(name, "")
            continue
        q = (quantum or {}).get(name)
        stored = _codes(x, q) if q else None
        if stored is None:
            stored, q = x, None
        kw = dict(compression="gzip", compression_opts=1, shuffle=True) if x.size > 4096 else {}
        ds = grp.create_dataset(name, data=stored, **kw)
        ds.attrs["unit"] = units.get(name, "")
        if q and stored is not x:
            ds.attrs["quantum"] = q


def _codes(x: np.ndarray, q: float, chunk: int = 1 << 18) -> np.ndarray | None:
    """x / q as the narrowest integers that hold them (int16 for a 16-bit converter, else int32) when
    every x is exactly code * q, else None (stored as floats). Checked in row pieces: memory for one
    piece, not three full-length temporaries."""
    if x.dtype.kind != "f" or x.ndim != 1:
        return None
    out = np.empty(x.shape, np.int32)
    lo = hi = 0
    for a in range(0, x.size, chunk):
        c = np.round(x[a:a + chunk] / q)
        if c.size and not (np.all(np.abs(c) < 2**31) and np.array_equal(c * q, x[a:a + chunk])):
            return None
        out[a:a + chunk] = c
        if c.size:
            lo, hi = min(lo, int(c.min())), max(hi, int(c.max()))
    return out.astype(np.int16) if -2**15 < lo and hi < 2**15 else out


def _read_group(grp, path, where: str, text: bool = False):
    """{name: array}, {name: unit}, {name: quantum} of an HDF5 group of 1-D numeric datasets (text
    allowed with ``text``, for segment labels)."""
    import h5py  # heavy: loaded when a file is read

    arrays, units, quantum = {}, {}, {}
    if not isinstance(grp, h5py.Group):
        raise RecordingError(f"{path}: '/{where}' must be a group of datasets, found a {type(grp).__name__}; "
                             "write the file with imurig (imurig convert) or fix its layout")
    for name in grp:
        ds = grp.get(name)
        if not isinstance(ds, h5py.Dataset):
            raise RecordingError(f"{path}: '/{where}/{name}' must be a dataset, found "
                                 f"{'a dangling or external link' if ds is None else type(ds).__name__}")
        x = ds[()]
        if np.ndim(x) != 1:
            raise RecordingError(f"{path}: '/{where}/{name}' must be a 1-D array, it has shape {np.shape(x)}")
        if ds.dtype.kind in "OS" and not text:
            raise RecordingError(f"{path}: '/{where}/{name}' holds text; it must hold numbers")
        if ds.dtype.kind in "OS":
            x = np.array([v.decode("utf-8", "replace") if isinstance(v, bytes) else str(v) for v in x], dtype=str)
        elif ds.dtype.kind not in "biuf":
            raise RecordingError(f"{path}: '/{where}/{name}' holds {ds.dtype} values; numbers (or text for "
                                 "segment labels) are needed")
        if "quantum" in ds.attrs:
            q = _float_attr(ds.attrs["quantum"], path, f"/{where}/{name} quantum")
            if x.dtype.kind not in "biuf":
                raise RecordingError(f"{path}: '/{where}/{name}' has a quantum but holds text")
            x = x.astype(np.float64) * q
            quantum[name] = q
        arrays[name] = x
        u = ds.attrs.get("unit", "")
        units[name] = u.decode("utf-8", "replace") if isinstance(u, bytes) else str(u)
    return arrays, units, quantum


def _float_attr(v, path, what: str) -> float:
    try:
        q = float(np.asarray(v).item())
    except (TypeError, ValueError) as e:
        raise RecordingError(f"{path}: {what} must be a number, found {v!r}") from e
    if not np.isfinite(q) or q <= 0:
        raise RecordingError(f"{path}: {what} must be a positive number, found {q!r}")
    return q


def _json_attr(attrs, key: str, path, required: bool):
    """A JSON attribute (text) decoded, or None when absent and not required."""
    if key not in attrs:
        if required:
            raise RecordingError(f"{path}: the root attribute '{key}' (JSON text) is missing; write the file "
                                 "with imurig (imurig convert)")
        return None
    v = attrs[key]
    if isinstance(v, bytes):
        v = v.decode("utf-8", "replace")
    if not isinstance(v, str):
        raise RecordingError(f"{path}: the root attribute '{key}' must be JSON text, found {type(v).__name__}")
    try:
        d = json.loads(v)
    except json.JSONDecodeError as e:
        raise RecordingError(f"{path}: the root attribute '{key}' is not valid JSON ({e.msg} at character "
                             f"{e.pos})") from e
    if not isinstance(d, dict):
        raise RecordingError(f"{path}: the root attribute '{key}' must be a JSON object, found {type(d).__name__}")
    return d


def save_h5(rec: Recording, path, overwrite: bool = False) -> Path:
    """Save losslessly to HDF5.

    Layout: root attrs ``format``, ``version``, ``meta`` (JSON), ``truth`` (JSON or absent);
    datasets ``/time_s``, ``/channels/<name>``, ``/segments/<col>``, ``/truth_signals/<name>``,
    ``/events/<name>`` (time stamps),
    each with an attribute ``unit``. ADC channels whose values are exact multiples of their
    quantum (one LSB, attribute ``quantum``) are stored as integer codes (int16 when they fit,
    else int32), which is lossless; large datasets are chunked and gzip-compressed.
    """
    import h5py  # heavy: loaded when a file is written, not when the CLI starts

    rec.validate()

    def writer(tmp: Path):
        with h5py.File(tmp, "w") as f:
            f.attrs["format"] = FORMAT_NAME
            f.attrs["version"] = FORMAT_VERSION
            f.attrs["meta"] = to_json(rec.meta)
            if rec.truth is not None:
                f.attrs["truth"] = to_json(rec.truth)
            f.create_dataset("time_s", data=rec.time_s, compression="gzip", compression_opts=1, shuffle=True)
            _write_group(f.create_group("channels"), rec.channels, rec.units, rec.channel_quantum)
            _write_group(f.create_group("segments"), rec.segments, rec.segment_units)
            _write_group(f.create_group("truth_signals"), rec.truth_signals, rec.truth_units)
            _write_group(f.create_group("events"), rec.events, {k: "s" for k in rec.events})

    return atomic_write(Path(path), writer, overwrite)


def load_h5(path) -> Recording:
    """Load a recording written by :func:`save_h5` (bit-exact). Anything else, or a damaged file, is
    refused with a :class:`RecordingError` that names the file, what is wrong and how to fix it."""
    import h5py  # heavy: loaded when a file is read, not when the CLI starts

    path = Path(path)
    if not path.exists():
        raise RecordingError(f"{path} does not exist")
    try:
        f = h5py.File(path, "r")
    except OSError as e:
        raise RecordingError(f"{path} is not a readable HDF5 file ({e}); give an imurig .h5 recording or a "
                             "lab .csv/.mat file") from e
    try:
        with f:
            fmt = f.attrs.get("format")
            if (fmt.decode("utf-8", "replace") if isinstance(fmt, bytes) else fmt) != FORMAT_NAME:
                raise RecordingError(f"{path} is not an imurig recording (no format attribute '{FORMAT_NAME}')")
            meta = _json_attr(f.attrs, "meta", path, required=True)
            truth = _json_attr(f.attrs, "truth", path, required=False)
            for key in ("time_s", "channels", "segments"):
                if f.get(key) is None:
                    raise RecordingError(f"{path}: '/{key}' is missing (or a dangling link); write the file with "
                                         "imurig (imurig convert)")
            channels, units, quantum = _read_group(f["channels"], path, "channels")
            segments, seg_units, _ = _read_group(f["segments"], path, "segments", text=True)
            tsig, tunits, _ = _read_group(f["truth_signals"], path, "truth_signals") if "truth_signals" in f \
                else ({}, {}, {})
            events = _read_group(f["events"], path, "events")[0] if "events" in f else {}
            ts = f["time_s"]
            if not isinstance(ts, h5py.Dataset) or ts.ndim != 1 or ts.dtype.kind not in "iuf":
                raise RecordingError(f"{path}: '/time_s' must be a 1-D numeric dataset")
            time_s = ts[()]
    except RecordingError:
        raise
    except (OSError, KeyError, TypeError, ValueError, RuntimeError) as e:   # a damaged file: h5py's own errors
        raise RecordingError(f"{path}: the HDF5 file is damaged or not laid out as imurig writes it "
                             f"({type(e).__name__}: {e}); write it again with imurig") from e
    for k, v in segments.items():
        if v.dtype.kind == "f" and not np.all(np.isfinite(v)):
            raise RecordingError(f"{path}: segment column '{k}' has NaN/inf values")
    rec = Recording(time_s=time_s, channels=channels, units=units, segments=segments,
                    segment_units=seg_units, meta=meta, truth=truth, truth_signals=tsig,
                    truth_units=tunits, channel_quantum=quantum, events=events)
    try:
        return rec.validate()
    except RecordingError as e:
        raise RecordingError(f"{path}: {e}") from e