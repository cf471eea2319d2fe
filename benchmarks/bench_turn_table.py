"""Benchmark of the turn-table campaign (not a timed test): wall, CPU and peak memory per stage.

Each repeat runs in a fresh process, one after the other:
- ``simulate``: the default campaign's record (the table's truth: MuJoCo for the ramps between rates and
  the closed form while a rate is held, or ``--truth mujoco``, MuJoCo for every sample; then the sensor
  chain with slip rings, converter and timers), wall and CPU of the rig and of the chain, the peak memory
  after the rig and after the chain;
- optionally (``--cli``) the whole ``imurig campaign turn-table`` command (with the timer and arm
  studies, SIMONA, figures, HDF5 and .rrd) in its own process.
Medians over the repeats, with the load average (``os.getloadavg``) before and after, since the
machine may be shared. ``--mounts r_up`` simulates one mounting (a third of the samples).

    python benchmarks/bench_turn_table.py                 # simulate, 1 repeat
    python benchmarks/bench_turn_table.py --repeat 3 --cli
    python benchmarks/bench_turn_table.py --mounts r_up   # one mounting
    python benchmarks/bench_turn_table.py --chain whole --truth mujoco  # MuJoCo steps every sample (the reference)
    python benchmarks/bench_turn_table.py --chain whole   # the whole-record chain (simulate()) instead of the stream
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

from bench_tilt_table import _child, cpu_s, peak_rss_mb

ROOT = Path(__file__).resolve().parents[1]


def simulate_once(mounts: tuple[str, ...] | None, truth: str = "closed_form", chain: str = "stream") -> dict:
    """The campaign's record in this process (a fresh one): wall, CPU and peak memory per stage. ``chain``:
    "stream" (what the command runs: the rows in pieces, the acquisition windows kept; no HDF5 file) or
    "whole" (``lab.measure`` on the whole rig record, what ``simulate()`` gives)."""
    from imurig.campaigns.turn_table import TurnTableCampaign
    from imurig.kernel import random_streams
    from imurig.rigs.turn_table import TurnTableProtocol

    camp = TurnTableCampaign(protocol=TurnTableProtocol(mounts=mounts) if mounts else TurnTableProtocol())
    if chain == "stream":
        from imurig.campaigns.turn_stream import stream_campaign

        if truth != "closed_form":
            raise SystemExit("--chain stream runs the closed-form truth; use --chain whole with --truth mujoco")
        c0, t0 = cpu_s(), time.perf_counter()
        s = stream_campaign(camp)
        res = {"simulate_s": time.perf_counter() - t0, "simulate_cpu_s": cpu_s() - c0, "samples_1kHz": s.n,
               "window_rows": s.rec.n, "streamed": s.streamed}
        res["samples_per_s"] = s.n / res["simulate_s"]
        res["peak_rss_MB"] = peak_rss_mb()
        return res
    table, lab, ss = camp.build()
    table.truth = truth
    c0, t0 = cpu_s(), time.perf_counter()
    rig = table.simulate(camp.protocol, camp.start_time, random_streams.generator("campaign/turn-table/rig", camp.seed))
    res = {"rig_s": time.perf_counter() - t0, "rig_cpu_s": cpu_s() - c0, "peak_rss_after_rig_MB": peak_rss_mb(),
           "samples_1kHz": rig.n}
    c1, t1 = cpu_s(), time.perf_counter()
    rec = lab.measure(rig, ss)
    res["chain_s"], res["chain_cpu_s"] = time.perf_counter() - t1, cpu_s() - c1
    res["simulate_s"] = time.perf_counter() - t0
    res["simulate_cpu_s"] = cpu_s() - c0
    res["channels"] = len(rec.channels)
    res["samples_per_s"] = rec.n / res["simulate_s"]
    res["peak_rss_MB"] = peak_rss_mb()
    return res


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--mounts", default=None, help="comma-separated mountings (default: the protocol's three)")
    ap.add_argument("--truth", default="closed_form", choices=("closed_form", "mujoco"),
                    help="the turn table's truth (TurnTable.truth)")
    ap.add_argument("--chain", default="stream", choices=("stream", "whole"),
                    help="the streamed chain (the command's) or the whole-record chain (simulate())")
    ap.add_argument("--cli", action="store_true", help="also time the whole `imurig campaign turn-table`")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    mounts = tuple(a.mounts.split(",")) if a.mounts else None
    if a.child:
        print(json.dumps(simulate_once(mounts, a.truth, a.chain)))
        return {}
    for v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):  # the children as the CLI runs
        os.environ.setdefault(v, "1")
    load0 = os.getloadavg()
    runs = []
    for _ in range(a.repeat):
        cmd = [sys.executable, str(Path(__file__).resolve()), "--child", "--truth", a.truth, "--chain", a.chain] + \
            (["--mounts", a.mounts] if a.mounts else [])
        out, wall, cpu, rss = _child(cmd)
        r = json.loads(out.strip().splitlines()[-1])
        r.update(process_wall_s=wall, process_cpu_s=cpu, process_peak_rss_MB=rss)
        if a.cli:
            with tempfile.TemporaryDirectory() as d:
                _, wall, cpu, rss = _child([sys.executable, "-m", "imurig.cli.main", "campaign", "turn-table",
                                            "--out", f"{d}/out"])
            r.update(cli_wall_s=wall, cli_cpu_s=cpu, cli_peak_rss_MB=rss)
        runs.append(r)
        print(json.dumps(r), flush=True)
    summary = {"repeats": a.repeat, "mounts": a.mounts or "all", "truth": a.truth, "chain": a.chain,
               "load_before": [round(x, 2) for x in load0],
               "load_after": [round(x, 2) for x in os.getloadavg()], "samples_1kHz": runs[-1]["samples_1kHz"]}
    for k in runs[-1]:
        if k != "samples_1kHz":
            summary[k] = round(statistics.median(r[k] for r in runs), 3)
    for k, v in summary.items():
        print(f"{k:26s} {v}")
    print(json.dumps(summary))
    return summary


if __name__ == "__main__":
    main()
