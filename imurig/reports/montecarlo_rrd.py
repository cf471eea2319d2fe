"""The Monte-Carlo study in rerun: per run (on the ``time`` timeline, 1 s = run 1) each
parameter's z-score inside the ±1.96 band, and its error (estimate − injected), one view per
unit; the per-parameter statistics as text."""
from __future__ import annotations

import re

import numpy as np
import rerun.blueprint as rrb

from imurig.montecarlo.stats import table_arrays
from imurig.reports.rrd_layout import layout, readable, series_view, summary_view
from imurig.reports.viz import RrdWriter, log_scalars, log_text

Z95 = 1.959963984540054


def _unit_key(unit: str) -> str:
    """An entity name for a unit (letters, digits, underscores): ``m/s^2`` -> ``m_per_s2``,
    ``V/(m/s^2)`` -> ``V_per_m_per_s2``, dimensionless -> ``1``."""
    return re.sub(r"[^A-Za-z0-9_]", "", (unit or "1").replace("/", "_per_")) or "1"


def blueprint(units) -> rrb.Blueprint:
    """Left: z per run with the 95 % band, the statistics. Right: the errors, one view per unit."""
    groups = list(dict.fromkeys(units))
    errs = [series_view(f"error (estimate − injected) per run, {u or '1'}", [f"/error/{_unit_key(u)}/**"])
            for u in groups]
    right = errs[0] if len(errs) == 1 else rrb.Vertical(*errs)
    return layout(rrb.Horizontal(
        rrb.Vertical(series_view("z = (estimate − injected) / std. error per run, with ±1.96",
                                 ["/z/**", "/z_band/**"]), summary_view("statistics"), row_shares=[3, 2]),
        right, column_shares=[1, 1]))


def write_rrd(path, study, stats_md: str) -> None:
    """``study.rows`` -> z (points) with the band, errors grouped by unit under ``error/<unit>/``."""
    idx, names, units, A = table_arrays(study.rows)
    run = idx.astype(float)
    with RrdWriter(path, recording_name="Monte-Carlo study", overwrite=True, blueprint=blueprint(units)) as w:
        if len(run):
            band = np.array([run.min(), run.max()])
            log_scalars(w, "z_band", band, {"upper": np.full(2, Z95), "lower": np.full(2, -Z95)}, role="bound",
                        labels={"upper": "+1.96 (95 %)", "lower": "−1.96"})
        # one colour per parameter (the viewer's own palette): the roles do not apply here
        log_scalars(w, "z", run, {n: A["z"][:, j] for j, n in enumerate(names)}, points=True,
                    labels={n: f"z {n}" for n in names})
        for u in dict.fromkeys(units):
            cols = [j for j, uu in enumerate(units) if uu == u]
            err = {names[j]: A["estimate"][:, j] - A["injected"][:, j] for j in cols}
            k, shown = readable(np.concatenate(list(err.values())), u or "1")
            log_scalars(w, f"error/{_unit_key(u)}", run, {n: v * k for n, v in err.items()}, {n: shown for n in err},
                        points=True, labels={n: f"{n} [{shown}]" for n in err})
        log_text(w, "summary", stats_md)
