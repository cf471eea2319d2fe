"""Parameter rows of a Monte-Carlo run: ``{name, unit, injected, estimate, std_error, z,
within_bound, crlb}`` (the project's parameter-row schema plus the run's Cramér-Rao bound)."""
from __future__ import annotations

import numpy as np

from imurig.kernel.errors import ConfigError


def complete_rows(rows: list[dict], injected: dict, z_bound: float) -> list[dict]:
    """Fill a user estimator's rows {name, estimate, std_error[, unit]} with injected, z and
    within_bound (|z| <= ``z_bound``), z = (estimate - injected) / std_error."""
    out = []
    for r in rows:
        if "name" not in r or "estimate" not in r:
            raise ConfigError(f"an estimator row needs 'name' and 'estimate' (and 'std_error'), got {r!r}")
        v = injected.get(r["name"])
        se = r.get("std_error")
        z = None if v is None or not se or se <= 0 else (r["estimate"] - v) / se
        out.append({"name": r["name"], "unit": r.get("unit", ""), "injected": None if v is None else float(v),
                    "estimate": float(r["estimate"]), "std_error": None if se is None else float(se), "z": z,
                    "within_bound": None if z is None else bool(abs(z) <= z_bound)})
    return out


def plain(row: dict) -> dict:
    """The row with numpy floats as Python floats (JSON-ready, comparable across processes)."""
    return {k: (float(v) if isinstance(v, (np.floating, float)) else v) for k, v in row.items()}
