"""Benchmark of the full default tilt-table campaign (not a timed test).

Reports wall time of each stage, simulated samples per second and peak resident memory.

    python benchmarks/bench_tilt_table.py            # full seed protocol (240 positions, 15 s each)
    python benchmarks/bench_tilt_table.py --quick    # 4 x 6 x 2 positions, 4 s each
"""
from __future__ import annotations

import argparse
import json
import resource
import sys
import tempfile
import time

from imurig.campaigns.tilt_table import TiltTableCampaign
from imurig.reports.tilt_table import analyse, run
from imurig.rigs.tilt_table import TiltTableProtocol


def peak_rss_mb() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return (r if sys.platform == "darwin" else r * 1024) / 2**20


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--with-outputs", action="store_true", help="also time report, HDF5 and .rrd writing")
    a = ap.parse_args(argv)
    proto = (TiltTableProtocol(theta_deg=(0, 30, 60, 90), phi_deg=(0, 60, 120, 180, 240, 300), dwell_s=4)
             if a.quick else TiltTableProtocol())
    camp = TiltTableCampaign(protocol=proto)
    res = {"positions": proto.n_positions}
    t0 = time.perf_counter()
    rec = camp.simulate()
    res["simulate_s"] = time.perf_counter() - t0
    res["samples_1kHz"] = rec.n
    res["channels"] = len(rec.channels)
    res["simulated_samples_per_s"] = rec.n / res["simulate_s"]
    res["peak_rss_after_simulate_MB"] = peak_rss_mb()
    t1 = time.perf_counter()
    analyse(rec, camp.model)
    res["analyse_s"] = time.perf_counter() - t1
    res["peak_rss_MB"] = peak_rss_mb()
    if a.with_outputs:
        with tempfile.TemporaryDirectory() as d:
            t2 = time.perf_counter()
            run(camp, f"{d}/out")
            res["full_run_with_outputs_s"] = time.perf_counter() - t2
        res["peak_rss_MB"] = peak_rss_mb()
    res = {k: (round(v, 2) if isinstance(v, float) else v) for k, v in res.items()}
    for k, v in res.items():
        print(f"{k:32s} {v}")
    print(json.dumps(res))
    return res


if __name__ == "__main__":
    main()
