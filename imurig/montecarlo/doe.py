"""Design of experiments: compare schedules on accuracy against lab time (seed Table 4.7).

Each schedule is a full Monte-Carlo study (same master seed, so run i of every schedule
draws the same sensors and table: a paired comparison) in ``out/schedules/<slug>/``;
``out/report.md`` puts their accuracy beside their lab time, the way the seed's Table 4.7
gives the time of each part of the tilt-table calibration.
"""
from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from imurig.kernel.errors import ConfigError, OutputExistsError
from imurig.montecarlo import registry
from imurig.montecarlo.engine import dask_client, run_study
from imurig.reports.montecarlo import _atomic_text, _save_fig
from imurig.reports.common import clean_json, md_table

GROUPS = {"sensitivity": ("sensitivity_", 1e6, "ppm of S"), "misalignment": ("misalignment_", 1e6, "µrad"),
          "bias": ("bias_", 1e6 / 9.80665, "µg"), "nonlinearity": ("nonlinearity_", 1e6 * 9.80665, "µg/g²")}


TILT_NOTE = ("Acquiring time in seconds; the rest in minutes. The seed: warm-up 15 min, 15 s acquisition, "
             "10 min for 12 phi positions, 120 min for 10 tilt angles, 280 min for the complete calibration.")


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


def table_47(campaign, params: dict) -> dict:
    """The seed's Table 4.7 rows for a tilt-table schedule, at the seed's rates (seconds)."""
    from imurig.montecarlo.tilt import SEED_SETTING_OVERHEAD_S, SEED_WARMUP_S

    per_pos = params["dwell_s"] + SEED_SETTING_OVERHEAD_S
    nphi, nth, nm = len(params["phi_deg"]), len(params["theta_deg"]), len(params["mounts"])
    lab = campaign.lab_time(params)
    return {"warm-up": SEED_WARMUP_S, "acquiring time per position": params["dwell_s"],
            f"{nphi} positions in the phi plane": nphi * per_pos,
            f"{nth} tilt angles (one mounting)": nth * nphi * per_pos,
            f"complete calibration ({nm} mountings)": lab["lab_time_seed_rates_s"],
            "virtual rig time (slews, settling, dwell, remount)": lab["rig_time_s"]}


def compare_schedules(campaign, runs: int, master_seed: int = 0, out=None, base_params: dict | None = None,
                      schedules: dict | None = None, distributions=None, client=None, scheduler=None, workers=None,
                      overwrite: bool = False, resume: bool = False, retries: int = 2) -> dict:
    """Run one study per schedule and write the comparison into ``out``; returns the summary."""
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
        import shutil

        shutil.rmtree(out)
    out.mkdir(parents=True, exist_ok=True)
    scheds = schedules or camp.schedules()
    _atomic_text(out / "doe.json", json.dumps({"campaign": camp.name, "schedules": scheds, "runs": runs,
                                               "master_seed": master_seed, "base_params": base_params or {}}))
    results = []
    with dask_client(client, scheduler, workers) as c:
        for label, over in scheds.items():
            params = {**(base_params or {}), **over}
            st = run_study(camp, runs, master_seed, params=params, distributions=distributions, client=c,
                           out=out / "schedules" / slug(label), resume=True, retries=retries, desc=label)
            p = camp.validate(params)
            results.append({"label": label, "folder": f"schedules/{slug(label)}", "params": p,
                            "lab_time": camp.lab_time(p),
                            "table_4_7": camp.table_4_7(p) if hasattr(camp, "table_4_7") else {},
                            "groups": group_rms(st.stats, st.rows, getattr(camp, "doe_groups", None)),
                            "timing": st.timing})
    figs = _figure(results, out)
    summary = {"campaign": camp.name, "runs_per_schedule": runs, "master_seed": master_seed, "schedules": results,
               "figures": figs, "table_4_7_note": getattr(camp, "table_4_7_note", None)}
    _atomic_text(out / "summary.json", json.dumps(clean_json(summary), indent=2, allow_nan=False) + "\n")
    _atomic_text(out / "report.md", _render(summary))
    return summary


def _figure(results, out: Path) -> dict:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = [g for g in results[0]["groups"] if all(g in r["groups"] for r in results)]
    if not groups or not all("lab_time_seed_rates_s" in r["lab_time"] for r in results):
        return {}
    fig, axes = plt.subplots(1, len(groups), figsize=(3.2 * len(groups), 3.4), squeeze=False)
    for ax, g in zip(axes[0], groups):
        for r in results:
            h = r["lab_time"]["lab_time_seed_rates_s"] / 3600
            ax.plot(h, r["groups"][g]["rms"], "o")
            ax.annotate(r["label"], (h, r["groups"][g]["rms"]), fontsize=6)
            if r["groups"][g]["crlb"]:
                ax.plot(h, r["groups"][g]["crlb"], "r_", ms=12)
        ax.set_title(f"{g} RMS error [{results[0]['groups'][g]['unit']}]", fontsize=8)
        ax.set_xlabel("lab time at the seed's rates (h)", fontsize=8)
        ax.set_yscale("log")
        ax.tick_params(labelsize=7)
    axes[0][0].set_ylabel("RMS error (dots), CRLB (red bars)", fontsize=8)
    fig.tight_layout()
    _save_fig(fig, out / "fig_schedules.png")
    plt.close(fig)
    return {"schedules": "fig_schedules.png"}


def _render(summary: dict) -> str:
    res = summary["schedules"]
    lines = [f"# Design of experiments: {summary['campaign']}, {summary['runs_per_schedule']} runs per schedule\n",
             ("Every schedule runs the same master seed, so run i of each draws the same sensors and table "
              "(a paired comparison). Accuracy: RMS of the estimation error over runs and over the three axes "
              "(sensitivity relative to its value); CRLB: the Cramér-Rao bound of that schedule.\n"),
             "## Lab time (like seed Table 4.7, minutes at the seed's rates)\n"]
    keys = list(dict.fromkeys(k for r in res for k in r["table_4_7"]))
    lines.append(md_table(["step"] + [r["label"] for r in res],
                          [[k] + [None if k not in r["table_4_7"] else
                                  (r["table_4_7"][k] if k == "acquiring time per position" else r["table_4_7"][k] / 60)
                                  for r in res] for k in keys]))
    lines.append("\n" + (summary.get("table_4_7_note") or TILT_NOTE) + "\n")
    lines.append("\n## Accuracy against lab time\n")
    groups = [g for g in res[0]["groups"] if all(g in r["groups"] for r in res)]
    hdr = ["schedule", "positions", "lab time (h)"]
    if not all("lab_time_seed_rates_s" in r["lab_time"] for r in res):
        return "\n".join(lines)
    for g in groups:
        u = res[0]["groups"][g]["unit"]
        hdr += [f"{g} RMS ({u})", f"{g} CRLB ({u})"]
    hdr += ["mean coverage"]
    rows = []
    for r in res:
        row = [r["label"], r["lab_time"]["positions"], r["lab_time"]["lab_time_seed_rates_s"] / 3600]
        for g in groups:
            row += [r["groups"][g]["rms"], r["groups"][g]["crlb"]]
        row.append(float(np.mean([r["groups"][g]["coverage"] for g in groups])))
        rows.append(row)
    lines.append(md_table(hdr, rows))
    lines.append("\nEach schedule's full report (per-parameter table, histograms, coverage) is in its folder: "
                 + ", ".join(f"[{r['label']}]({r['folder']}/report.md)" for r in res) + ".\n")
    if summary.get("figures"):
        lines.append("\n![schedules](fig_schedules.png)\n")
    return "\n".join(lines)

