"""Score reports: report.md (tables and a z-score figure), summary.json."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from imurig.kernel.outputs import OutputFolder, clean_json
from imurig.reports.common import md_table
from imurig.scoring.score import Score


def score_markdown(s: Score, fig: str | None = None) -> str:
    sm = s.summary()
    md = [f"# Score: {s.estimator} on {s.campaign} (seed {s.seed})\n",
          (f"**{'PASS' if s.passed else 'FAIL'}**: {sm['n_within_bound']} of {sm['n_parameters']} parameters within "
          f"|z| <= {s.z_bound:g}; RMS z {sm['rms_z']:.2f} (about 1 for honest standard errors); max |z| "
          f"{sm['max_abs_z']:.2f} ({sm['max_abs_z_parameter']}).\n"),
          ("z = (estimate - injected) / std_error. SE/bench: the standard error over the bench's own "
          "(below 1: more precise than the bench).\n")]
    if not s.passed:
        md += ["```", s.failure_message(), "```\n"]
    md.append(md_table(["parameter", "unit", "injected", "estimate", "error", "std. error", "z", "SE/bench",
                        "within bound"],
                       [[r["name"], r["unit"], r["injected"], r["estimate"], r["error"], r["std_error"],
                         f"{r['z']:+.2f}", None if r.get("se_ratio") is None else f"{r['se_ratio']:.2f}",
                         r["within_bound"]] for r in s.rows]))
    for k, v in s.residuals.items():
        md += [f"\n## Residuals: {k}\n", v.get("what", ""), "\n",
               md_table(["axis", f"RMS, estimated parameters ({v['unit']})", f"RMS, injected parameters ({v['unit']})"],
                        [[a, v["rms"][a], v["floor_rms"][a]] for a in v["rms"]])]
    if s.extra.get("output_residuals"):
        o = s.extra["output_residuals"]
        md += ["\n## Calibrated output minus true input (apply)\n",
               md_table(["axis", f"RMS ({o['unit']})"], [[a, x] for a, x in o["rms"].items()])]
    if fig:
        md.append(f"\n![z-scores]({fig})\n")
    return "\n".join(md)


def plot_z(path: Path, s: Score) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    z = np.array([r["z"] for r in s.rows])
    fig, ax = plt.subplots(figsize=(max(6, 0.35 * len(z)), 3.5))
    ax.bar(range(len(z)), z, color=["tab:blue" if abs(v) <= s.z_bound else "tab:red" for v in z])
    for b in (-s.z_bound, s.z_bound):
        ax.axhline(b, color="k", ls="--", lw=0.8)
    ax.set_xticks(range(len(z)), [r["name"] for r in s.rows], rotation=70, fontsize=7)
    ax.set_ylabel("z = error / std. error")
    ax.set_title(f"{s.estimator} on {s.campaign}", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_score(out, s: Score, overwrite: bool = False, figure: bool = True) -> Path:
    """Write report.md, summary.json (and fig_z.png) into the folder ``out`` atomically."""
    with OutputFolder(out, overwrite=overwrite) as folder:
        fig = None
        if figure:
            plot_z(folder.file("fig_z.png"), s)
            fig = "fig_z.png"
        folder.write_json("summary.json", clean_json(s.to_dict()))
        folder.write_text("report.md", score_markdown(s, fig))
    return Path(out)

