"""Flying a flight plan: the Citation in MuJoCo (:mod:`imurig.flights.aircraft`) flown through the
plan's phases (:mod:`imurig.flights.phases`) by the pilot and the autopilot
(:mod:`imurig.flights.pilot`), and the flight's navigation truth at the IMU
(:func:`simulate_flight`). The plan's types are importable from here too.
"""
from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass

import mujoco

from imurig.flights import earth
from imurig.flights.aircraft import CitationSim
from imurig.flights.autopilot import Autopilot
from imurig.flights.phases import (
    COAST,
    DEG,
    DELFT,
    PHASES,
    RUNWAY_24_DEG,
    SCHIPHOL,
    AlphaDotSTurns,
    Climb,
    DoubleDoublet,
    Elevator3211,
    FlightPlan,
    GroundCircle,
    Leg,
    Level,
    Parked,
    Takeoff,
    default_phases,
)
from imurig.flights.pilot import Pilot
from imurig.flights.truth import cabin_temperature_K, truth_from_kinematics
from imurig.kernel.navdata import FlightTruth
from imurig.kernel.progress import progress

__all__ = [
    "COAST", "DELFT", "PHASES", "RUNWAY_24_DEG", "SCHIPHOL", "AlphaDotSTurns", "Climb", "DoubleDoublet",
    "Elevator3211", "FlightPlan", "FlownPlan", "GroundCircle", "Leg", "Level", "Parked", "Takeoff",
    "default_phases", "fly", "simulate_flight",
]


@dataclass
class FlownPlan:
    """The result of flying a plan: the IMU's kinematics in the flat world, phase labels, figures."""

    kinematics: object
    phases: tuple
    plan: FlightPlan
    wall_s: float
    trim: dict
    sites: dict


def fly(plan: FlightPlan | None = None, progress_bar: bool = True) -> FlownPlan:
    """Fly ``plan`` (default: :func:`default_phases`) in MuJoCo; returns the recorded kinematics."""
    plan = (plan or FlightPlan()).validate()
    t0 = time.perf_counter()
    sim = CitationSim(plan.aero, rate_hz=plan.rate_hz, h0_m=0.0)
    ap = Autopilot(plan.aero, sim.dt)
    pilot = Pilot(plan, sim, ap, plan.control_hz)
    first = plan.phases[0]
    if isinstance(first, (Parked, GroundCircle, Takeoff)):
        q = earth.q_from_euler(0.0, 0.0, plan.heading_deg * DEG)
        sim.data.qpos[3:7] = q
        sim.settle(3.0)
        trim = {}
        ap.de0, ap.thr0 = 0.01, 0.5
    else:
        alt = getattr(first, "altitude_m", 1500.0)
        V = getattr(first, "speed_m_s", 120.0)
        sim.h0_m = 0.0
        trim = sim.set_airborne(V, alt, psi=plan.heading_deg * DEG)
        ap.de0, ap.thr0 = trim["de"], sim.act.thr
        pilot.h_c, pilot.V_c = alt, V
        pilot.psi_hold = plan.heading_deg * DEG
    labels = []
    bar_cm = (progress(total=len(plan.phases), desc="flying", unit="phase") if progress_bar
              else contextlib.nullcontext(type("NoBar", (), {"update": lambda self, n: None})()))
    with bar_cm as bar:
        for ph in plan.phases:
            t_start = sim.t
            for cmd, n in pilot.run(ph):
                sim.run(cmd, n)
            labels.append((ph.name, t_start, sim.t))
            bar.update(1)
    sites = {nm: sim.model.site_pos[mujoco.mj_name2id(sim.model, mujoco.mjtObj.mjOBJ_SITE, nm)].copy()
             for nm in ("gps_antenna", "magnetometer")}
    return FlownPlan(sim.kinematics(), tuple(labels), plan, time.perf_counter() - t0, trim, sites)


def simulate_flight(plan: FlightPlan | None = None, progress_bar: bool = True) -> FlightTruth:
    """Fly ``plan`` (default: the default flight) and return its :class:`FlightTruth` at the IMU.

    ``meta`` carries the plan, the wall time of the MuJoCo flight (``sim_wall_s``), the
    real-time factor (``real_time_factor`` = flight time / wall time, MuJoCo part only) and the
    control inputs per sample (``controls``: de, da, dr in rad, thr and brake 0-1, steer rad)."""
    t0 = time.perf_counter()
    flown = fly(plan, progress_bar)
    p = flown.plan
    k = flown.kinematics
    T = cabin_temperature_K(k.time_s, -k.p_N[:, 2])
    meta = {"plan": p.to_dict(), "sim_wall_s": flown.wall_s,
            "real_time_factor": float((k.time_s[-1] - k.time_s[0] + 1 / p.rate_hz) / flown.wall_s),
            "controls": dict(k.controls), "trim": flown.trim}
    truth = truth_from_kinematics(k, p.origin, p.start_time, "citation", flown.sites["gps_antenna"],
                                  flown.sites["magnetometer"], flown.phases, meta, T)
    truth.meta["total_wall_s"] = time.perf_counter() - t0
    return truth
