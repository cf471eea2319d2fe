"""Score reports: report.md (tables and a z-score figure), summary.json; the scoreboard
(scoreboard.md, scoreboard.json) and the Monte-Carlo score table."""
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
    import matplotlib  # heavy: loaded when figures are drawn, not when the CLI starts

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    z = np.array([r["z"] for r in s.rows])
    fig, ax = plt.subplots(figsize=(max(6, 0.35 * len(z)), 3.5))
    ax.bar(range(len(z)), z, color=["tab:blue" if abs(v) <= s.z_bound else "tab:red" for v in z],
           label="z of each parameter")
    for b in (-s.z_bound, s.z_bound):
        ax.axhline(b, color="k", ls="--", lw=0.8, label=f"{b:+g} bound")
    ax.legend(fontsize=7, loc="upper right")
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


def scoreboard_markdown(rows: list[dict]) -> str:
    """The scoreboard rows (:func:`imurig.scoring.scoreboard.scoreboard`) as a Markdown table."""

    def f(v, d=2):
        return "–" if v is None else f"{v:.{d}f}"

    body = []
    for r in rows:
        if "error" in r:
            body.append([r["campaign"], r["estimator"], "**error**", r["error"].splitlines()[0][:80], "", "", "", "", ""])
            continue
        body.append([r["campaign"], r["estimator"], "PASS" if r["passed"] else "**FAIL**", r["within"], f(r["rms_z"]),
                     f"{r['max_abs_z']:.2f} ({r['max_abs_z_parameter']})", f(r["median_se_ratio"]),
                     f(r["residual_over_floor"], 3), f(r["fit_wall_s"], 2)])
    return md_table(["campaign", "estimator", "result", "within 4 SE", "RMS z", "max |z|", "SE / bench",
                     "residual / floor", "fit s"], body)


def write_scoreboard(out, rows: list[dict], overwrite: bool = False) -> Path:
    """Write scoreboard.json and scoreboard.md into the folder ``out`` atomically."""
    with OutputFolder(out, overwrite=overwrite) as folder:
        folder.write_json("scoreboard.json", clean_json({"rows": rows}))
        folder.write_text("scoreboard.md", "# imurig scoreboard\n\n" + scoreboard_markdown(rows) + "\n")
    return Path(out)


def monte_carlo_table(result: dict) -> str:
    """A Monte-Carlo score (:func:`imurig.scoring.montecarlo.score_monte_carlo`) as a Markdown table."""

    def f(v, d=3):
        return "–" if v is None else f"{v:.{d}g}"

    return md_table(["parameter", "unit", "bias", "RMS", "CRLB", "RMS/CRLB", "RMS/SE", "95 % coverage", "band ok"],
                    [[s["name"], s["unit"], f(s.get("bias")), f(s.get("rms")), f(s.get("crlb")),
                      f(s.get("rms_over_crlb")), f(s.get("rms_over_se")), f(s.get("coverage")), s.get("coverage_ok")]
                     for s in result["parameters"]])
