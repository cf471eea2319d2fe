"""Benchmark of the flight's navigation (not a timed test): IMU samples/s through the INS
pre-integration and mechanisation, filter epochs/s of the 18-state loosely coupled EKF (GPS
position + velocity at 1 Hz, magnetic heading at 1 Hz, temperatures at 1 Hz), the filter's
real-time factor, wall time and peak resident memory.

Input: the paper's static attitude tests (``imurig.flights.truth.static_tests_truth``, 200 s
at 100 Hz) tiled ``--repeat`` times, with synthetic sensors of the filter's own error model.

    python benchmarks/bench_ekf.py                 # 200 s, nav 25 Hz
    python benchmarks/bench_ekf.py --repeat 5 --nav-rate 50
"""
from __future__ import annotations

import argparse
import json
import resource
import sys
import time

import numpy as np
from imurig.flights import ekf, ins
from imurig.flights.synthetic import synthetic_sensors
from imurig.flights.truth import static_tests_truth


def peak_rss_mb() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return (r if sys.platform == "darwin" else r * 1024) / 2**20


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=1, help="tile the 200 s static test this many times")
    ap.add_argument("--nav-rate", type=float, default=25.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--uncalibrated-states", action="store_true",
                    help="the uncalibrated run's state vector (scale, misalignment, nonlinearity, thermal, "
                         "gyro-instability and compass states: 58) instead of the paper's 18")
    a = ap.parse_args(argv)
    tr = static_tests_truth(dwell_s=60.0 * a.repeat)
    noise = ekf.ImuNoise()
    imu, gps, _ = synthetic_sensors(tr, noise, np.random.default_rng(a.seed), lever_gps_B=tr.lever_gps_B,
                                        mag_sigma_rad=np.radians(0.5))
    n = tr.n
    K = max(1, round(tr.rate_hz / a.nav_rate))
    t0 = time.perf_counter()
    inc = ins.preintegrate(tr.time_s, imu.w_IB_B, imu.f_B, K)
    t_pre = time.perf_counter() - t0
    x0 = ins.NavState(float(tr.lat_rad[0]), float(tr.lon_rad[0]), float(tr.h_m[0]), tr.v_N[0].copy(),
                      tr.q_NB[0].copy())
    t0 = time.perf_counter()
    x = x0.copy()
    for k in range(inc.dtheta_B.shape[0]):
        x = ins.nav_step(x, inc.dtheta_B[k], inc.dv_B[k], inc.T_s)
    t_mech = time.perf_counter() - t0
    extra = {}
    if a.uncalibrated_states:
        extra = {"estimate_scale_factors": True, "estimate_misalignments": True, "estimate_nonlinearity": True,
                     "estimate_thermal_terms": True, "sigma0_acc_thermal": (1e-4, 1e-4, 1e-3, 1e-3),
                     "gyro_bias_gm_states": True, "mag_error_state": True, "mag_error_sigma_rad": 0.08,
                     "gps_pos_tau_s": 100.0, "gps_pos_sigma_white_N_m": (0.1, 0.1, 0.2)}
    cfg = ekf.FilterConfig(nav_rate_hz=a.nav_rate, mag_heading_sigma_rad=np.radians(0.5), **extra)
    f = ekf.LooseEKF(cfg, noise, lever_gps_B=tr.lever_gps_B)
    t0 = time.perf_counter()
    res = f.fit(imu, gps, x0).solution_
    t_filt = time.perf_counter() - t0
    dur = float(tr.time_s[-1] - tr.time_s[0])
    out = {"states": cfg.n_states, "duration_s": dur, "imu_samples": n, "imu_rate_hz": tr.rate_hz, "nav_rate_hz": a.nav_rate,
           "epochs": int(res.time_s.size),
           "preintegration_samples_per_s": n / t_pre,
           "ins_only_samples_per_s": n / (t_pre + t_mech), "ins_only_real_time_factor": dur / (t_pre + t_mech),
           "filter_epochs_per_s": res.time_s.size / t_filt, "filter_imu_samples_per_s": n / t_filt,
           "filter_real_time_factor": dur / t_filt, "filter_wall_s": t_filt, "peak_rss_MB": peak_rss_mb()}
    print(json.dumps(out, indent=1))
    return out


if __name__ == "__main__":
    main()
