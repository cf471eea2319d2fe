"""The files of a Monte-Carlo study that hold its data: results.h5 (the results table) and
text files written atomically. Reports (summary.json, report.md, figures, study.rrd) are
written by :mod:`imurig.reports.montecarlo`.

results.h5 (the project's binary format, h5py; one row per run, one column per parameter):

    /run                (N,)      run index i (its seed: the stream "montecarlo/run" of (master_seed, i))
    /parameters         (P,)      parameter names;  attrs units (P,)
    /estimate, /std_error, /injected, /crlb, /z   (N, P) float64 (NaN where absent)
    /info/<key>         (N,)      per-run wall time, samples, ...
    attrs["config"]     JSON of the study config (campaign, params, master seed, distributions)
"""
from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np

from imurig.kernel.outputs import atomic_write
from imurig.montecarlo.stats import table_arrays

RESULTS_FORMAT = "imurig.montecarlo.results v1"


def atomic_text(path: Path, text: str) -> Path:
    """Write ``text`` to ``path`` through a temporary file renamed when complete (replaces ``path``)."""
    return atomic_write(Path(path), lambda tmp: tmp.write_text(text), overwrite=True)


def write_results_h5(path: Path, study) -> Path:
    """The results table of ``study`` (module doc), written atomically."""
    idx, names, units, A = table_arrays(study.rows)

    def writer(tmp: Path):
        with h5py.File(tmp, "w") as f:
            f.attrs["config"] = json.dumps(study.config)
            f.attrs["format"] = RESULTS_FORMAT
            f.create_dataset("run", data=idx)
            f.create_dataset("parameters", data=np.array(names, dtype=h5py.string_dtype()))
            f["parameters"].attrs["units"] = np.array(units, dtype=h5py.string_dtype())
            for k, v in A.items():
                f.create_dataset(k, data=v, compression="gzip")
            g = f.create_group("info")
            keys = sorted({k for r in study.runs.values() for k, v in r["info"].items()
                           if isinstance(v, (int, float))})
            for k in keys:
                g.create_dataset(k, data=np.array([float(study.runs[i]["info"].get(k, np.nan)) for i in idx]))

    return atomic_write(Path(path), writer, overwrite=True)


def read_results_h5(path) -> dict:
    """The results table as numpy arrays (names, run, estimate, ...)."""
    with h5py.File(path, "r") as f:
        out = {k: f[k][()] for k in ("run", "estimate", "std_error", "injected", "crlb", "z")}
        out["parameters"] = [s.decode() if isinstance(s, bytes) else s for s in f["parameters"][()]]
        out["config"] = json.loads(f.attrs["config"])
        out["info"] = {k: f["info"][k][()] for k in f["info"]}
    return out
