"""The Monte-Carlo study in rerun: per run (on the ``run`` timeline) each parameter's z-score
inside the ±1.96 band, and its error (estimate − injected), one view per unit; the
per-parameter statistics as text."""
from __future__ import annotations

import re

import numpy as np
import rerun.blueprint as rrb

from imurig.montecarlo.stats import table_arrays
from imurig.reports.rrd_layout import layout, readable, series_view, summary_view, symmetric_range
from imurig.reports.viz import RrdWriter, log_scalars, log_text

Z95 = 1.959963984540054


def _unit_key(unit: str) -> str:
    """An entity name for a unit (letters, digits, underscores): ``m/s^2`` -> ``m_per_s2``,
    ``V/(m/s^2)`` -> ``V_per_m_per_s2``, dimensionless -> ``1``."""
    return re.sub(r"[^A-Za-z0-9_]", "", (unit or "1").replace("/", "_per_")) or "1"


def blueprint(units, ranges=None) -> rrb.Blueprint:
    """Left: z per run with the 95 % band, the statistics. Right: the errors, one view per unit
    (y axes ``ranges`` {unit: range})."""
    groups = list(dict.fromkeys(units))
    errs = [series_view(f"error (estimate − injected) per run, {u or '1'}", [f"/error/{_unit_key(u)}/**"],
                        y_range=(ranges or {}).get(u)) for u in groups]
    right = errs[0] if len(errs) == 1 else rrb.Vertical(*errs) if len(errs) == 2 else rrb.Grid(*errs, grid_columns=2)
    return layout(rrb.Horizontal(
        rrb.Vertical(series_view("z = (estimate − injected) / std. error per run, with ±1.96",
                                 ["/z/**", "/z_band/**"]), summary_view("statistics"), row_shares=[3, 2]),
        right, column_shares=[1, 1]))


def write_rrd(path, study, stats_md: str) -> None:
    """``study.rows`` -> z (points) with the band, errors grouped by unit under ``error/<unit>/``."""
    idx, names, units, A = table_arrays(study.rows)
    run = idx.astype(float)
    errors = {}  # unit -> ({parameter: error per run, scaled}, shown unit)
    for u in dict.fromkeys(units):
        err = {names[j]: A["estimate"][:, j] - A["injected"][:, j] for j, uu in enumerate(units) if uu == u}
        k, shown = readable(np.concatenate(list(err.values())), u or "1")
        errors[u] = ({n: v * k for n, v in err.items()}, shown)
    bp = blueprint(units, {u: symmetric_range(*e.values()) for u, (e, _s) in errors.items()})
    with RrdWriter(path, recording_name="Monte-Carlo study", overwrite=True, blueprint=bp) as w:
        if len(run):
            band = np.array([run.min(), run.max()])
            log_scalars(w, "z_band", band, {"upper": np.full(2, Z95), "lower": np.full(2, -Z95)}, role="bound",
                        labels={"upper": "+1.96 (95 %)", "lower": "−1.96"}, sequence="run")
        # one colour per parameter (the viewer's own palette): the roles do not apply here
        log_scalars(w, "z", run, {n: A["z"][:, j] for j, n in enumerate(names)}, points=True,
                    labels={n: f"z {n}" for n in names}, sequence="run")
        for u, (err, shown) in errors.items():
            log_scalars(w, f"error/{_unit_key(u)}", run, err, {n: shown for n in err}, points=True,
                        labels={n: f"{n} [{shown}]" for n in err}, sequence="run")
        log_text(w, "summary", stats_md)
