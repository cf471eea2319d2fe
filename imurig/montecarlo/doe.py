"""Design of experiments: compare schedules on accuracy against lab time (seed Table 4.7).

Each schedule is a full Monte-Carlo study (same master seed, so run i of every schedule
draws the same sensors and table: a paired comparison) in ``out/schedules/<slug>/``; the
comparison's report (:func:`imurig.reports.montecarlo_doe.write_comparison`) puts their
accuracy beside their lab time, the way the seed's Table 4.7 gives the time of each part of
the tilt-table calibration.
"""
from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np

from imurig.kernel.errors import ConfigError, OutputExistsError
from imurig.montecarlo import registry
from imurig.montecarlo.engine import dask_client, run_study
from imurig.montecarlo.results import atomic_text

GROUPS = {"sensitivity": ("sensitivity_", 1e6, "ppm of S"), "misalignment": ("misalignment_", 1e6, "µrad"),
          "bias": ("bias_", 1e6 / 9.80665, "µg"), "nonlinearity": ("nonlinearity_", 1e6 * 9.80665, "µg/g²")}


def slug(label: str) -> str:
    return re.sub(r"[^a-z0-9]+", "-", label.lower()).strip("-")


def group_rms(stats: list[dict], study_rows, groups: dict | None = None) -> dict:
    """RMS error and CRLB per parameter group (RMS over the group's parameters), in display units
    (``groups``: {group: (name prefix, scale, unit)}, default the accelerometer's).
    Sensitivity errors are relative (estimate / injected - 1)."""
    out = {}
    for g, (prefix, scale, unit) in (groups or GROUPS).items():
        sel = [s for s in stats if s["name"].startswith(prefix) and s.get("rms") is not None]
        if not sel:
            continue
        if g == "sensitivity":
            rel = []
            crl = []
            for rows in study_rows.values():
                for r in rows:
                    if r["name"].startswith(prefix) and r["injected"]:
                        rel.append(r["estimate"] / r["injected"] - 1)
                        if r.get("crlb"):
                            crl.append(r["crlb"] / r["injected"])
            rms = float(np.sqrt(np.mean(np.square(rel))))
            crlb = float(np.sqrt(np.mean(np.square(crl)))) if crl else None
        else:
            rms = float(np.sqrt(np.mean([s["rms"] ** 2 for s in sel])))
            crlb = float(np.sqrt(np.mean([s["crlb"] ** 2 for s in sel]))) if all(s.get("crlb") for s in sel) else None
        cov = float(np.mean([s["coverage"] for s in sel if "coverage" in s]))
        out[g] = {"rms": rms * scale, "crlb": None if crlb is None else crlb * scale, "unit": unit, "coverage": cov}
    return out


def compare_schedules(campaign, runs: int, master_seed: int = 0, out=None, base_params: dict | None = None,
                      schedules: dict | None = None, distributions=None, client=None, scheduler=None, workers=None,
                      overwrite: bool = False, resume: bool = False, retries: int = 2, study_report=None,
                      report=None) -> dict:
    """Run one study per schedule into ``out`` and return the comparison's summary.

    ``study_report(study, campaign)`` (optional) writes each schedule's study report (as
    :func:`imurig.montecarlo.engine.run_study`'s ``report``); ``report(summary, out)``
    (optional) writes the comparison's summary.json, report.md and figure, e.g.
    :func:`imurig.reports.montecarlo.write_study_outputs` and
    :func:`imurig.reports.montecarlo_doe.write_comparison`, which ``imurig montecarlo
    --compare-schedules`` passes.
    """
    camp = registry.get(campaign) if isinstance(campaign, str) else campaign
    if out is None:
        raise ConfigError("compare_schedules needs an output folder")
    out = Path(out)
    if out.exists() and any(out.iterdir()) and not (resume or overwrite):
        raise OutputExistsError(f"{out} exists; pass --resume to continue the comparison, --overwrite to replace it, "
                                "or choose another --out")
    if overwrite and out.exists() and not resume:
        if not (out / "doe.json").exists():
            raise OutputExistsError(f"{out} is not a schedule-comparison folder; refusing to delete it")
        shutil.rmtree(out)
    out.mkdir(parents=True, exist_ok=True)
    scheds = schedules or camp.schedules()
    atomic_text(out / "doe.json", json.dumps({"campaign": camp.name, "schedules": scheds, "runs": runs,
                                              "master_seed": master_seed, "base_params": base_params or {}}))
    results = []
    with dask_client(client, scheduler, workers) as c:
        for label, over in scheds.items():
            params = {**(base_params or {}), **over}
            st = run_study(camp, runs, master_seed, params=params, distributions=distributions, client=c,
                           out=out / "schedules" / slug(label), resume=True, retries=retries, desc=label,
                           report=study_report)
            p = camp.validate(params)
            results.append({"label": label, "folder": f"schedules/{slug(label)}", "params": p,
                            "lab_time": camp.lab_time(p),
                            "table_4_7": camp.table_4_7(p) if hasattr(camp, "table_4_7") else {},
                            "groups": group_rms(st.stats, st.rows, getattr(camp, "doe_groups", None)),
                            "timing": st.timing})
    summary = {"campaign": camp.name, "runs_per_schedule": runs, "master_seed": master_seed, "schedules": results,
               "figures": {}, "table_4_7_note": getattr(camp, "table_4_7_note", None)}
    if report is not None:
        report(summary, out)
    return summary
