"""Benchmark of the Monte-Carlo engine (issue 7): simulated sensor samples per second for one
tilt-table (or turn-table) run, runs per minute for a study on this machine, peak memory, and
how the run time grows with the campaign length and with the number of runs.

    python benchmarks/bench_montecarlo.py [--workers 2] [--quick] [--campaign turn-table]

Campaign length: the dwell per position (tilt table) or the least whole-round window per
step (turn table, quick protocol).

Prints Markdown tables (pasted into docs/montecarlo.md) and writes nothing else.
"""
from __future__ import annotations

import argparse
import os
import resource
import shutil
import tempfile
import time

import numpy as np


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


LENGTH = {"tilt-table": "dwell_s", "turn-table": "min_window_s"}


def one_run(dwells, repeats: int = 3, campaign: str = "tilt-table") -> list[dict]:
    """Wall time of one run (simulate + calibrate + CRLB) in this process vs campaign length."""
    from imurig.montecarlo import registry
    from imurig.montecarlo.engine import run_seed

    camp = registry.get(campaign)
    out = []
    for dwell in dwells:
        p = camp.validate({LENGTH[campaign]: float(dwell)})
        camp.run(p, run_seed(0, 999))  # warm the per-process caches (layout, IGRF field)
        walls, sims = [], []
        for i in range(repeats):
            t0 = time.perf_counter()
            r = camp.run(p, run_seed(0, i))
            walls.append(time.perf_counter() - t0)
            sims.append(r["info"]["simulate_s"])
        n = r["info"]["samples"]
        ch = r["info"]["channels"]
        out.append({"dwell_s": dwell, "samples": n, "channels": ch, "run_s": float(np.median(walls)),
                    "simulate_s": float(np.median(sims)),
                    "samples_per_s": n / float(np.median(sims)),
                    "channel_samples_per_s": n * ch / float(np.median(sims))})
    return out


def study(ns, workers: int, campaign: str = "tilt-table") -> list[dict]:
    """Compute time of studies of N runs on one local cluster (started once)."""
    from imurig.montecarlo.engine import dask_client, run_study

    out = []
    with dask_client(workers=workers) as c:
        run_study(campaign, 2, 0, client=c, report=False)  # warm the workers
        for n in ns:
            d = tempfile.mkdtemp(prefix="bench_mc_")
            try:
                st = run_study(campaign, n, 1, client=c, out=os.path.join(d, "s"), report=False)
            finally:
                shutil.rmtree(d, ignore_errors=True)
            out.append({"runs": n, "compute_s": st.timing["compute_s"], "runs_per_min": st.timing["runs_per_min"]})
        rss = c.run(lambda: resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
    return out, max(rss.values())


def _fit(x, y):
    A = np.column_stack([np.ones(len(x)), x])
    coef, *_ = np.linalg.lstsq(A, np.asarray(y), rcond=None)
    pred = A @ coef
    r2 = 1 - np.sum((y - pred) ** 2) / np.sum((y - np.mean(y)) ** 2)
    return coef, r2


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--quick", action="store_true", help="fewer points")
    ap.add_argument("--campaign", choices=sorted(LENGTH), default="tilt-table")
    a = ap.parse_args()
    os.environ.setdefault("IMURIG_PROGRESS", "0")
    if a.campaign == "turn-table":
        dwells = (4, 8, 16) if a.quick else (4, 8, 16, 32)
    else:
        dwells = (5, 15, 30) if a.quick else (5, 15, 30, 60)
    ns = (8, 16) if a.quick else (10, 20, 40)

    s, worker_rss = study(ns, a.workers, a.campaign)
    print(f"## {a.campaign}: studies on a local cluster of {a.workers} worker processes (default schedule)\n")
    print("| runs | compute (s) | runs/min |")
    print("|---|---|---|")
    for r in s:
        print(f"| {r['runs']} | {r['compute_s']:.1f} | {r['runs_per_min']:.1f} |")
    coef, r2 = _fit([r["runs"] for r in s], [r["compute_s"] for r in s])
    print(f"\nstudy time = {coef[0]:.2f} s + {coef[1]:.3f} s x runs  (R^2 = {r2:.4f}); "
          f"{60 / coef[1]:.1f} runs/min at the margin")
    print(f"peak RSS per worker: {worker_rss:.0f} MB; client process so far: {_rss_mb():.0f} MB\n")

    t = one_run(dwells, campaign=a.campaign)
    print(f"## One {a.campaign} run (this process): time vs campaign length ({LENGTH[a.campaign]})\n")
    print(f"| {LENGTH[a.campaign]} | samples | run (s) | simulate (s) | samples/s | channel-samples/s |")
    print("|---|---|---|---|---|---|")
    for r in t:
        print(f"| {r['dwell_s']:g} | {r['samples']} | {r['run_s']:.3f} | {r['simulate_s']:.3f} | "
              f"{r['samples_per_s']:.3g} | {r['channel_samples_per_s']:.3g} |")
    coef, r2 = _fit([r["samples"] for r in t], [r["run_s"] for r in t])
    print(f"\nrun time = {coef[0]:.3f} s + {coef[1] * 1e6:.3f} us x samples  (R^2 = {r2:.4f})")
    print(f"peak RSS of this process (after the longest run): {_rss_mb():.0f} MB")


if __name__ == "__main__":
    main()
