"""Estimate files: the documented CSV and JSON a user's code writes for ``imurig score``.

CSV (``#`` lines are comments; exactly these four columns, in any order)::

    name,value,std_error,unit
    sensitivity_x,0.1017912,1.1e-06,V/(m/s^2)
    bias_x,3.3,0.09,mg
    misalignment_xy,0.77,0.015,mrad

JSON: ``{"parameters": [{"name": ..., "value": ..., "std_error": ..., "unit": ...}, ...]}``,
or the bare list, or ``{"<name>": {"value": ..., "std_error": ..., "unit": ...}, ...}``.

``value`` may also be called ``estimate`` (the bench's parameter-row name). ``unit`` may be
any unit of the right dimension (:mod:`imurig.scoring.units`); values are converted.
Missing, unknown, duplicate and NaN rows, non-positive standard errors and units of the
wrong dimension are refused with a message naming every offending row.
"""
from __future__ import annotations

import csv
import json
import math
from pathlib import Path

from imurig.kernel.outputs import atomic_write
from imurig.scoring.interface import (
    EstimatesError,
    ParameterEstimate,
    normalise_estimates,
)

COLUMNS = ("name", "value", "std_error", "unit")


def _num(text: str, what: str, where: str) -> float:
    t = text.strip()
    if t == "":
        return math.nan
    try:
        return float(t)
    except ValueError:
        raise EstimatesError(f"{where}: {what} {text!r} is not a number (use '.' as decimal point)") from None


def read_estimates_csv(path) -> list[ParameterEstimate]:
    p = Path(path)
    if not p.exists():
        raise EstimatesError(f"estimates file {p} does not exist")
    try:
        text = p.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as e:
        raise EstimatesError(f"{p} is not UTF-8 text (byte {e.object[e.start]:#04x} at {e.start}); write the "
                             "estimates as a UTF-8 CSV 'name,value,std_error,unit'") from None
    lines = [(i + 1, line) for i, line in enumerate(text.splitlines())
             if line.strip() and not line.lstrip().startswith("#")]
    if not lines:
        raise EstimatesError(f"{p} is empty; write a header 'name,value,std_error,unit' and one row per parameter")
    rows = list(csv.reader([ln for _, ln in lines]))
    header = [h.strip() for h in rows[0]]
    hdr = ["value" if h == "estimate" else h for h in header]
    if sorted(hdr) != sorted(COLUMNS) or len(set(hdr)) != len(hdr):
        raise EstimatesError(f"{p}: the header must be the four columns {','.join(COLUMNS)} (any order), "
                             f"got {','.join(header)}")
    out = []
    for (lineno, _), r in zip(lines[1:], rows[1:]):
        where = f"{p.name} line {lineno}"
        if len(r) != len(hdr):
            raise EstimatesError(f"{where}: {len(r)} fields but the header has {len(hdr)}; "
                                 "quote units that contain commas")
        d = dict(zip(hdr, (x.strip() for x in r)))
        if not d["name"]:
            raise EstimatesError(f"{where}: empty parameter name")
        if not d["unit"]:
            raise EstimatesError(f"{where}: parameter {d['name']!r} has no unit")
        out.append(ParameterEstimate(d["name"], _num(d["value"], "value", where),
                                     _num(d["std_error"], "std_error", where), d["unit"]))
    return out


def read_estimates_json(path) -> list[ParameterEstimate]:
    p = Path(path)
    try:
        d = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise EstimatesError(f"estimates file {p} does not exist") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise EstimatesError(f"{p} is not valid JSON text: {e}") from None
    if isinstance(d, dict) and "parameters" in d:
        d = d["parameters"]
    if isinstance(d, list):
        for r in d:
            if isinstance(r, dict) and r.get("unit") in (None, ""):
                raise EstimatesError(f"{p}: parameter {r.get('name')!r} has no unit")
    elif isinstance(d, dict):
        for k, v in d.items():
            if not isinstance(v, dict) or v.get("unit") in (None, ""):
                raise EstimatesError(f"{p}: parameter {k!r} must be an object with value, std_error and unit")
    if not isinstance(d, (list, dict)) or (isinstance(d, list) and not all(isinstance(r, dict) for r in d)):
        raise EstimatesError(f"{p}: the estimates must be a list of objects {{name, value, std_error, unit}} or an "
                             f"object name -> {{value, std_error, unit}}, not {type(d).__name__}")
    try:
        return normalise_estimates(_nan_from_null(d))
    except (TypeError, ValueError, KeyError, AttributeError) as e:
        if isinstance(e, EstimatesError):
            raise EstimatesError(f"{p}: {e}") from None
        raise EstimatesError(f"{p}: {type(e).__name__}: {e}; each estimate needs name, value, std_error and "
                             "unit") from None


def _nan_from_null(d):
    """JSON null for a value or std_error reads as NaN (and is then refused as NaN)."""
    def fix(r):
        return {k: (math.nan if k in ("value", "estimate", "std_error") and v is None else v) for k, v in r.items()}

    if isinstance(d, list):
        return [fix(r) if isinstance(r, dict) else r for r in d]
    return {k: fix(v) for k, v in d.items()}


def read_estimates(path) -> list[ParameterEstimate]:
    """Read a CSV or JSON estimates file (by extension)."""
    p = Path(path)
    if p.suffix.lower() == ".json":
        return read_estimates_json(p)
    if p.suffix.lower() in (".csv", ".txt"):
        return read_estimates_csv(p)
    raise EstimatesError(f"estimates must be a .csv or .json file, got {p.name}")


def write_estimates_csv(path, estimates, overwrite: bool = False) -> Path:
    """Write estimates (any form normalise_estimates accepts) as the documented CSV."""
    est = normalise_estimates(estimates)

    def w(tmp: Path):
        with open(tmp, "w", encoding="utf-8", newline="") as fh:
            wr = csv.writer(fh, lineterminator="\n")
            wr.writerow(COLUMNS)
            for e in est:
                wr.writerow([e.name, repr(float(e.value)), repr(float(e.std_error)), e.unit])

    return atomic_write(Path(path), w, overwrite)


def write_estimates_json(path, estimates, overwrite: bool = False) -> Path:
    est = normalise_estimates(estimates)
    text = json.dumps({"parameters": [e.to_dict() for e in est]}, indent=2)
    return atomic_write(Path(path), lambda tmp: tmp.write_text(text + "\n"), overwrite)
