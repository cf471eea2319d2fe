"""Outputs of a Monte-Carlo study: summary.json, report.md with figures, study.rrd, and the
results table results.h5 (:mod:`imurig.montecarlo.results`). Every file is written to a
temporary name and renamed when complete.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from imurig.kernel.outputs import atomic_write, clean_json
from imurig.montecarlo.results import atomic_text, write_results_h5
from imurig.montecarlo.stats import error_matrix, parameter_stats
from imurig.reports.common import fmt, md_table
from imurig.reports.flight_budget import budget_report


def save_fig(fig, path: Path) -> None:
    """Save a matplotlib figure as PNG through a temporary file renamed when complete."""
    atomic_write(Path(path), lambda tmp: fig.savefig(tmp, dpi=110, format="png"), overwrite=True)


#: a campaign's own report section: name -> (study, folder, save_fig) -> {markdown, summary, figures}
EXTRA_REPORTS = {"flight": budget_report}


def figures(study, stats: list[dict], folder: Path, prefix: str = "") -> dict[str, str]:
    """Error histograms, RMS vs CRLB, coverage with its binomial band."""
    import matplotlib  # heavy: loaded when figures are drawn, not when the CLI starts

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names, E = error_matrix(study.rows)
    by = {s["name"]: s for s in stats}
    out = {}
    n = len(names)
    cols = 3
    rowsn = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rowsn, cols, figsize=(11, 2.3 * rowsn), squeeze=False)
    for k, name in enumerate(names):
        ax = axes[k // cols][k % cols]
        e = E[:, k][np.isfinite(E[:, k])]
        s = by[name]
        if e.size:
            ax.hist(e, bins=max(8, min(40, e.size // 5)), density=True, color="#8fb3d9", edgecolor="white",
                    label="runs")
            x = np.linspace(e.min(), e.max(), 200) if e.max() > e.min() else np.array([e.min()])
            if s.get("std"):
                ax.plot(x, _normpdf(x, s["bias"], s["std"]), "k-", lw=1, label="N(bias, std)")
            if s.get("crlb"):
                ax.plot(x, _normpdf(x, 0.0, s["crlb"]), "r--", lw=1, label="N(0, CRLB)")
        ax.set_title(f"{name} [{s.get('unit', '')}]", fontsize=8)
        ax.tick_params(labelsize=7)
    for k in range(n, rowsn * cols):
        axes[k // cols][k % cols].axis("off")
    axes[0][0].legend(fontsize=7)
    fig.suptitle(f"Estimation error (estimate - injected), {len(study.rows)} runs", fontsize=10)
    fig.tight_layout()
    out["errors"] = f"{prefix}fig_errors.png"
    save_fig(fig, folder / out["errors"])
    plt.close(fig)

    fig, ax = plt.subplots(1, 2, figsize=(11, 3.8))
    y = np.arange(n)
    ratio = [by[m].get("rms_over_crlb") or np.nan for m in names]
    se_ratio = [by[m].get("rms_over_se") or np.nan for m in names]
    ax[0].barh(y, ratio, color="#d98f8f", label="RMS / CRLB")
    ax[0].axvline(1.0, color="k", lw=1, label="efficient")
    ax[0].legend(fontsize=7)
    ax[0].set_yticks(y, names, fontsize=7)
    ax[0].set_xscale("log")
    ax[0].set_xlabel("RMS error / Cramér-Rao bound (1 = efficient)")
    ax[1].barh(y, se_ratio, color="#8fd9a8", label="RMS / RMS SE")
    ax[1].axvline(1.0, color="k", lw=1, label="honest SEs")
    ax[1].legend(fontsize=7)
    ax[1].set_yticks(y, names, fontsize=7)
    ax[1].set_xlabel("RMS error / RMS reported standard error (1 = honest SEs)")
    fig.tight_layout()
    out["rms_crlb"] = f"{prefix}fig_rms_crlb.png"
    save_fig(fig, folder / out["rms_crlb"])
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(11, 3.5))
    cov = [by[m].get("coverage", np.nan) for m in names]
    lo = [by[m].get("coverage_ci", [np.nan, np.nan])[0] for m in names]
    hi = [by[m].get("coverage_ci", [np.nan, np.nan])[1] for m in names]
    band = next((by[m]["coverage_band"] for m in names if "coverage_band" in by[m]), None)
    if band:
        ax.axhspan(band[0], band[1], color="#dddddd", label="99 % band of Binomial(N, 0.95)/N")
    ax.errorbar(y, cov, yerr=[np.array(cov) - lo, np.array(hi) - cov], fmt="o", ms=4, capsize=2,
                label="coverage, Clopper-Pearson 95 %")
    ax.axhline(0.95, color="k", lw=1, label="nominal 0.95")
    ax.set_xticks(y, names, rotation=60, ha="right", fontsize=7)
    ax.set_ylabel("coverage of 95 % intervals")
    ax.legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    out["coverage"] = f"{prefix}fig_coverage.png"
    save_fig(fig, folder / out["coverage"])
    plt.close(fig)
    return out


def _normpdf(x, m, s):
    return np.exp(-0.5 * ((x - m) / s) ** 2) / (s * np.sqrt(2 * np.pi))


def stats_table(stats: list[dict]) -> str:
    rows = []
    for s in stats:
        band = s.get("coverage_band")
        ci = s.get("coverage_ci")
        rows.append([s["name"], s.get("unit"), s.get("bias"), s.get("bias_se"), s.get("rms"), s.get("crlb"),
                     s.get("rms_over_crlb"), s.get("mean_se"), s.get("rms_over_se"), s.get("coverage"),
                     None if ci is None else f"{ci[0]:.3f}-{ci[1]:.3f}",
                     None if band is None else f"{band[0]:.3f}-{band[1]:.3f}", s.get("coverage_ok")])
    return md_table(["parameter", "unit", "bias", "SE(bias)", "RMS", "CRLB", "RMS/CRLB", "reported SE", "RMS/SE",
                     "coverage", "95 % CI", "99 % band", "in band"], rows)


def summary_lines(stats: list[dict]) -> dict:
    r = [s["rms_over_crlb"] for s in stats if s.get("rms_over_crlb")]
    c = [s for s in stats if "coverage" in s]
    return {"rms_over_crlb_min": min(r) if r else None, "rms_over_crlb_median": float(np.median(r)) if r else None,
            "rms_over_crlb_max": max(r) if r else None,
            "coverage_mean": float(np.mean([s["coverage"] for s in c])) if c else None,
            "coverage_in_band": f"{sum(s['coverage_ok'] for s in c)}/{len(c)}" if c else None}


def write_study_outputs(study, campaign) -> dict:
    """results.h5, summary.json, report.md, figures and study.rrd into the study folder."""
    folder = Path(study.path)
    stats = parameter_stats(study.rows)
    write_results_h5(folder / "results.h5", study)
    figs = figures(study, stats, folder) if getattr(campaign, "generic_figures", True) else {}
    own = EXTRA_REPORTS.get(campaign.name)
    extra = (own(study, folder, save_fig) if own
             else campaign.extra_report(study, folder) if hasattr(campaign, "extra_report") else None)
    if extra:
        figs.update(extra.get("figures", {}))
    lab = campaign.lab_time(study.config["params"]) if hasattr(campaign, "lab_time") else {}
    info = [r["info"] for r in study.runs.values()]
    per_run = {k: float(np.mean([i[k] for i in info if k in i])) for k in ("wall_s", "simulate_s", "estimate_s",
                                                                            "crlb_s", "samples")
               if any(k in i for i in info)}
    peak = [i["peak_rss_mb"] for i in info if "peak_rss_mb" in i]
    if peak:
        study.timing = {**(study.timing or {}), "worker_peak_rss_mb": max(peak)}
    summary = {"config": study.config, "runs": len(study.runs), "timing": study.timing, "per_run_mean": per_run,
               "lab_time": lab, "overall": summary_lines(stats), "parameters": stats,
               "files": {"results": "results.h5", "runs": "runs/", **{k: v for k, v in figs.items()}}}
    if extra:
        summary.update(extra.get("summary", {}))
    atomic_text(folder / "summary.json", json.dumps(clean_json(summary), indent=2, allow_nan=False) + "\n")
    _write_rrd(folder / "study.rrd", study, stats)
    atomic_text(folder / "report.md", render_report(study, stats, figs, lab, per_run,
                                                     extra.get("markdown", "") if extra else "",
                                                     getattr(campaign, "lab_time_note", LAB_NOTE)))
    return summary


LAB_NOTE = ("`lab_time_seed_rates_s` uses the seed's Table 4.7 rates: 15 min warm-up and 60 s per position at 15 s "
            "acquisition (45 s to set and check the angles), plus the remount between mountings.")


def render_report(study, stats, figs, lab, per_run, extra_md: str = "", lab_note: str = LAB_NOTE) -> str:
    cfg = study.config
    ov = summary_lines(stats)
    t = study.timing or {}
    lines = [f"# Monte-Carlo study: {cfg['campaign']}, {len(study.runs)} runs\n",
             (f"Master seed {cfg['master_seed']}; run i uses the stream `montecarlo/run` of ({cfg['master_seed']}, i) "
             "and is reproduced alone by `imurig montecarlo ... --only-run i`. "
             f"Estimator: {cfg.get('estimator') or 'the campaign calibration'}. "
             f"User-set distributions: {', '.join(cfg['distributions']) or 'none (datasheet draws)'}.\n"),
             ("Each run draws the sensor and table errors, simulates the campaign, calibrates it and compares "
             "every estimate with its injected value. The Cramér-Rao bound (CRLB) is each run's Fisher bound at "
             "its own truth (schedule, noise model, survey); RMS/CRLB = 1 is an efficient estimator. Coverage: "
             "the fraction of runs whose 95 % interval (estimate ± 1.96 SE) holds the injected value; the band is "
             "where Binomial(N, 0.95)/N falls with 99 % probability.\n"),
             "## Summary\n",
             md_table(["quantity", "value"], [
                 ["RMS/CRLB (min, median, max)", (f"{fmt(ov['rms_over_crlb_min'], 3)}, "
                                                  f"{fmt(ov['rms_over_crlb_median'], 3)}, {fmt(ov['rms_over_crlb_max'], 3)}")],
                 ["mean coverage of 95 % intervals", ov["coverage_mean"]],
                 ["parameters with coverage inside the 99 % band", ov["coverage_in_band"]],
                 ["runs this session / wall time (s)", f"{t.get('new_runs')} / {fmt(t.get('wall_s'), 4)}"],
                 ["runs per minute (this session; from first submission to last result)", t.get("runs_per_min")],
                 ["runs per minute including cluster start-up", t.get("runs_per_min_incl_startup")],
                 ["workers", t.get("workers")],
                 ["peak memory of a worker process (MB)", t.get("worker_peak_rss_mb")],
                 ["mean time per run: simulate / estimate / CRLB (s)",
                  (f"{fmt(per_run.get('simulate_s'), 3)} / {fmt(per_run.get('estimate_s'), 3)} / "
                  f"{fmt(per_run.get('crlb_s'), 3)}")],
                 ["samples per run", per_run.get("samples")]]),
             extra_md,
             "\n## Per parameter\n", stats_table(stats)]
    if lab:
        lines += ["\n## Schedule and lab time\n", md_table(["quantity", "value"], [[k, v] for k, v in lab.items()]),
                  "\n" + lab_note + "\n"]
    lines += ["\n## Schedule settings\n", "```json\n" + json.dumps(cfg["params"], indent=1) + "\n```\n",
              "\n## Figures\n"] + [f"![{k}]({v})\n" for k, v in figs.items()]
    return "\n".join(lines)


def _write_rrd(path: Path, study, stats) -> None:
    """study.rrd (imurig.reports.montecarlo_rrd): z and errors per run, the statistics."""
    from imurig.reports.montecarlo_rrd import write_rrd  # rerun: heavy, loaded for the .rrd only

    write_rrd(path, study, stats_table(stats))
