"""The diagnosis in rerun: per channel and observable the recording, its nominal twin and the
twin corrected by the effects found, overlaid; below each, the residuals before (recording −
twin) and after (recording − corrected twin); the findings as text."""
from __future__ import annotations

import numpy as np
import rerun.blueprint as rrb

from imurig.reports.rrd_layout import layout, readable, series_view, summary_view, symmetric_range
from imurig.reports.viz import RrdWriter, log_scalars, log_text

ROLE = {"recording": "measured", "twin": "twin", "corrected_twin": "corrected_twin"}
LABEL = {"recording": "recording", "twin": "twin", "corrected_twin": "corrected twin",
         "before": "before: recording − twin", "after": "after: recording − corrected twin"}
COLUMNS = 3


def _title(prefix: str) -> str:
    """``signals/acc_x/position_means`` -> ``acc_x position means``."""
    return " ".join(prefix.split("/")[1:]).replace("_means", " means").replace("_", " ").replace("acc ", "acc_") \
        .replace("gyro ", "gyro_").replace("mag ", "mag_")


def _residuals(series: dict, unit: str) -> tuple[dict, str]:
    """({"before": recording − twin, "after": recording − corrected twin} scaled, unit)."""
    rec = np.asarray(series["recording"], dtype=float)
    res = {"before": rec - np.asarray(series["twin"]), "after": rec - np.asarray(series["corrected_twin"])}
    f, u = readable(np.concatenate(list(res.values())), unit)
    return {k: v * f for k, v in res.items()}, u


def blueprint(overlays) -> rrb.Blueprint:
    """A grid of COLUMNS columns: a row of overlays, then the row of their residuals, per group
    of COLUMNS (channel, observable) pairs; the findings on the right."""
    views = []
    for g in range(0, len(overlays), COLUMNS):
        group = overlays[g:g + COLUMNS]
        for prefix, _t, _s, unit in group:
            views.append(series_view(f"{_title(prefix)}, {unit}", [f"/{prefix}/**"]))
        for prefix, _t, series, unit in group:
            res, _u = _residuals(series, unit)
            views.append(series_view(f"{_title(prefix)}: residuals", [f"/residuals/{prefix[8:]}/**"],
                                     y_range=symmetric_range(*res.values())))
    if not views:
        return layout(rrb.Horizontal(summary_view("findings")))
    return layout(rrb.Horizontal(rrb.Grid(*views, grid_columns=min(COLUMNS, len(overlays))),
                                 summary_view("findings"), column_shares=[4, 1]))


def write(path, overlays, summary: str) -> None:
    """``overlays``: [(entity prefix ``signals/<channel>/<observable>``, time (n,) s,
    {"recording", "twin", "corrected_twin": (n,)}, unit)]. Writes the overlays to
    ``<prefix>/<series>``, the residuals to ``residuals/<channel>/<observable>/{before,after}``
    (points for per-position, per-step and per-round means, lines for time series), and the
    summary."""
    with RrdWriter(path, recording_name="diagnosis", overwrite=True, blueprint=blueprint(overlays)) as w:
        for prefix, t, series, unit in overlays:
            points = not prefix.endswith(("slews", "field"))
            for k in ("twin", "corrected_twin", "recording"):
                if k in series:
                    log_scalars(w, prefix, t, {k: series[k]}, {k: unit}, role=ROLE[k], points=points,
                                labels={k: f"{LABEL[k]} [{unit}]"})
            res, u = _residuals(series, unit)
            for k, role in (("before", "residual"), ("after", "residual_after")):
                log_scalars(w, f"residuals/{prefix[8:]}", t, {k: res[k]}, {k: u}, role=role, points=points,
                            labels={k: f"{LABEL[k]} [{u}]"})
        log_text(w, "summary", summary)
