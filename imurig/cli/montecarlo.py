"""``imurig montecarlo CAMPAIGN --runs N``: the command-line front of :mod:`imurig.montecarlo`."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from imurig.kernel.errors import ConfigError


def _floats(text: str) -> list[float]:
    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None


def _words(text: str) -> list[str]:
    return [v.strip() for v in text.split(",") if v.strip()]


def add_montecarlo_parser(sub) -> None:
    p = sub.add_parser(
        "montecarlo", help="Monte-Carlo accuracy study of a campaign on dask (bias, RMS vs Cramér-Rao bound, coverage)",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
        description="Run N seeded virtual campaigns (each draws its sensor and rig errors, simulates, calibrates) "
                    "on a local dask cluster or an existing one, stream every run to OUT/runs/, and write "
                    "results.h5, summary.json and report.md (error histograms, RMS beside the Cramér-Rao bound, "
                    "coverage of the 95 % intervals). --compare-schedules compares schedules on accuracy against "
                    "lab time (seed Table 4.7).")
    p.add_argument("campaign", help="campaign to study: tilt-table, turn-table or flight (or any campaign "
                                    "registered with imurig.montecarlo.register)")
    p.add_argument("--n-runs", "--runs", dest="runs", type=int, default=200,
                   help="number of Monte-Carlo runs N (per schedule with --compare-schedules; --runs: the older name)")
    p.add_argument("--seed", type=int, default=2005, help="master seed: run i uses the stream 'montecarlo/run' of (seed, i)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="address of an existing dask scheduler (e.g. tcp://10.0.0.5:8786); default: a local cluster")
    p.add_argument("--workers", type=int, default=None, help="local cluster: worker processes (default: min(2, cores))")
    p.add_argument("--out", default=None, help="study folder (default imurig-out/montecarlo/<campaign>)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing study folder")
    p.add_argument("--resume", action="store_true", help="continue an interrupted study in --out (same settings)")
    p.add_argument("--retries", type=int, default=2, help="retries of a run whose task fails")
    p.add_argument("--only-run", type=int, default=None, metavar="I",
                   help="reproduce run I alone in this process and print its rows (JSON); with an existing --out, "
                        "use that study's settings and say whether it equals the stored row")
    p.add_argument("--distributions", default=None, metavar="FILE",
                   help="TOML/JSON of user-set error distributions {source: {mean, std|variance}} (SI)")
    p.add_argument("--compare-schedules", action="store_true",
                   help="design of experiments, accuracy vs lab time: tilt-table 12 vs 6 phi positions x 15 vs "
                        "60 s dwell; turn-table 9 vs 15 gyro rates")
    s = p.add_argument_group("schedule (default: the seed's 10 x 12 x 2 positions, 15 s, 100 Hz averaged logging)")
    s.add_argument("--theta", type=_floats, default=None, metavar="DEG,...", help="tilt angles")
    s.add_argument("--phi", type=_floats, default=None, metavar="DEG,...", help="rotation angles")
    s.add_argument("--mounts", type=_words, default=None, metavar="MOUNT,...",
                   help="mountings: z_down, z_up (tilt table); p_up, q_up, r_up, ..._down (turn table)")
    s.add_argument("--dwell", type=float, default=None, help="seconds acquired per position")
    s.add_argument("--rate", type=float, default=None, help="logged sample rate, Hz")
    s.add_argument("--logging", choices=["averaged", "direct"], default=None,
                   help="averaged: each sample the mean of the 1 kHz conversions; direct: 1 kHz samples")
    s.add_argument("--rig", choices=["static", "mujoco"], default=None,
                   help="static: closed-form rest windows; mujoco: the full MuJoCo table every run (slow)")
    s.add_argument("--model", default=None, help="calibration model (tilt table: physical, linear, cross; "
                                                  "turn table: physical)")
    s.add_argument("--statistic", choices=["huber", "median", "mean"], default=None,
                   help="per-position statistic (default huber: a robust M-estimate at 95 %% Gaussian efficiency; "
                        "median: the seed's)")
    s.add_argument("--setting-resolution-arcmin", type=float, default=None, help="table angle-setting resolution")
    s.add_argument("--survey-arcsec", type=float, default=None, help="inclinometer survey accuracy (1 sigma)")
    s.add_argument("--no-people", action="store_true", help="no door/chair transients")
    t = p.add_argument_group("turn-table schedule (default: the quick protocol, 5 dial rates 10-100 deg/s, 8 s, "
                             "200 Hz)")
    t.add_argument("--protocol", choices=["quick", "full"], default=None,
                   help="quick (~1 s per run) or full: the seed's 9 dial rates 1-100 deg/s, 10 s, 1 kHz (~20 s per run)")
    t.add_argument("--rates", type=_floats, default=None, metavar="DPS,...", help="dial rates, deg/s")
    t.add_argument("--directions", type=_floats, default=None, metavar="1,-1", help="directions: 1, -1 or both")
    t.add_argument("--window", type=float, default=None, help="least whole-round acquisition per step, s")
    t.add_argument("--timer", choices=["adc", "gps_mark", "hp6700"], default=None, help="round timer")
    f = p.add_argument_group("flight (error budget)")
    f.add_argument("--duration", type=float, default=None, help="flight length, s (the short default plan is cut)")
    f.add_argument("--residuals", choices=["calibrated", "datasheet"], default=None,
                   help="residual errors after calibration: the rig calibrations' Monte-Carlo RMS, or the "
                        "datasheet spread (an uncalibrated IMU)")
    f.add_argument("--budget", choices=["one-at-a-time", "all-on"], default=None,
                   help="one-at-a-time: every run flies once per error source alone, once with all on, once "
                        "with none (the budget); all-on: only the all-on flight")
    p.set_defaults(func=run_cli)


def _params(args) -> dict:
    m = {"theta": "theta_deg", "phi": "phi_deg", "mounts": "mounts", "dwell": "dwell_s", "rate": "sample_rate_hz",
         "logging": "logging", "rig": "rig", "model": "model", "statistic": "statistic",
         "setting_resolution_arcmin": "setting_resolution_arcmin", "survey_arcsec": "survey_accuracy_arcsec",
         "protocol": "protocol", "rates": "dial_rates_dps", "window": "min_window_s", "timer": "timer",
         "duration": "duration_s", "budget": "budget", "residuals": "residuals"}
    out = {v: getattr(args, k) for k, v in m.items() if getattr(args, k) is not None}
    if args.no_people:
        out["people"] = False
    if args.directions is not None:
        out["directions"] = [int(d) for d in args.directions]
    return out


def run_cli(args) -> None:
    # heavy (the campaigns' MuJoCo rigs, dask, matplotlib): loaded when the command runs, not for --help
    from imurig.montecarlo import distributions as dist
    from imurig.montecarlo import registry
    from imurig.montecarlo.doe import compare_schedules
    from imurig.montecarlo.engine import RUN_FILE, load_study, reproduce_run, run_study
    from imurig.reports.montecarlo import write_study_outputs
    from imurig.reports.montecarlo_doe import write_comparison

    registry.get(args.campaign)  # an unknown campaign is refused with the list of known ones
    out = Path(args.out or f"imurig-out/montecarlo/{args.campaign}")
    user = dist.load(args.distributions) if args.distributions else None
    params = _params(args)
    if args.runs < 1:
        raise ConfigError(f"--runs must be >= 1, got {args.runs}")
    if args.only_run is not None:
        if args.only_run < 0:
            raise ConfigError(f"--only-run must be >= 0, got {args.only_run}")
        stored = None
        if (out / "study.json").exists():
            st = load_study(out)
            cfg = st.config
            res = reproduce_run(cfg["campaign"], args.only_run, cfg["master_seed"], cfg["params"],
                                cfg["distributions"])
            f = out / "runs" / RUN_FILE.format(args.only_run)
            if f.exists():
                stored = json.loads(f.read_text())
        else:
            res = reproduce_run(args.campaign, args.only_run, args.seed, params, user)
        doc = {"index": res["index"], "seed": res["seed"], "rows": res["rows"]}
        if stored is not None:
            doc["equals_stored_row"] = stored["rows"] == res["rows"]
        json.dump(doc, sys.stdout, indent=1)
        print()
        return
    if args.compare_schedules:
        compare_schedules(args.campaign, args.runs, args.seed, out=out, base_params=params, distributions=user,
                          scheduler=args.scheduler, workers=args.workers, overwrite=args.overwrite,
                          resume=args.resume, retries=args.retries, study_report=write_study_outputs,
                          report=write_comparison)
        print(f"wrote {out}/report.md")
        return
    st = run_study(args.campaign, args.runs, args.seed, params=params, distributions=user, scheduler=args.scheduler,
                   workers=args.workers, out=out, overwrite=args.overwrite, resume=args.resume, retries=args.retries,
                   report=write_study_outputs)
    doc = json.loads((out / "summary.json").read_text())
    s = doc["overall"]
    t = st.timing
    rate = f"{t['runs_per_min']:.1f} runs/min" if t.get("runs_per_min") else "no new runs"
    if s.get("rms_over_crlb_min") is not None:
        print(f"wrote {out}/report.md: {len(st.runs)} runs; RMS/CRLB {s['rms_over_crlb_min']:.2f}-"
              f"{s['rms_over_crlb_max']:.2f} (median {s['rms_over_crlb_median']:.2f}); mean coverage "
              f"{s['coverage_mean']:.3f}, {s['coverage_in_band']} parameters in their binomial band; {rate}")
    elif "budget" in doc:
        h = doc["budget"].get("heading_rms_deg", {})
        print(f"wrote {out}/report.md: {len(st.runs)} runs; heading RMS floor {h.get('rms', {}).get('none', float('nan')):.4f}"
              f" deg, all sources {h.get('rms', {}).get('all', float('nan')):.4f} deg; {rate}")
    else:
        print(f"wrote {out}/report.md: {len(st.runs)} runs; {rate}")
