"""Benchmark of the flight simulation (not a timed test): the default Citation flight and the van.

Reports, per stage, wall time, simulated IMU samples per second, the real-time factor
(flight time / wall time) and the peak resident memory of the process.

    python benchmarks/bench_flight_sim.py            # default flight plan (~15 min) + default van test
    python benchmarks/bench_flight_sim.py --quick    # a 1-minute airborne plan and a short van run
"""
from __future__ import annotations

import argparse
import json
import resource
import sys
import time


def peak_rss_mb() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return (r if sys.platform == "darwin" else r * 1024) / 2**20


def main(argv=None) -> dict:
    from imurig.flights.gps import GpsReceiver
    from imurig.flights.imu import measure_flight
    from imurig.flights.plan import (
        AlphaDotSTurns,
        FlightPlan,
        Level,
        fly,
        simulate_flight,
    )
    from imurig.flights.van import (
        VanCircle,
        VanHardBrake,
        VanParked,
        VanPlan,
        VanStraight,
        simulate_van,
    )
    from imurig.sensors.chain import ImuLab
    from imurig.kernel import random_streams

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    a = ap.parse_args(argv)
    plan = (FlightPlan(phases=(Level(20.0), AlphaDotSTurns(banks_first_deg=(30,), banks_second_deg=(30,)), Level(10.0)))
            if a.quick else FlightPlan())
    van = (VanPlan(phases=(VanParked(5.0), VanStraight(10.0), VanCircle(turns=1.0), VanHardBrake()))
           if a.quick else VanPlan())
    res = {}
    t0 = time.perf_counter()
    flown = fly(plan, progress_bar=False)
    res["mujoco_flight_s"] = time.perf_counter() - t0
    n = flown.kinematics.time_s.size
    res["flight_time_s"] = n / plan.rate_hz
    res["imu_samples"] = n
    res["mujoco_samples_per_s"] = n / res["mujoco_flight_s"]
    res["mujoco_real_time_factor"] = res["flight_time_s"] / res["mujoco_flight_s"]
    t0 = time.perf_counter()
    truth = simulate_flight(plan, progress_bar=False)
    res["truth_total_s"] = time.perf_counter() - t0
    res["truth_after_mujoco_s"] = res["truth_total_s"] - truth.meta["sim_wall_s"]
    t0 = time.perf_counter()
    fixes = GpsReceiver.euro4("rtk").measure(truth, random_streams.generator("flight/gps", 2005))
    res["gps_s"], res["gps_fixes"] = time.perf_counter() - t0, fixes.n
    t0 = time.perf_counter()
    lab = ImuLab.draw(random_streams.generator("sensor_errors", 2005))
    rec = measure_flight(truth, lab, random_streams.seed_sequence("flight/sensor-chain", 2005))
    res["imu_chain_s"], res["imu_channels"] = time.perf_counter() - t0, len(rec.channels)
    res["flight_end_to_end_s"] = res["truth_total_s"] + res["gps_s"] + res["imu_chain_s"]
    res["end_to_end_real_time_factor"] = res["flight_time_s"] / res["flight_end_to_end_s"]
    t0 = time.perf_counter()
    vt = simulate_van(van)
    res["van_total_s"], res["van_time_s"] = time.perf_counter() - t0, vt.n / vt.rate_hz
    res["van_real_time_factor"] = res["van_time_s"] / res["van_total_s"]
    res["peak_rss_mb"] = peak_rss_mb()
    print(json.dumps({k: (round(v, 3) if isinstance(v, float) else v) for k, v in res.items()}, indent=1))
    return res


if __name__ == "__main__":
    main()
