"""The report of a schedule comparison (:mod:`imurig.montecarlo.doe`): summary.json, report.md
with the lab time beside the accuracy (like the seed's Table 4.7), and fig_schedules.png."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from imurig.kernel.outputs import clean_json
from imurig.montecarlo.results import atomic_text
from imurig.reports.common import md_table
from imurig.reports.montecarlo import save_fig

TILT_NOTE = ("Acquiring time in seconds; the rest in minutes. The seed: warm-up 15 min, 15 s acquisition, "
             "10 min for 12 phi positions, 120 min for 10 tilt angles, 280 min for the complete calibration.")


def write_comparison(summary: dict, out) -> dict:
    """Write fig_schedules.png, summary.json and report.md of a comparison into ``out``; the
    figure files go into ``summary["figures"]``. Returns the summary."""
    out = Path(out)
    summary["figures"] = comparison_figure(summary["schedules"], out)
    atomic_text(out / "summary.json", json.dumps(clean_json(summary), indent=2, allow_nan=False) + "\n")
    atomic_text(out / "report.md", comparison_markdown(summary))
    return summary


def comparison_figure(results, out: Path) -> dict:
    """Accuracy of every parameter group against the lab time of each schedule: fig_schedules.png."""
    import matplotlib  # heavy: loaded when figures are drawn, not when the CLI starts

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = [g for g in results[0]["groups"] if all(g in r["groups"] for r in results)]
    if not groups or not all("lab_time_seed_rates_s" in r["lab_time"] for r in results):
        return {}
    fig, axes = plt.subplots(1, len(groups), figsize=(3.2 * len(groups), 3.4), squeeze=False)
    for ax, g in zip(axes[0], groups):
        for r in results:
            h = r["lab_time"]["lab_time_seed_rates_s"] / 3600
            ax.plot(h, r["groups"][g]["rms"], "o", label=f"{r['label']}: RMS error")
            ax.annotate(r["label"], (h, r["groups"][g]["rms"]), fontsize=6)
            if r["groups"][g]["crlb"]:
                ax.plot(h, r["groups"][g]["crlb"], "r_", ms=12, label=f"{r['label']}: CRLB")
        ax.set_title(f"{g} RMS error [{results[0]['groups'][g]['unit']}]", fontsize=8)
        ax.set_xlabel("lab time at the seed's rates (h)", fontsize=8)
        ax.set_yscale("log")
        ax.tick_params(labelsize=7)
        ax.legend(fontsize=5)
    axes[0][0].set_ylabel("RMS error (dots), CRLB (red bars)", fontsize=8)
    fig.tight_layout()
    save_fig(fig, out / "fig_schedules.png")
    plt.close(fig)
    return {"schedules": "fig_schedules.png"}


def comparison_markdown(summary: dict) -> str:
    """report.md of a schedule comparison (its summary from :func:`imurig.montecarlo.doe.compare_schedules`)."""
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

