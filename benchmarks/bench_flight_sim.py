"""Benchmark of the flight simulation (not a timed test): the default Citation flight and the van.

Reports, per stage, wall time, simulated IMU samples per second, the real-time factor
(flight time / wall time) and the peak resident memory of the process.

    python benchmarks/bench_flight_sim.py            # default flight plan (~15 min) + default van test
    python benchmarks/bench_flight_sim.py --quick    # a 1-minute airborne plan and a short van run
    python benchmarks/bench_flight_sim.py --peer     # beside gnss-ins-sim on comparable work, in one run

``--peer``: gnss-ins-sim (``../shared/peers/``, see its README; a fresh process) generates 9-axis
IMU + 10 Hz GPS at 1 kHz for its 3-D demo trajectory (~80 s); imurig flies an 80 s airborne plan
(level, S-turns at 30 deg bank, level) at 1 kHz in MuJoCo and makes the flight's truth, 10 Hz GPS
fixes and the IMU chain's recording. Samples per wall second of each (the peer's own timer, without
its imports) and the ratio imurig / peer, with the load average before and after. As the peer's
timer leaves out its imports and set-up, ``--warmup`` runs of imurig's side (1 by default, not
counted) leave out imurig's one-time set-up: numba's typing and target registries at its first call
(~0.25 CPU-s) and the compiled flight steps and truth pass loaded from numba's disk cache (after an
install or an edit, compiled: seconds). ``imurig_cpu_s_warmup`` shows what those runs took
(``--warmup 0`` counts the first run; ``ratio_first_run`` is the first counted pair). Each run also gives imurig's CPU-s by stage (``cpu_s_stages``: flight + truth, GPS, IMU
chain), and the summary MuJoCo's own cost per step for the Citation in the air (``mj_step_us``, CPU).
"""
from __future__ import annotations

import os

# as the CLI does (imurig/cli/__init__.py) and the other benchmarks: one BLAS thread, set before numpy loads
for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import resource  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402


def peak_rss_mb() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return (r if sys.platform == "darwin" else r * 1024) / 2**20


def mj_step_us(steps: int = 10_000, repeat: int = 5) -> float:
    """MuJoCo's own step for the Citation in the air as the flight takes it (contacts and constraint
    solver off, 1 kHz, without the profiling clock: :mod:`imurig.rigs.mujoco_clock`): CPU microseconds
    per ``mj_step``, the best of ``repeat`` loops of ``steps`` steps run inside MuJoCo (``nstep``: no
    Python call per step), no forces applied."""
    import mujoco
    from imurig.flights.aircraft import _NO_CONTACT, CitationSim
    from imurig.rigs.mujoco_clock import untimed

    sim = CitationSim(rate_hz=1000.0)
    sim.set_airborne(120.0, 1500.0)
    m, d = sim.model, sim.data
    m.opt.disableflags |= _NO_CONTACT
    untimed()
    q0, v0, best = d.qpos.copy(), d.qvel.copy(), math.inf
    for _ in range(repeat):
        d.qpos[:], d.qvel[:] = q0, v0
        c0 = time.process_time()
        mujoco.mj_step(m, d, nstep=steps)
        best = min(best, time.process_time() - c0)
    return round(best / steps * 1e6, 3)


def _imurig_once(plan) -> dict:
    """imurig's side of one pair: fly ``plan`` (MuJoCo and truth), its 10 Hz GPS fixes, the IMU chain's
    recording; wall, CPU and CPU-s per stage."""
    from imurig.flights.gps import GpsReceiver
    from imurig.flights.imu import measure_flight
    from imurig.flights.plan import simulate_flight
    from imurig.kernel import random_streams
    from imurig.sensors.chain import ImuLab

    t0, c0 = time.perf_counter(), time.process_time()
    truth = simulate_flight(plan, progress_bar=False)
    t_truth, c_truth = time.perf_counter() - t0, time.process_time() - c0
    GpsReceiver.euro4("rtk", rate_hz=10.0).measure(truth, random_streams.generator("flight/gps", 2005))
    c_gps = time.process_time() - c0
    lab = ImuLab.draw(random_streams.generator("sensor_errors", 2005))
    measure_flight(truth, lab, random_streams.seed_sequence("flight/sensor-chain", 2005))
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    return {"samples": truth.n, "sim_s": truth.n / plan.rate_hz, "wall_s": wall, "cpu_s": cpu,
            "mujoco_and_truth_s": t_truth, "samples_per_s": truth.n / wall,
            "cpu_s_stages": {"fly_and_truth": round(c_truth, 4), "gps": round(c_gps - c_truth, 4),
                             "imu_chain": round(cpu - c_gps, 4)}}


def beside_peer(repeat: int = 1, warmup: int = 1) -> dict:
    """imurig's 80 s flight at 1 kHz (MuJoCo, truth, GPS, IMU chain) beside gnss-ins-sim at 1 kHz:
    ``warmup`` runs of imurig's side first, not counted (module doc), then ``repeat`` pairs."""
    from imurig.flights import flight_kernel  # noqa: F401  (imported as a flight imports it: numba, outside the timer)
    from imurig.flights.plan import AlphaDotSTurns, FlightPlan, Level

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_tilt_table import PEER, peer_once   # the peer's runner (a fresh process, its own timer)

    if not PEER.exists():
        raise SystemExit(f"{PEER} not found; put the peers next to the repository")
    plan = FlightPlan(phases=(Level(37.0), AlphaDotSTurns(banks_first_deg=(30,), banks_second_deg=(30,)),
                              Level(10.0)), rate_hz=1000.0)
    load0, runs = os.getloadavg(), []
    warm = [_imurig_once(plan)["cpu_s"] for _ in range(warmup)]
    for _ in range(repeat):
        peer = peer_once(1000.0)
        im = _imurig_once(plan)
        runs.append({"imurig": im, "peer": peer, "ratio_samples_per_s": im["samples_per_s"] / peer["samples_per_s"]})
        print(json.dumps(runs[-1]), flush=True)
    ratios = sorted(r["ratio_samples_per_s"] for r in runs)
    med = lambda xs: sorted(xs)[len(xs) // 2]  # noqa: E731
    out = {"repeats": repeat, "warmup_runs": warmup, "ratio_samples_per_s_median": ratios[len(ratios) // 2],
           # each side's median over the runs, then their ratio: not tied to the load of each pair's moment
           "ratio_of_medians": med([r["imurig"]["samples_per_s"] for r in runs])
           / med([r["peer"]["samples_per_s"] for r in runs]),
           "imurig_cpu_s_median": med([r["imurig"]["cpu_s"] for r in runs]),
           "peer_cpu_s_median": med([r["peer"]["cpu_s"] for r in runs]),
           # the one-time set-up the warm-up runs paid (numba's registries, the cached compiled code loaded)
           "imurig_cpu_s_warmup": [round(c, 3) for c in warm],
           "ratio_first_run": runs[0]["ratio_samples_per_s"],
           "load_before": [round(x, 2) for x in load0], "load_after": [round(x, 2) for x in os.getloadavg()],
           "mj_step_us": mj_step_us(), "peak_rss_mb": peak_rss_mb()}
    print(json.dumps(out))
    return out


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
    ap.add_argument("--peer", action="store_true", help="beside gnss-ins-sim at 1 kHz (module doc)")
    ap.add_argument("--repeat", type=int, default=1, help="with --peer: runs; the median ratio")
    ap.add_argument("--warmup", type=int, default=1,
                    help="with --peer: imurig's runs before the counted ones, not counted (module doc)")
    a = ap.parse_args(argv)
    if a.peer:
        return beside_peer(a.repeat, a.warmup)
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
