"""Benchmark of the flight's navigation filter (not a timed test): filter epochs/s and the real-time
factor of the loosely coupled EKF (GPS position + velocity at 1 Hz, magnetic heading at 1 Hz,
temperatures at 1 Hz), with wall time, CPU time and peak memory, as the median of ``--repeats``
runs on the same data; also IMU samples/s of the INS alone (pre-integration + mechanisation).

Input: the paper's static attitude tests (``imurig.flights.truth.static_tests_truth``, 200 s at
100 Hz, ``--repeat`` times longer dwells) with synthetic sensors of the filter's own error model.

The machine may be shared: the load average (``os.getloadavg``) before and after is printed, and
with ``--baseline FILE`` (the JSON a previous run wrote with ``--save FILE``, e.g. before a change)
the ratio of the medians, which the load affects less than the absolute times.

    python benchmarks/bench_ekf.py                              # 18 states, nav 25 Hz, 5 repeats
    python benchmarks/bench_ekf.py --save before.json           # keep the figures
    python benchmarks/bench_ekf.py --baseline before.json       # ... and compare with them later
    python benchmarks/bench_ekf.py --filter extended --nav-rate 50
    python benchmarks/bench_ekf.py --python --save py.json     # the plain Python path (compiled=False)
    python benchmarks/bench_ekf.py --baseline py.json          # ... and the compiled one against it

The paper's 18 states run their propagation between updates compiled (numba,
``imurig.flights.ekf_kernel``); the warm-up run compiles it (the first time after an install or an
edit, ~4.5 CPU-s) or loads it from the on-disk cache, and is not counted.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import sys
import time
import tracemalloc

import numpy as np
from imurig.flights import ekf, ins
from imurig.flights.synthetic import synthetic_sensors
from imurig.flights.truth import static_tests_truth

#: the uncalibrated flight's sensor-error states (scale, misalignment, nonlinearity, thermal,
#: receiver, gyro-instability and compass states: 58 in all), the ``extended`` choice
EXTENDED = {"estimate_scale_factors": True, "estimate_misalignments": True, "estimate_nonlinearity": True,
            "estimate_thermal_terms": True, "sigma0_acc_thermal": (1e-4, 1e-4, 1e-3, 1e-3),
            "gyro_bias_gm_states": True, "mag_error_state": True, "mag_error_sigma_rad": 0.08,
            "gps_pos_states": True, "gps_pos_tau_s": 100.0, "gps_pos_sigma_white_N_m": (0.1, 0.1, 0.2)}


def peak_rss_mb() -> float:
    """Peak resident memory of this process so far, MiB."""
    r = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return (r if sys.platform == "darwin" else r * 1024) / 2**20


def _timed(fn):
    """(result, wall s, CPU s) of ``fn()``."""
    w0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - w0, time.process_time() - c0


def _ratios(out: dict, base: dict) -> dict:
    """after/before of the medians (speed: > 1 is faster; memory: < 1 is leaner)."""
    keys = ("filter_epochs_per_s", "filter_real_time_factor", "ins_only_real_time_factor")
    r = {k: out[k] / base[k] for k in keys if k in base}
    for k in ("filter_wall_s", "filter_cpu_s", "filter_peak_alloc_MB"):
        if k in base:
            r[k] = out[k] / base[k]
    return r


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=1, help="dwells this many times longer (200 s at 1)")
    ap.add_argument("--repeats", type=int, default=5, help="timed runs; the medians are reported")
    ap.add_argument("--nav-rate", type=float, default=25.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--filter", default="paper18", choices=["paper18", "extended"],
                    help="'paper18': the paper's 18 states; 'extended': the uncalibrated flight's 58")
    ap.add_argument("--python", action="store_true", help="the plain Python path (LooseEKF(compiled=False))")
    ap.add_argument("--save", default=None, help="write the figures to this JSON file")
    ap.add_argument("--baseline", default=None, help="a JSON written by --save: print after/before ratios")
    a = ap.parse_args(argv)
    load0 = os.getloadavg()
    tr = static_tests_truth(dwell_s=60.0 * a.repeat)
    noise = ekf.ImuNoise()
    imu, gps, _ = synthetic_sensors(tr, noise, np.random.default_rng(a.seed), lever_gps_B=tr.lever_gps_B,
                                    mag_sigma_rad=np.radians(0.5))
    n, dur = tr.n, float(tr.time_s[-1] - tr.time_s[0])
    K = max(1, round(tr.rate_hz / a.nav_rate))
    x0 = ins.NavState(float(tr.lat_rad[0]), float(tr.lon_rad[0]), float(tr.h_m[0]), tr.v_N[0].copy(),
                      tr.q_NB[0].copy())

    def ins_only():
        inc = ins.preintegrate(tr.time_s, imu.w_IB_B, imu.f_B, K)
        x = x0.copy()
        for k in range(inc.dtheta_B.shape[0]):
            x = ins.nav_step(x, inc.dtheta_B[k], inc.dv_B[k], inc.T_s)
        return x

    cfg = ekf.FilterConfig(nav_rate_hz=a.nav_rate, mag_heading_sigma_rad=np.radians(0.5),
                           **(EXTENDED if a.filter == "extended" else {}))
    f = ekf.LooseEKF(cfg, noise, lever_gps_B=tr.lever_gps_B, compiled=not a.python)

    def run_filter():
        return f.fit(imu, gps, x0).solution_

    res, *_ = _timed(run_filter)                   # warm-up (imports, caches), not counted
    runs = [_timed(run_filter) for _ in range(a.repeats)]
    ins_runs = [_timed(ins_only) for _ in range(a.repeats)]
    tracemalloc.start()                            # one traced run for the allocations' peak (slower)
    run_filter()
    peak_alloc = tracemalloc.get_traced_memory()[1] / 2**20
    tracemalloc.stop()
    wall = statistics.median(r[1] for r in runs)
    cpu = statistics.median(r[2] for r in runs)
    ins_wall = statistics.median(r[1] for r in ins_runs)
    epochs = int(res.time_s.size)
    out = {"filter": a.filter, "compiled": f.compiled and cfg.n_states == 18,
           "states": cfg.n_states, "duration_s": dur, "imu_samples": n,
           "imu_rate_hz": tr.rate_hz, "nav_rate_hz": a.nav_rate, "epochs": epochs, "repeats": a.repeats,
           "filter_epochs_per_s": epochs / wall, "filter_real_time_factor": dur / wall,
           "filter_wall_s": wall, "filter_wall_s_all": [round(r[1], 4) for r in runs],
           "filter_cpu_s": cpu, "filter_peak_alloc_MB": peak_alloc,
           "ins_only_samples_per_s": n / ins_wall, "ins_only_real_time_factor": dur / ins_wall,
           "peak_rss_MB": peak_rss_mb(), "load_avg_before": load0, "load_avg_after": os.getloadavg(),
           "cpus": os.cpu_count()}
    if a.baseline:
        with open(a.baseline) as fh:
            out["after_over_before"] = _ratios(out, json.load(fh))
    print(json.dumps(out, indent=1))
    if a.save:
        with open(a.save, "w") as fh:
            json.dump(out, fh, indent=1)
    return out


if __name__ == "__main__":
    main()
