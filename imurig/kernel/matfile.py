"""MATLAB recordings (``.mat`` v5 through scipy.io, v7.3 through h5py), read like the lab CSV.

A file in the layout ``imurig export`` writes (``channels`` and ``units`` structs, ``meta_json``)
is read as declared.

The file holds vectors named like the CSV columns (``time_s``, ``theta_deg``, ``acc_x_V``,
``pulse_V`` ...), either as top-level variables or as the fields of one struct. Text variables or
fields ``rig`` and ``site`` (a site name such as 'delft') and a struct ``meta`` (nested structs
for dotted keys, e.g. ``meta.adc.range_V``) carry the metadata. The same inference as for a
minimal lab CSV then applies (:func:`imurig.kernel.labcsv.build_recording`).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from imurig.kernel.errors import RecordingError
from imurig.kernel.import_lab import check_memory
from imurig.kernel.labcsv import build_recording
from imurig.kernel.recording import Recording

TEXT_KEYS = ("rig", "site")


def read_mat(path, rig: str | None = None, site=None, pulse_channel: str | None = None,
             memory_limit_bytes: int | None = None):
    """Read a ``.mat`` file (module doc) into a Recording; RecordingError names what is wrong."""
    import h5py  # heavy: loaded when a MATLAB file is read, not when the CLI starts

    path = Path(path)
    if not path.exists():
        raise RecordingError(f"{path} does not exist")
    if h5py.is_hdf5(path):
        variables = _read_v73(path, memory_limit_bytes)
    else:
        variables = _read_v5(path, memory_limit_bytes)
    if "meta_json" in variables and isinstance(variables.get("channels"), dict):
        return _from_export(variables, path)
    meta = variables.pop("meta", {})
    if not isinstance(meta, dict):
        raise RecordingError(f"{path}: the variable 'meta' must be a struct of metadata")
    for k in TEXT_KEYS:
        if isinstance(variables.get(k), str):
            meta[k] = variables.pop(k)
    arrays = {k: v for k, v in variables.items() if isinstance(v, np.ndarray) and v.ndim == 1 and v.size > 1}
    if "time_s" not in arrays:
        structs = [v for v in variables.values() if isinstance(v, dict)]
        if len(structs) == 1:
            return _from_struct(structs[0], meta, path, rig, site, pulse_channel)
        raise RecordingError(f"{path}: no vector 'time_s' (variables: {sorted(variables)}); name the variables like "
                             "the lab CSV's columns (time_s, theta_deg, acc_x_V ...) or put them in one struct")
    n = arrays["time_s"].size
    bad = [k for k, v in arrays.items() if v.size != n]
    if bad:
        raise RecordingError(f"{path}: vector(s) {bad} do not have the {n} samples of time_s")
    header = ["time_s"] + [k for k in arrays if k != "time_s"]
    return build_recording({k: np.asarray(arrays[k], float) for k in header}, header, meta, str(path), path.name,
                           rig=rig, site=site, pulse_channel=pulse_channel)


def _from_export(v: dict, path: Path):
    """The layout ``imurig export`` writes (SI channels, a units struct, segments, meta as JSON)."""
    meta = json.loads(v["meta_json"])
    units = v.get("units", {})
    channels = {k: np.asarray(x, float).ravel() for k, x in v["channels"].items()}
    missing = [k for k in channels if not isinstance(units.get(k), str)]
    if missing:
        raise RecordingError(f"{path}: channel(s) {missing} have no unit in the 'units' struct")
    events = {k: np.atleast_1d(np.asarray(x, float)).ravel() for k, x in (v.get("events") or {}).items()}
    segments, seg_units = {}, {}
    for k, x in (v.get("segments") or {}).items():
        a = np.atleast_1d(np.asarray(x))
        if k == "segment" or k.startswith("ref_"):
            continue
        if a.dtype.kind in "OUS":
            segments[k], seg_units[k] = a.astype(str), ""
        elif k in ("start_s", "stop_s"):
            segments[k], seg_units[k] = a.astype(float), "s"
        elif k == "run":
            segments[k], seg_units[k] = a.astype(int), "1"
        elif k.endswith("_deg"):
            segments[k[:-4]], seg_units[k[:-4]] = np.radians(a.astype(float)), "rad"
    rec = Recording(time_s=np.asarray(v["time_s"], float).ravel(), channels=channels,
                    units={k: units[k] for k in channels}, segments=segments, segment_units=seg_units,
                    meta=meta, events=events)
    return rec.validate()


def _from_struct(struct: dict, meta: dict, path: Path, rig, site, pulse_channel):
    inner = {k: v for k, v in struct.items()}
    inner_meta = inner.pop("meta", {})
    meta = {**(inner_meta if isinstance(inner_meta, dict) else {}), **meta}
    for k in TEXT_KEYS:
        if isinstance(inner.get(k), str):
            meta[k] = inner.pop(k)
    arrays = {k: np.asarray(v, float).ravel() for k, v in inner.items() if isinstance(v, np.ndarray) and v.size > 1}
    if "time_s" not in arrays:
        raise RecordingError(f"{path}: the struct has no field 'time_s' (fields: {sorted(inner)})")
    header = ["time_s"] + [k for k in arrays if k != "time_s"]
    return build_recording(arrays, header, meta, str(path), path.name, rig=rig, site=site,
                           pulse_channel=pulse_channel)


def _read_v5(path: Path, limit):
    import scipy.io  # heavy: loaded when a MATLAB file is read

    try:
        info = scipy.io.whosmat(path)
    except Exception as e:  # scipy raises several types on a file that is not MAT
        raise RecordingError(f"{path}: not a MATLAB file scipy can read ({e})") from None
    _check(info and [(name, shape) for name, shape, _ in info], path, limit)
    raw = scipy.io.loadmat(path, squeeze_me=True, struct_as_record=False, mat_dtype=False)
    return {k: _plain_v5(v) for k, v in raw.items() if not k.startswith("__")}


def _plain_v5(v):
    if isinstance(v, np.ndarray) and v.dtype.kind == "O":
        return np.array([_plain_v5(e) for e in v.ravel()], dtype=object)
    if hasattr(v, "_fieldnames"):
        return {f: _plain_v5(getattr(v, f)) for f in v._fieldnames}
    if isinstance(v, str):
        return v
    a = np.asarray(v)
    if a.dtype.kind in "US":
        return str(a)
    if a.dtype.kind in "biuf" and a.ndim == 0:
        return a.item()
    return a.ravel() if a.dtype.kind in "biuf" else v


def _read_v73(path: Path, limit):
    import h5py  # heavy: loaded when a MATLAB file is read

    with h5py.File(path, "r") as f:
        shapes = []
        f.visititems(lambda name, obj: shapes.append((name, obj.shape)) if isinstance(obj, h5py.Dataset) else None)
        _check(shapes, path, limit)
        return {k: _plain_v73(f[k]) for k in f if not k.startswith("#")}


def _plain_v73(obj):
    import h5py  # heavy: loaded when a MATLAB file is read

    if isinstance(obj, h5py.Group):
        return {k: _plain_v73(obj[k]) for k in obj}
    cls = obj.attrs.get("MATLAB_class", b"")
    cls = cls.decode() if isinstance(cls, bytes) else str(cls)
    x = obj[()]
    if cls == "char":
        return "".join(chr(int(c)) for c in np.asarray(x).ravel())
    a = np.asarray(x)
    if a.size == 1:
        return a.ravel()[0].item()
    return a.ravel()


def _check(shapes, path, limit):
    """Memory: the largest vector length x the number of vectors."""
    sizes = [int(np.prod(s)) for _, s in (shapes or []) if len(s)]
    if sizes:
        check_memory(max(sizes), len(sizes), str(path), limit)
