"""Benchmark of mismatch discovery on the concealed-effect suite (not a timed test).

For every effect of the suite: detection rate (correct channels and name, nothing else) at a
realistic size, false discoveries on null records, the fitted parameter's error against truth
(in standard errors), and a power curve -- the smallest size detected in >= 95 % of seeds.

    python benchmarks/bench_diagnose.py --seeds 20        # the full study (a few minutes)
    python benchmarks/bench_diagnose.py --seeds 4 --quick # a smoke run
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np

from imurig.diagnose.suite import CASES, diagnose_case, found_effects, null_groups, null_recording


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--quick", action="store_true", help="skip the power curves")
    a = ap.parse_args(argv)
    seeds = list(range(100, 100 + a.seeds))
    t0 = time.perf_counter()
    out = {"null": {}, "effects": {}}
    for group, case in null_groups().items():
        fd = 0
        for s in seeds:
            fd += bool(found_effects(diagnose_case(case, null_recording(case, s), s, null=True)))
        out["null"][group] = {"records": len(seeds), "with_false_discovery": fd, "rate": fd / len(seeds)}
        print("null", group, json.dumps(out["null"][group]), flush=True)
    for case in CASES:
        hits, z = 0, []
        for s in seeds:
            rec = case.make(s, case.realistic_size)
            d = diagnose_case(case, rec, s)
            hits += found_effects(d) == case.expected
            if case.truth_param and case.found_param and case.found_param(d):
                est, se = case.found_param(d)
                z.append((est - case.truth_param(rec)) / se)
        row = {"realistic_size": case.realistic_size, "size_unit": case.size_unit,
               "detection_rate": hits / len(seeds),
               "parameter_z_rms": float(np.sqrt(np.mean(np.square(z)))) if z else None}
        if not a.quick and case.sizes:
            curve = {}
            for size in case.sizes:
                h = sum(found_effects(diagnose_case(case, case.make(s, size), s)) >= case.expected for s in seeds)
                curve[size] = h / len(seeds)
            row["power_curve"] = curve
            ok = [sz for sz, p in curve.items() if p >= 0.95]
            row["smallest_size_detected_95pct"] = min(ok) if ok else None
        out["effects"][case.effect] = row
        print(case.effect, json.dumps(row), flush=True)
    out["wall_s"] = round(time.perf_counter() - t0, 1)
    print(json.dumps(out["null"]))
    print(json.dumps(out, indent=1))
    return out


if __name__ == "__main__":
    main()
