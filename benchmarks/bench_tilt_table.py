"""Benchmark of the default tilt-table campaign beside gnss-ins-sim, in one run (not a timed test).

Each repeat runs, one after the other in fresh processes,
- the peer: gnss-ins-sim (``../shared/peers/``, see its README) generating 9-axis IMU + 10 Hz GPS
  at ``--peer-rate`` Hz for its 3-D demo trajectory (~80 s), and
- imurig: the campaign's simulation (MuJoCo rig + the streamed sensor chain with the low-pass of the
  windows, :mod:`imurig.campaigns.tilt_stream`) and analysis (per-position statistics, the report's seven
  fits), optionally with the output folder (``imurig campaign tilt-table``: HDF5 written as it streams).
Per process: wall time, CPU time (user + system) and peak resident memory; samples per second
(1 kHz samples of the campaign, each 12 channels; the peer's IMU samples, each 9 axes) and
the ratio imurig / peer of samples per wall second (and per CPU second). Medians over the repeats; the load average
(``os.getloadavg``) before and after, since the machine may be shared.

    python benchmarks/bench_tilt_table.py                # full seed protocol (240 positions, 15 s each)
    python benchmarks/bench_tilt_table.py --quick        # 4 x 6 x 2 positions, 4 s each
    python benchmarks/bench_tilt_table.py --repeat 3 --with-outputs
    python benchmarks/bench_tilt_table.py --no-peer      # imurig alone
    python benchmarks/bench_tilt_table.py --command --repeat 8   # the whole command, in pairs with the peer

``--command`` times what a user waits for: ``imurig campaign tilt-table`` in a fresh process (the
interpreter's start, the imports, recording.h5 written as it streams, the figures, campaign.rrd, the report),
into a temporary folder, and the peer's whole process beside it, in turn (peer, imurig, peer, imurig, ...):
each pair's ratio of samples per wall second is taken pair by pair, so that the machine's speed drifting
over the call moves both sides of a pair alike. Both sides' wall, CPU and peak memory are those of their
whole processes (the operating system's accounting, ``wait4``), the peer's imports included.
"""
from __future__ import annotations

import os

# as the CLI does (imurig/cli/__init__.py): one BLAS thread, set before numpy loads
for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import re
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PEER = ROOT.parent / "shared" / "peers" / "bench_gnss_ins_sim.py"


def peak_rss_mb() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return (r if sys.platform == "darwin" else r * 1024) / 2**20


def cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def imurig_once(quick: bool, with_outputs: bool) -> dict:
    """The campaign in this process (a fresh one): wall, CPU and peak memory per stage."""
    from imurig.campaigns.tilt_rig import RigAhead
    from imurig.campaigns.tilt_stream import stream_campaign
    from imurig.campaigns.tilt_table import TiltTableCampaign
    from imurig.reports.tilt_table import analyse, run
    from imurig.rigs.tilt_table import TiltTableProtocol

    proto = (TiltTableProtocol(theta_deg=(0, 30, 60, 90), phi_deg=(0, 60, 120, 180, 240, 300), dwell_s=4)
             if quick else TiltTableProtocol())
    camp = TiltTableCampaign(protocol=proto)
    res = {"positions": proto.n_positions}
    c0, t0 = cpu_s(), time.perf_counter()
    # the streamed chain, as the command runs it (the rig's run started ahead, its MuJoCo moves beside the
    # stream; no file: the outputs are below)
    sim = stream_campaign(camp, rig=RigAhead.start(seed=camp.seed, protocol=proto, start_time=camp.start_time))
    res["simulate_s"] = time.perf_counter() - t0
    res["samples_1kHz"] = sim.n
    res["channels"] = len(sim.rec100.channels)
    res["streamed"] = sim.streamed
    res["peak_rss_after_simulate_MB"] = peak_rss_mb()
    t1 = time.perf_counter()
    out = analyse(sim.rec100, camp.model, processed=sim.rec100)
    res["analyse_s"] = time.perf_counter() - t1
    res["campaign_wall_s"] = time.perf_counter() - t0
    res["campaign_cpu_s"] = cpu_s() - c0
    z = [p["z"] for p in out["parameters"] if p["z"] is not None]
    res["z_rms"] = (sum(v * v for v in z) / len(z)) ** 0.5 if z else None
    res["within_4se"] = f"{sum(abs(v) <= 4 for v in z)}/{len(z)}"
    del sim, out
    if with_outputs:
        with tempfile.TemporaryDirectory() as d:
            t2 = time.perf_counter()
            run(camp, f"{d}/out")
            res["full_run_with_outputs_s"] = time.perf_counter() - t2
    res["samples_per_s"] = res["samples_1kHz"] / res["campaign_wall_s"]
    res["peak_rss_MB"] = peak_rss_mb()
    return res


def _child(cmd: list[str], env: dict | None = None) -> tuple[str, float, float, float]:
    """Run ``cmd`` (in ``env``, default this one's); its stdout, wall time, CPU time and peak memory (MB, from
    wait4)."""
    with tempfile.TemporaryFile("w+") as fo, tempfile.TemporaryFile("w+") as fe:  # no pipe to fill up
        t0 = time.perf_counter()
        p = subprocess.Popen(cmd, stdout=fo, stderr=fe, text=True, cwd=ROOT, env=env)
        _, status, ru = os.wait4(p.pid, 0)
        wall = time.perf_counter() - t0
        p.returncode = os.waitstatus_to_exitcode(status)
        fo.seek(0)
        fe.seek(0)
        out, err = fo.read(), fe.read()
    if p.returncode:
        raise SystemExit(f"{' '.join(cmd)} failed (exit {p.returncode}):\n{err[-2000:]}")
    rss = (ru.ru_maxrss if sys.platform == "darwin" else ru.ru_maxrss * 1024) / 2**20
    return out, wall, ru.ru_utime + ru.ru_stime, rss


def peer_once(rate_hz: float) -> dict:
    """gnss-ins-sim in a fresh process: its samples, wall, CPU and peak memory."""
    out, wall, cpu, rss = _child([sys.executable, str(PEER), f"{rate_hz:g}"])
    m = re.search(r"samples (\d+) sim_s ([\d.]+) wall_s ([\d.]+)", out)
    if not m:
        raise SystemExit(f"unexpected output from {PEER}: {out!r}")
    n, inner_wall = int(m.group(1)), float(m.group(3))
    return {"samples": n, "sim_s": float(m.group(2)), "wall_s": inner_wall, "process_wall_s": wall,
            "cpu_s": cpu, "peak_rss_MB": rss, "samples_per_s": n / inner_wall}


def command_once(quick: bool) -> dict:
    """``imurig campaign tilt-table`` as a user runs it, in a fresh process, into a temporary folder: its
    wall, CPU and peak memory (the whole process: start, imports, HDF5, figures, .rrd), and its samples."""
    exe = shutil.which("imurig", path=str(Path(sys.executable).parent))
    cmd = [exe] if exe else [sys.executable, "-c", "from imurig.cli import run; run()"]
    with tempfile.TemporaryDirectory() as d:
        cmd += ["campaign", "tilt-table", "--out", f"{d}/out"]
        if quick:
            cmd += ["--theta", "0,30,60,90", "--phi", "0,60,120,180,240,300", "--dwell", "4"]
        _, wall, cpu, rss = _child(cmd, env={**os.environ, "IMURIG_PROGRESS": "0"})   # no bar on a file
        with open(f"{d}/out/summary.json") as f:
            summary = json.load(f)
    checked = [p["within_bound"] for p in summary["parameters"] if p["within_bound"] is not None]
    return {"wall_s": wall, "cpu_s": cpu, "peak_rss_MB": rss, "samples": summary["n_samples"],
            "within_4se": f"{sum(checked)}/{len(checked)}"}


def command_pairs(a) -> dict:
    """``--command``: the whole command and the peer's whole process in turn, ``a.repeat`` pairs."""
    load0 = os.getloadavg()
    pairs = []
    for _ in range(a.repeat):
        peer = peer_once(a.peer_rate)
        im = command_once(a.quick)
        ratio = (im["samples"] / im["wall_s"]) / (peer["samples"] / peer["process_wall_s"])
        ratio_cpu = (im["samples"] / im["cpu_s"]) / (peer["samples"] / peer["cpu_s"])
        pairs.append({"imurig": im, "peer": peer, "ratio_samples_per_s": ratio, "ratio_samples_per_cpu_s": ratio_cpu})
        print(json.dumps(pairs[-1]), flush=True)
    med = statistics.median
    summary = {"pairs": len(pairs), "load_before": [round(x, 2) for x in load0],
               "load_after": [round(x, 2) for x in os.getloadavg()],
               "imurig_command_samples": pairs[-1]["imurig"]["samples"],
               "imurig_command_within_4se": pairs[-1]["imurig"]["within_4se"]}
    for k in ("wall_s", "cpu_s", "peak_rss_MB"):
        vals = [p["imurig"][k] for p in pairs]
        summary[f"imurig_command_{k}"] = med(vals)
        summary[f"imurig_command_{k}_min_max"] = [min(vals), max(vals)]
    for k, src in (("process_wall_s", "process_wall_s"), ("cpu_s", "cpu_s"), ("peak_rss_MB", "peak_rss_MB")):
        summary[f"peer_{k}"] = med([p["peer"][src] for p in pairs])
    summary["peer_samples"] = pairs[-1]["peer"]["samples"]
    summary["peer_samples_per_s"] = med([p["peer"]["samples"] / p["peer"]["process_wall_s"] for p in pairs])
    for k in ("ratio_samples_per_s", "ratio_samples_per_cpu_s"):
        vals = [p[k] for p in pairs]
        summary[k] = med(vals)
        summary[f"{k}_min_max"] = [min(vals), max(vals)]
    return _report(summary)


def _report(summary: dict) -> dict:
    """The summary rounded (floats, and lists of floats, to 3 decimals), printed a line a figure, then as JSON."""
    r3 = lambda v: round(v, 3) if isinstance(v, float) else v  # noqa: E731
    summary = {k: [r3(x) for x in v] if isinstance(v, list) else r3(v) for k, v in summary.items()}
    for k, v in summary.items():
        print(f"{k:34s} {v}")
    print(json.dumps(summary))
    return summary


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--with-outputs", action="store_true", help="also time report, HDF5 and .rrd writing")
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--no-peer", action="store_true", help="skip gnss-ins-sim")
    ap.add_argument("--peer-rate", type=float, default=1000.0)
    ap.add_argument("--command", action="store_true",
                    help="the whole `imurig campaign tilt-table` process in pairs with the peer's whole process")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.child:
        print(json.dumps(imurig_once(a.quick, a.with_outputs)))
        return {}
    if not a.no_peer and not PEER.exists():
        raise SystemExit(f"{PEER} not found; give --no-peer or put the peers next to the repository")
    if a.command:
        if a.no_peer:
            raise SystemExit("--command pairs the command with the peer: leave out --no-peer")
        return command_pairs(a)
    load0 = os.getloadavg()
    runs = []
    for _ in range(a.repeat):
        peer = None if a.no_peer else peer_once(a.peer_rate)
        cmd = [sys.executable, str(Path(__file__).resolve()), "--child"] + ["--quick"] * a.quick \
            + ["--with-outputs"] * a.with_outputs
        out, wall, cpu, rss = _child(cmd)
        im = json.loads(out.strip().splitlines()[-1])
        im.update(process_wall_s=wall, process_cpu_s=cpu, process_peak_rss_MB=rss)
        runs.append({"imurig": im, "peer": peer})
        print(json.dumps(runs[-1]), flush=True)
    med = lambda xs: statistics.median(xs)  # noqa: E731
    summary = {"repeats": a.repeat, "load_before": [round(x, 2) for x in load0],
               "load_after": [round(x, 2) for x in os.getloadavg()]}
    for k in ("campaign_wall_s", "campaign_cpu_s", "simulate_s", "analyse_s", "samples_per_s", "peak_rss_MB",
              "process_wall_s", "process_cpu_s", "process_peak_rss_MB", "full_run_with_outputs_s"):
        vals = [r["imurig"][k] for r in runs if k in r["imurig"]]
        if vals:
            summary[f"imurig_{k}"] = med(vals)
    for k in ("samples_1kHz", "channels", "z_rms", "within_4se"):
        summary[f"imurig_{k}"] = runs[-1]["imurig"][k]
    if not a.no_peer:
        for k in ("samples", "wall_s", "cpu_s", "peak_rss_MB", "samples_per_s"):
            summary[f"peer_{k}"] = med([r["peer"][k] for r in runs])
        summary["ratio_samples_per_s"] = med([r["imurig"]["samples_per_s"] / r["peer"]["samples_per_s"]
                                              for r in runs])
        # per CPU second (less sensitive to the load; the peer's CPU includes its interpreter and imports)
        summary["ratio_samples_per_cpu_s"] = med([(r["imurig"]["samples_1kHz"] / r["imurig"]["campaign_cpu_s"])
                                                  / (r["peer"]["samples"] / r["peer"]["cpu_s"]) for r in runs])
    return _report(summary)


if __name__ == "__main__":
    main()
