"""The plain lab CSV format (import and export).

A file is a block of ``# key: value`` metadata lines, then one header row, then
numbers::

    # imurig_format: 1
    # rig: tilt_table
    # site.latitude_deg: 52.0
    # site.longitude_deg: 4.37
    # site.altitude_m: 0.0
    # site.gravity_m_s2: 9.81242231
    # start_time: 2005-06-01T18:00:00+00:00
    # setpoints: ["theta", "phi"]
    time_s,segment,run,theta_deg,phi_deg,acc_x_V,acc_y_V,acc_z_V,temp_box_V
    0.000,-1,0,0.0,0.0,0.00218,-0.00113,0.99731,2.98201
    ...

Rules
- Every column but ``segment`` and ``run`` ends in a unit suffix (``_V``, ``_deg``,
  ``_dps``, ``_m_s2``, ``_degC``, ``_nT`` ...; see :mod:`imurig.kernel.units`). Values are
  converted to SI on import.
- ``time_s`` is required and must increase strictly.
- ``segment`` (optional, integer): the acquisition window a row belongs to, ``-1`` while
  the rig moves. Without it, segments are the runs of constant set-point values.
- ``setpoints`` (metadata): the columns that hold commanded values (constant within a
  segment); they become the segments table, and stay channels too.
- Metadata values are JSON when they parse as JSON, text otherwise; dotted keys nest.
- ``event_<name>_s`` columns (optional) hold discrete event time stamps (e.g. pulse
  times from a counter) on the row nearest each event and are empty (``nan``) elsewhere.
- ``#`` lines without ``key: value`` are comments.
"""
from __future__ import annotations

import json
import re
import warnings
from pathlib import Path

import numpy as np

from imurig.kernel.errors import RecordingError
from imurig.kernel.import_lab import check_memory, columns_to_channels, count_rows, infer_structure, is_minimal
from imurig.kernel.infer import resolve_site
from imurig.kernel.outputs import atomic_write
from imurig.kernel.recording import Recording
from imurig.kernel.units import from_si, split_column



def _parse_value(text: str):
    try:
        return json.loads(text)
    except (json.JSONDecodeError, ValueError):
        return text


def _nest(flat: dict) -> dict:
    out: dict = {}
    for key, val in flat.items():
        d = out
        parts = key.split(".")
        for p in parts[:-1]:
            d = d.setdefault(p, {})
            if not isinstance(d, dict):
                raise RecordingError(f"metadata key '{key}' clashes with a plain value of '{p}'")
        d[parts[-1]] = val
    return out


def _flatten(d: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(_flatten(v, key + "."))
        else:
            out[key] = v
    return out


def read_csv(path, rig: str | None = None, site=None, pulse_channel: str | None = None,
             memory_limit_bytes: int | None = None) -> Recording:
    """Read a lab CSV into a Recording (SI inside). Raises RecordingError with the fix.

    A file without a ``segment`` column and without ``# setpoints:`` is a minimal lab file: its
    structure is inferred and reported (:func:`imurig.kernel.import_lab.infer_structure`); ``rig``,
    ``site`` (a name such as 'delft') and ``pulse_channel`` stand in for what the file lacks.
    """
    path = Path(path)
    if not path.exists():
        raise RecordingError(f"{path} does not exist")
    meta_flat, header, n_head = _read_head(path)
    check_memory(count_rows(path) - n_head, len(header), str(path), memory_limit_bytes)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)          # "input contained no data": refused below
            data = np.loadtxt(path, delimiter=",", skiprows=n_head, ndmin=2, dtype=float)
    except ValueError as exc:
        m = re.search(r"number of columns changed from (\d+) to (\d+) at row (\d+)", str(exc))
        if m:
            raise RecordingError(f"{path}: data row {int(m[3]) + 1} has {m[2]} values, the rows before it "
                                 f"{m[1]}; every row needs one value per header name (a cut-off last line?)") from None
        sep = next((name for ch, name in ((";", "';'"), ("\t", "a tab")) if ch in "".join(header) + str(exc)), None)
        if sep:
            raise RecordingError(f"{path}: the values are separated by {sep}; imurig reads comma-separated "
                                 "values with '.' as decimal point: save the file as CSV with ',' between "
                                 "values (and '.' in numbers)") from None
        raise RecordingError(f"{path}: a value is not a number ({exc}); use '.' as decimal point and "
                             "'nan' for missing values") from None
    if data.size == 0:
        raise RecordingError(f"{path}: the header has no data rows below it")
    if data.shape[1] != len(header):
        raise RecordingError(f"{path}: {data.shape[1]} values per row but {len(header)} header names")
    cols = {h: data[:, i] for i, h in enumerate(header)}
    del data
    meta = _nest(meta_flat)
    return build_recording(cols, header, meta, str(path), path.name, rig=rig, site=site,
                           pulse_channel=pulse_channel)


def build_recording(cols: dict, header: list[str], meta: dict, where: str, source: str, rig=None, site=None,
                    pulse_channel=None) -> Recording:
    """Named columns (``time_s``, ``name_unit`` ..., optional ``segment``/``run``) and metadata to a
    validated Recording: as declared, or inferred for a minimal file (see :func:`read_csv`)."""
    if "time_s" not in header:
        raise RecordingError(f"{where}: no 'time_s' column; the lab format needs a time column in seconds "
                             f"(columns are {header})")
    channels, units, events, notes = columns_to_channels(cols, meta, where)
    rec = Recording(time_s=cols["time_s"], channels=channels, units=units, meta=meta, events=events)
    rec.meta.setdefault("source", source)
    minimal = is_minimal(header, meta)
    if minimal:
        _check_time(rec, where)
        order = [split_name(h) for h in header if h != "time_s"]
        infer_structure(rec, where, order, rig=rig, site=site, pulse_channel=pulse_channel, column_notes=notes)
        return rec.validate()
    if rig:
        rec.meta["rig"] = rig.replace("-", "_")
    if site is not None or isinstance(meta.get("site"), str):
        resolve_site(rec, site, where)
    setpoints = meta.get("setpoints", [])
    if isinstance(setpoints, str):
        setpoints = [s.strip() for s in setpoints.split(",") if s.strip()]
        meta["setpoints"] = setpoints
    if not isinstance(setpoints, list) or not all(isinstance(sp, str) for sp in setpoints):
        raise RecordingError(f"{where}: '# setpoints:' must list column names, e.g. "
                             f"'# setpoints: [\"theta\", \"phi\"]', not {setpoints!r}")
    for sp in setpoints:
        if sp not in channels:
            raise RecordingError(f"{where}: metadata names set-point '{sp}' but there is no column '{sp}_<unit>'")
    rec.validate()
    rec.segments, rec.segment_units = _segments_from_columns(rec, cols.get("segment"), cols.get("run"), setpoints)
    return rec.validate()


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _read_head(path: Path):
    meta_flat: dict = {}
    header = None
    n_head = 0
    with open(path, "rb") as fh:
        for raw in fh:
            n_head += 1
            try:
                line = raw.decode("utf-8")
            except UnicodeDecodeError as e:
                raise RecordingError(f"{path}: line {n_head} is not UTF-8 text (byte {raw[e.start]:#04x} at "
                                     f"column {e.start + 1}); save the file as UTF-8 (or plain ASCII)") from None
            if n_head == 1:
                line = line.lstrip("\ufeff")            # a byte-order mark some editors write
            s = line.strip()
            if not s:
                continue
            if s.startswith("#"):
                body = s[1:].strip()
                if ":" in body:
                    key, _, val = body.partition(":")
                    key = key.strip()
                    if key and " " not in key:
                        meta_flat[key] = _parse_value(val.strip())
                continue
            header = [h.strip() for h in s.split(",")]
            break
    if header is not None and all(_is_number(h) for h in header):
        raise RecordingError(f"{path}: the first line after the '#' metadata holds numbers ({s[:40]}...), not "
                             "column names; add a header row such as 'time_s,theta_deg,phi_deg,acc_x_V,...'")
    if header is None:
        raise RecordingError(f"{path}: no header row found after the '#' metadata block")
    if len(set(header)) != len(header):
        dup = sorted({h for h in header if header.count(h) > 1})
        raise RecordingError(f"{path}: duplicate columns {dup}")
    return meta_flat, header, n_head


def _check_time(rec: Recording, where: str) -> None:
    t = rec.time_s
    if t.size < 2 or not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        try:
            rec.validate()
        except RecordingError as e:
            raise RecordingError(f"{where}: {e}") from None


def split_name(header: str) -> str:
    """The channel name of a column header (its unit suffix dropped)."""
    if header.endswith("_counts"):
        return header[:-7]
    return header.rpartition("_")[0] if header.endswith("_g") else split_column(header)[0]


def _segments_from_columns(rec: Recording, seg_id, run, setpoints):
    t = rec.time_s
    dt = float(np.median(np.diff(t)))
    if seg_id is not None:
        if not np.all(np.isfinite(seg_id)) or np.any(seg_id != np.round(seg_id)):
            raise RecordingError("the 'segment' column must hold integers (-1 while the rig moves)")
        key = seg_id
        valid = seg_id >= 0
    elif setpoints:
        sp = np.stack([rec.channels[s] for s in setpoints], axis=1)
        change = np.any(np.diff(sp, axis=0) != 0, axis=1)
        key = np.concatenate(([0], np.cumsum(change)))
        valid = np.ones(t.size, bool)
    else:
        return {}, {}
    brk = np.flatnonzero((np.diff(key) != 0) | (np.diff(valid.astype(int)) != 0)) + 1
    starts = np.concatenate(([0], brk))
    stops = np.concatenate((brk, [t.size]))
    keep = valid[starts]
    starts, stops = starts[keep], stops[keep]
    seg = {"start_s": t[starts], "stop_s": t[stops - 1] + dt}
    units = {"start_s": "s", "stop_s": "s"}
    if run is not None:
        if not np.all(np.isfinite(run[starts])):
            raise RecordingError("the 'run' column has NaN/inf values at the start of a segment; give every row "
                                 "of a segment its run number (0, 1, ...) or leave the column out")
        seg["run"] = run[starts].astype(int)
        units["run"] = "1"
    for s in setpoints:
        x = rec.channels[s]
        seg[s] = np.array([np.median(x[a:b]) for a, b in zip(starts, stops)])
        units[s] = rec.units[s]
    return seg, units


def write_csv(rec: Recording, path, overwrite: bool = False, include_truth_signals: bool = False) -> Path:
    """Write ``rec`` in the lab CSV format (no truth parameters; see module doc)."""
    rec.validate()
    meta = dict(rec.meta)
    meta["imurig_format"] = 1
    cols = {"time_s": (rec.time_s, "%.6f")}
    sl = rec.segment_slices() if rec.n_segments else []
    if sl:
        seg = np.full(rec.n, -1, dtype=np.int64)
        for i, s in enumerate(sl):
            seg[s] = i
        cols["segment"] = (seg, "%d")
        if "run" in rec.segments:
            run = np.zeros(rec.n, dtype=np.int64)
            for r, s in zip(rec.segments["run"], sl):
                run[s] = r
            # rows between segments take the run of the following segment
            cols["run"] = (_fill_between(run, seg), "%d")
    sources = [(rec.channels, rec.units)]
    if include_truth_signals:
        sources.append(({"true_" + k: v for k, v in rec.truth_signals.items()},
                        {"true_" + k: u for k, u in rec.truth_units.items()}))
    for arrays, units in sources:
        for name, x in arrays.items():
            vals, suf = from_si(x, units[name])
            cols[f"{name}_{suf}"] = (vals, "%.10g")
    for name, ev in rec.events.items():
        if name.startswith("true_") or name.endswith("_true"):
            continue
        col = np.full(rec.n, np.nan)
        idx = np.clip(np.searchsorted(rec.time_s, ev), 0, rec.n - 1)
        if np.unique(idx).size != idx.size:
            raise RecordingError(f"events '{name}' are closer than one sample; the CSV cannot hold them")
        col[idx] = ev
        cols[f"event_{name}_s"] = (col, "%.9f")
    header = ",".join(cols)
    fmts = [f for _, f in cols.values()]
    table = np.column_stack([np.asarray(v, dtype=float) for v, _ in cols.values()])

    def writer(tmp: Path):
        with open(tmp, "w", encoding="utf-8", newline="\n") as fh:
            for k, v in _flatten(meta).items():
                fh.write(f"# {k}: {json.dumps(v) if not isinstance(v, str) else v}\n")
            fh.write(header + "\n")
            write_rows(fh, table, fmts)

    return atomic_write(Path(path), writer, overwrite)


#: rows formatted per text block of :func:`write_rows` (~4 MB of text at 60 characters a row)
ROWS_PER_BLOCK = 1 << 16


def write_rows(fh, table: np.ndarray, fmts: list[str]) -> None:
    """Write ``table`` (rows, columns) to the text file ``fh`` as comma-separated lines, column j
    formatted with ``fmts[j]``: the same text as ``np.savetxt(fh, table, fmt=fmts, delimiter=",")``,
    made by one ``%`` operation per block of rows instead of one per row (about half the CPU)."""
    line = ",".join(fmts) + "\n"
    for a in range(0, table.shape[0], ROWS_PER_BLOCK):
        block = table[a:a + ROWS_PER_BLOCK]
        fh.write((line * block.shape[0]) % tuple(block.ravel().tolist()))


def _fill_between(run: np.ndarray, seg: np.ndarray) -> np.ndarray:
    """Give rows outside segments (seg == -1) the run of the next segment (last one at the end)."""
    out = run.copy()
    idx = np.flatnonzero(seg >= 0)
    if idx.size == 0:
        return out
    nxt = np.searchsorted(idx, np.arange(run.size))
    nxt = np.clip(nxt, 0, idx.size - 1)
    out[seg < 0] = run[idx[nxt]][seg < 0]
    return out
