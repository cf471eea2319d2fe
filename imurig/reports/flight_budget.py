"""The report part of a flight Monte-Carlo study (:mod:`imurig.montecarlo.flight`): the navigation
error budget after calibration as markdown tables and a bar figure.

For metric m the budget (:func:`imurig.montecarlo.flight.budget`) gives the mean square of each
configuration over the runs, MS_c; the share of source s is what it adds on its own, MS_s − MS_none,
with its standard error over runs; "all on" is MS_all − MS_none.
"""
from __future__ import annotations

import numpy as np

from imurig.montecarlo.flight import FLIGHT, budget, residual_sigmas
from imurig.reports.common import md_table


def budget_report(study, folder, save_fig) -> dict:
    """The budget table (markdown), summary dict and figure of a flight study; ``save_fig(fig, path)``
    writes a figure into the study folder."""
    p = FLIGHT.validate(study.config["params"])
    b = budget(study.rows, FLIGHT.configurations(p))
    lines = [budget_markdown(b, p, len(study.rows))]
    figs = {}
    if b:
        budget_figure(b, folder / "fig_budget.png", save_fig)
        figs["budget"] = "fig_budget.png"
        lines.append("\n![budget](fig_budget.png)\n")
    return {"markdown": "\n".join(lines), "summary": {"budget": b, "residual_sigmas": residual_sigmas(p["residuals"])},
            "figures": figs}


def budget_markdown(b: dict, p: dict, n_runs: int) -> str:
    """One table per metric: RMS, mean square added, its SE and share of all-on, per source."""
    lines = ["\n## Navigation error budget after calibration\n",
             (f"Residual errors after calibration: **{p['residuals']}** "
              + ("(the rig calibrations' Monte-Carlo RMS)" if p["residuals"] == "calibrated"
                 else "(datasheet spread: an uncalibrated IMU)")
              + f"; flight plan {p['plan']!r}, RMS after the first {p['settle_s']:g} s; {n_runs} runs. "
              "Each cell: RMS over runs of the flight's RMS error. *added* = the mean square the source adds "
              "on its own above the floor (no residual: sensor noise, GPS, filter), with its standard error "
              "over runs; the sum of the sources against what all add together shows how far they are "
              "additive.\n")]
    for m, d in b.items():
        u = d["unit"]
        rows = [["floor (no calibration residual)", d["rms"]["none"], None, None, None]]
        for s, a in d["sources"].items():
            rows.append([s, a["rms_alone"], a["mean_square_added"], a["se"], a["share_of_all"]])
        rows.append(["sum of the sources", None, d["sum_of_sources"], None,
                     d["sum_of_sources"] / d["all_mean_square_added"] if d["all_mean_square_added"] else None])
        rows.append(["all on", d["rms"]["all"], d["all_mean_square_added"], d["all_se"], 1.0])
        lines += [f"\n### {m} ({u})\n",
                  md_table(["configuration", f"RMS ({u})", f"mean square added ({u}²)", "SE", "share of all-on"],
                           rows)]
    return "\n".join(lines)


def budget_figure(b: dict, path, save_fig) -> None:
    """Bars of the mean square each source adds (± SE), their sum and all-on, one panel per metric."""
    import matplotlib  # lazy: matplotlib is loaded only when the figure is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ms = list(b)
    fig, axes = plt.subplots(1, len(ms), figsize=(3.0 * len(ms), 3.6), squeeze=False)
    for ax, m in zip(axes[0], ms):
        d = b[m]
        names = list(d["sources"]) + ["sum", "all on"]
        vals = [d["sources"][s]["mean_square_added"] for s in d["sources"]] + [d["sum_of_sources"],
                                                                             d["all_mean_square_added"]]
        err = [d["sources"][s]["se"] or 0 for s in d["sources"]] + [0, d["all_se"] or 0]
        y = np.arange(len(names))
        ax.barh(y, vals, color=["#8fb3d9"] * len(d["sources"]) + ["#d9b38f", "#d98f8f"],
                label="mean square added")
        ax.errorbar(vals, y, xerr=err, fmt="none", ecolor="k", lw=0.8, label="± its standard error")
        ax.axvline(0, color="k", lw=0.8, label="zero")
        ax.legend(fontsize=6)
        ax.set_yticks(y, names if ax is axes[0][0] else [""] * len(names), fontsize=7)
        ax.set_title(f"{m}\nfloor RMS {d['rms']['none']:.3g} {d['unit']}", fontsize=8)
        ax.set_xlabel(f"mean square added ({d['unit']}²)", fontsize=7)
        ax.tick_params(labelsize=6)
    fig.suptitle("Flight error budget: mean square each residual source adds above the floor", fontsize=9)
    fig.tight_layout()
    save_fig(fig, path)
    plt.close(fig)
