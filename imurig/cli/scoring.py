"""``imurig export``, ``imurig score`` and ``imurig scoreboard``."""
from __future__ import annotations

import argparse
import importlib
import sys
from pathlib import Path

from imurig.kernel.errors import ImurigError
from imurig.reports.scoring import scoreboard_markdown, write_score, write_scoreboard
from imurig.scoring.files import read_estimates
from imurig.scoring.score import TruthSet, score_estimates
from imurig.scoring.specs import CAMPAIGNS, QUICK


def add_scoring_parsers(sub) -> None:
    """Register the three subcommands on the ``imurig`` subparsers ``sub``."""
    names = sorted(CAMPAIGNS)
    ex = sub.add_parser("export", help="write a campaign's recording without truth (CSV, .mat) and a separate truth file",
                        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
                        description="Export a named campaign for an estimator in any language: DIR holds the lab CSV, "
                                    "a MATLAB .mat, segments.csv and the parameters template; the truth goes to a "
                                    "separate file for 'imurig score'.")
    ex.add_argument("campaign", choices=names, help="the campaign whose recording (and truth, kept apart) to write")
    ex.add_argument("--seed", type=int, default=None, help="seed (default: the campaign's fixed seed)")
    ex.add_argument("--out", required=True, help="export folder (give this to your code)")
    ex.add_argument("--truth-out", default=None, help="truth file (default: OUT.truth.json beside the folder)")
    ex.add_argument("--no-mat", action="store_true", help="skip recording.mat")
    ex.add_argument("--overwrite", action="store_true")
    ex.set_defaults(func=_run_export)

    sc = sub.add_parser("score", help="score estimates (CSV or JSON) against an exported campaign's truth",
                        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
                        description="Read name,value,std_error,unit estimates, score them against the truth file "
                                    "written by 'imurig export', print the table and write report.md and "
                                    "summary.json. Exit status 1 when a parameter is outside the bound.")
    sc.add_argument("--truth", required=True, help="truth file from 'imurig export'")
    sc.add_argument("--estimates", required=True, help="estimates .csv or .json")
    sc.add_argument("--out", default=None, help="report folder (report.md, summary.json, fig_z.png)")
    sc.add_argument("--name", default=None, help="estimator name in the report (default: the file name)")
    sc.add_argument("--z-bound", type=float, default=None, help="|z| bound (default: the truth file's, 4)")
    sc.add_argument("--overwrite", action="store_true")
    sc.set_defaults(func=_run_score)

    sb = sub.add_parser("scoreboard", help="the bench's own estimators on every campaign (and yours beside them)",
                        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    sb.add_argument("--campaigns", default=",".join(QUICK), help="comma-separated campaign names, or 'all'")
    sb.add_argument("--seed", type=int, default=None, help="seed for every campaign (default: their fixed seeds)")
    sb.add_argument("--calibrator", action="append", default=[], metavar="MODULE:FACTORY",
                    help="your estimator: FACTORY(kind) returns a calibrator, or None to skip a kind")
    sb.add_argument("--estimates", action="append", default=[], metavar="CAMPAIGN=FILE",
                    help="your estimates file for a campaign (exported with the same seed)")
    sb.add_argument("--label", default="yours", help="name of your estimator in the table")
    sb.add_argument("--out", default=None, help="folder for scoreboard.md and scoreboard.json")
    sb.add_argument("--overwrite", action="store_true")
    sb.set_defaults(func=_run_scoreboard)


def _run_export(a):
    # heavy (the campaigns' MuJoCo rigs, scipy): loaded when the command runs, not for --help
    from imurig.scoring.export import export_campaign

    print(f"imurig: exporting {a.campaign} -> {a.out}", file=sys.stderr)
    m = export_campaign(a.campaign, a.out, seed=a.seed, truth_out=a.truth_out, overwrite=a.overwrite, mat=not a.no_mat)
    print(f"wrote {m['out']}: " + ", ".join(m["files"].values()))
    print(f"truth (keep away from the estimator): {m['truth']}")
    print(f"{len(m['parameters'])} parameters to estimate; template {Path(m['out']) / 'parameters.csv'}")


def _run_score(a):
    truth = TruthSet.load(a.truth)
    est = read_estimates(a.estimates)
    s = score_estimates(truth, est, estimator=a.name or Path(a.estimates).name, source=str(a.estimates),
                        z_bound=a.z_bound)
    print(s.table())
    if not s.passed:
        print(s.failure_message())
    if a.out:
        write_score(a.out, s, overwrite=a.overwrite)
        print(f"report: {Path(a.out) / 'report.md'}")
    if not s.passed:
        raise SystemExit(1)


def load_factory(spec: str):
    """'package.module:name' -> the object."""
    mod, _, attr = spec.partition(":")
    if not attr:
        raise ImurigError(f"--calibrator must be MODULE:FACTORY, got {spec!r}")
    try:
        return getattr(importlib.import_module(mod), attr)
    except (ImportError, AttributeError) as e:
        raise ImurigError(f"cannot load {spec!r}: {e}") from None


def _run_scoreboard(a):
    # heavy (the campaigns' MuJoCo rigs, scipy): loaded when the command runs, not for --help
    from imurig.scoring.scoreboard import scoreboard

    names = sorted(CAMPAIGNS) if a.campaigns == "all" else [n.strip() for n in a.campaigns.split(",") if n.strip()]
    others = {}
    for k, spec in enumerate(a.calibrator):
        others[a.label if k == 0 else f"{a.label}{k + 1}"] = load_factory(spec)
    if a.estimates:
        files = {}
        for item in a.estimates:
            camp, _, path = item.partition("=")
            if not path:
                raise ImurigError(f"--estimates must be CAMPAIGN=FILE, got {item!r}")
            files[camp] = path
        others[a.label + " (files)" if a.calibrator else a.label] = files
    rows = scoreboard(names, others, seed=a.seed)
    print(scoreboard_markdown(rows))
    if a.out:
        write_scoreboard(a.out, rows, overwrite=a.overwrite)
        print(f"scoreboard: {Path(a.out) / 'scoreboard.md'}")
