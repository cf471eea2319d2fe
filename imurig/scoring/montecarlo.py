"""Monte-Carlo scoring: a user's calibrator over N seeded runs on the distributed engine.

This adds no engine of its own: it wraps the calibrator as the estimator of
:func:`imurig.montecarlo.run_study` (dask.distributed; run i seeded by
the stream "montecarlo/run" of (master_seed, i), every virtual lab drawn afresh), and reads the
engine's per-parameter statistics (:mod:`imurig.montecarlo.stats`):

    RMS of the error over the runs against the Cramér-Rao bound (RMS / CRLB >= 1; near 1
    for an efficient estimator), the bias and its standard error, the RMS over the
    estimator's own mean standard error (about 1 for honest standard errors), and the
    coverage of its 95 % intervals with the binomial acceptance band.

Campaigns: those the engine registers (``imurig.montecarlo.registry``; so far the tilt
table, whose CRLB comes from the forward model with the lab's noise, setting and survey
errors). The calibrator must be picklable (it runs on the workers).
"""
from __future__ import annotations

import copy
from dataclasses import dataclass

from imurig.kernel.errors import ImurigError
from imurig.montecarlo.engine import run_study
from imurig.scoring.interface import fitted_estimates, normalise_estimates
from imurig.scoring.score import TruthSet, check_estimates
from imurig.scoring.specs import ACC_UNITS, triad_names


def _template_units(kind: str) -> dict[str, str]:
    if kind != "tilt-table":
        raise ImurigError(f"Monte-Carlo scoring knows the tilt-table campaign only so far, not {kind!r}")
    return {n: ACC_UNITS[n.split("_")[0]] for n in triad_names(("x", "y", "z"))}


@dataclass
class CalibratorEstimator:
    """The engine's estimator contract ``f(recording) -> [{name, unit, estimate, std_error}]``
    from a :class:`~imurig.scoring.interface.Calibrator`: fits a fresh copy per run, checks
    the estimates against the campaign's parameters and converts them to SI."""

    calibrator: object
    kind: str = "tilt-table"

    def __call__(self, recording) -> list[dict]:
        units = _template_units(self.kind)
        truth = TruthSet(self.kind, 0, [{"name": n, "unit": u, "injected": 0.0} for n, u in units.items()])
        cal = copy.deepcopy(self.calibrator)
        est = check_estimates(truth, normalise_estimates(fitted_estimates(cal, recording), units),
                              f"{type(self.calibrator).__name__}.fit()")
        return [{"name": n, "unit": units[n], "estimate": est[n].value, "std_error": est[n].std_error} for n in units]


def score_monte_carlo(calibrator, runs: int, master_seed: int = 0, campaign: str = "tilt-table",
                      params: dict | None = None, **engine_kw) -> dict:
    """Run ``calibrator`` on ``runs`` seeded virtual labs and summarise per parameter.

    ``engine_kw`` go to :func:`imurig.montecarlo.run_study` (``client``, ``workers``, ``out``,
    ``scheduler``, ``processes``, ``report`` ...). Returns {"parameters": [...], "timing": {...},
    "study": Study}; each parameter row has bias, rms, crlb, rms_over_crlb, mean_se,
    rms_over_se, coverage, coverage_band, coverage_ok, within_bound_fraction (as a Markdown
    table: :func:`imurig.reports.scoring.monte_carlo_table`).
    """
    study = run_study(campaign, runs, master_seed=master_seed, params=params,
                      estimator=CalibratorEstimator(calibrator, campaign), **engine_kw)
    stats = study.stats
    within = {}
    for rows in study.rows.values():
        for r in rows:
            within.setdefault(r["name"], []).append(bool(r.get("within_bound")))
    for s in stats:
        w = within.get(s["name"], [])
        s["within_bound_fraction"] = sum(w) / len(w) if w else None
    return {"campaign": campaign, "runs": runs, "master_seed": master_seed, "estimator": type(calibrator).__name__,
            "parameters": stats, "timing": study.timing, "study": study}
