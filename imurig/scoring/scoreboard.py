"""The baseline scoreboard: the bench's own estimators on every named campaign, and a
user's estimator beside them.

One row per (campaign, estimator): pass/fail at the z bound, parameters within it, RMS z
(about 1 for honest standard errors), the largest |z| and its parameter, the median of the
estimator's standard errors over the bench's (below 1: more precise), the residual RMS
over its floor with the injected parameters (mean over axes), and the fit's wall time.
The table and its files: :func:`imurig.reports.scoring.write_scoreboard`.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from imurig.kernel.errors import ImurigError
from imurig.scoring.baselines import baseline_for
from imurig.scoring.bench import score_calibrator
from imurig.scoring.campaigns import QUICK, campaign
from imurig.scoring.files import read_estimates
from imurig.scoring.score import Score, score_estimates


def _row(s: Score, label: str, sim_s: float | None = None) -> dict:
    sm = s.summary()
    ratio = None
    fm = s.residuals.get("forward_model")
    if fm:
        ratio = float(np.mean([fm["rms"][a] / fm["floor_rms"][a] for a in fm["rms"]]))
    return {"campaign": s.campaign, "seed": s.seed, "estimator": label, "passed": s.passed,
            "within": f"{sm['n_within_bound']}/{sm['n_parameters']}", "rms_z": sm["rms_z"], "max_abs_z": sm["max_abs_z"],
            "max_abs_z_parameter": sm["max_abs_z_parameter"], "median_se_ratio": sm["median_se_ratio"],
            "residual_over_floor": ratio, "fit_wall_s": s.extra.get("fit_wall_s"), "simulate_wall_s": sim_s}


def scoreboard(campaigns=QUICK, others: dict | None = None, seed: int | None = None) -> list[dict]:
    """Score the bench on each campaign, then every other estimator.

    ``others``: label -> a calibrator factory ``f(kind) -> calibrator or None`` (None: not
    for this kind), or label -> {campaign name: estimates (a file path, or any estimate
    form)}. A failing fit is reported in the row (``error``), not raised.
    """
    rows = []
    for name in campaigns:
        c = campaign(name, seed)
        t0 = time.perf_counter()
        c.simulate()
        sim = time.perf_counter() - t0
        rows.append(_row(score_calibrator(baseline_for(c.kind), c), "bench", sim))
        for label, how in (others or {}).items():
            try:
                if isinstance(how, dict):
                    if name not in how:
                        continue
                    est = how[name]
                    if isinstance(est, (str, Path)):
                        est = read_estimates(est)
                    s = score_estimates(c.truth(), est, estimator=label, source=f"{label} on {name}")
                else:
                    cal = how(c.kind)
                    if cal is None:
                        continue
                    s = score_calibrator(cal, c)
                rows.append(_row(s, label))
            except ImurigError as e:
                rows.append({"campaign": name, "seed": c.seed, "estimator": label, "passed": False, "error": str(e)})
    return rows
