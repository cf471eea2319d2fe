"""Flight plans: the manoeuvres of seed section 5.2 as typed phases, the default flight, validation.

Every manoeuvre is flown by control inputs (elevator, aileron, rudder, throttle, nose-wheel
steering, brakes) given to the simulated Citation (:mod:`imurig.flights.aircraft`) by a
scripted pilot and the autopilot; nothing is prescribed kinematically. Phases:

- :class:`Parked` — engines idle, brakes on (static alignment);
- :class:`GroundCircle` — the ground turning circle for the magnetometer (seed 5.2);
- :class:`Takeoff`, :class:`Climb` — to the cruise altitude;
- :class:`Leg` — to a waypoint; with ``track=True`` a straight-and-level SAR leg that holds
  the great-circle-like straight line between the previous and the next waypoint;
- :class:`Elevator3211` — pull D 3 u, push −D 2 u, pull D 1 u, push −D 1 u, then stick fixed;
- :class:`DoubleDoublet` — the short-period test: 5 s level, two 2-s doublets, stick free 10 s,
  5 s level;
- :class:`AlphaDotSTurns` — bank 20/30/45/60 deg to one side, each with a sharp 2-s elevator
  doublet while the bank is held, then the same to the other side, then 5 s level (seed 5.2
  says 15 deg for the first bank of the second side; the default mirrors the first side as
  the issue asks, and both lists are configurable);
- :class:`Level` — straight and level for a time.

Heights in a plan are above the departure runway (the flat world's origin); speeds are true
airspeeds (no wind). :meth:`FlightPlan.validate` refuses what the aircraft cannot fly: a bank
angle above 75 deg, a load factor (level turn plus doublet) above the limit load factor, a
lift coefficient above C_L,max, a speed below 1.3 V_stall, a turning circle tighter than the
nose-wheel steering allows.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import mujoco
import numpy as np
from imurig.flights import earth
from imurig.flights.aircraft import (
    G0,
    Autopilot,
    CitationAero,
    CitationSim,
    Cmd,
    isa_density,
)
from imurig.flights.truth import cabin_temperature_K, truth_from_kinematics

from imurig.kernel.errors import ConfigError
from imurig.kernel.navdata import FlightTruth

DEG = math.pi / 180.0
SCHIPHOL = (52.31, 4.76, 43.0)          # lat deg, lon deg, ellipsoidal height m (−3 m MSL + geoid ~46 m)
DELFT = (52.00, 4.37)                   # Geodesy institute, the DGPS reference station (seed 5.2)
COAST = (52.03, 4.17)                   # Ter Heijde, the North Sea coast west of Delft
RUNWAY_24_DEG = 234.0                   # Kaagbaan, runway 24


@dataclass(frozen=True)
class Parked:
    duration_s: float = 30.0
    name: str = "parked"


@dataclass(frozen=True)
class GroundCircle:
    radius_m: float = 25.0
    speed_m_s: float = 5.0
    turns: float = 1.0
    direction: str = "right"
    name: str = "ground_circle"


@dataclass(frozen=True)
class Takeoff:
    rotate_speed_m_s: float = 62.0
    pitch_deg: float = 8.0
    until_height_m: float = 50.0
    name: str = "takeoff"


@dataclass(frozen=True)
class Climb:
    altitude_m: float = 1500.0
    speed_m_s: float = 120.0
    toward: tuple = DELFT
    name: str = "climb"


@dataclass(frozen=True)
class Leg:
    to: tuple = DELFT
    altitude_m: float = 1500.0
    speed_m_s: float = 120.0
    track: bool = False
    name: str = "cruise"


@dataclass(frozen=True)
class Level:
    duration_s: float = 10.0
    altitude_m: float = 1500.0
    speed_m_s: float = 120.0
    name: str = "level"


@dataclass(frozen=True)
class Elevator3211:
    amplitude_deg: float = 1.0
    unit_s: float = 1.0
    free_s: float = 20.0
    name: str = "elevator_3211"


@dataclass(frozen=True)
class DoubleDoublet:
    amplitude_deg: float = 1.0
    period_s: float = 2.0
    lead_s: float = 5.0
    free_s: float = 10.0
    level_s: float = 5.0
    name: str = "double_doublet"


@dataclass(frozen=True)
class AlphaDotSTurns:
    banks_first_deg: tuple = (20.0, 30.0, 45.0, 60.0)
    banks_second_deg: tuple = (20.0, 30.0, 45.0, 60.0)
    first_side: str = "right"
    doublet_deg: float = 1.0
    doublet_s: float = 2.0
    hold_s: float = 8.0
    after_s: float = 4.0
    level_s: float = 5.0
    name: str = "alpha_dot_s_turns"


PHASES = (Parked, GroundCircle, Takeoff, Climb, Leg, Level, Elevator3211, DoubleDoublet, AlphaDotSTurns)


def default_phases() -> tuple:
    """Schiphol -> Delft -> the coast -> the manoeuvres over the North Sea (~15 min)."""
    return (Parked(30.0), GroundCircle(), Takeoff(), Climb(1500.0, 120.0, DELFT),
            Leg(DELFT, 1500.0, 120.0, name="cruise_to_delft"),
            Leg(COAST, 1500.0, 120.0, track=True, name="sar_leg_delft_coast"),
            Level(90.0, 1500.0, 120.0, name="sar_leg_sea"),
            Elevator3211(), Level(10.0), DoubleDoublet(), Level(10.0), AlphaDotSTurns(), Level(20.0))


@dataclass(frozen=True)
class FlightPlan:
    """A flight: where and when it starts, and its phases, flown at ``rate_hz`` (the IMU rate)."""

    phases: tuple = field(default_factory=default_phases)
    origin: tuple = SCHIPHOL
    heading_deg: float = RUNWAY_24_DEG
    start_time: str = "2005-06-26T10:00:00+02:00"
    rate_hz: float = 100.0
    aero: CitationAero = field(default_factory=CitationAero)

    def to_dict(self) -> dict:
        return {"origin": list(self.origin), "heading_deg": self.heading_deg, "start_time": self.start_time,
                "rate_hz": self.rate_hz,
                "phases": [{"kind": type(p).__name__, **asdict(p)} for p in self.phases]}

    def validate(self) -> FlightPlan:
        """Raise ConfigError (what is wrong, and the fix) for a plan the Citation cannot fly."""
        a = self.aero
        if self.rate_hz < 20 or self.rate_hz > 1000:
            raise ConfigError(f"rate_hz {self.rate_hz:g} is outside 20..1000 Hz; the DAQ-6036E logs at up to "
                              "1000 Hz and the flight dynamics need at least 20 Hz")
        if not self.phases:
            raise ConfigError("a flight plan needs at least one phase")
        mass = 6000.0
        for p in self.phases:
            if not isinstance(p, PHASES):
                raise ConfigError(f"unknown phase {p!r}; use one of {[c.__name__ for c in PHASES]}")
            if isinstance(p, GroundCircle):
                rmin = 5.4 / math.tan(a.steer_limit_rad)
                if p.radius_m < rmin:
                    raise ConfigError(f"ground circle radius {p.radius_m:g} m is tighter than the nose-wheel "
                                      f"steering allows ({rmin:.1f} m); use a radius of at least {rmin:.1f} m")
                if not 0 < p.speed_m_s <= 10:
                    raise ConfigError(f"taxi speed {p.speed_m_s:g} m/s: use 0 < speed <= 10 m/s on a circle")
                if p.direction not in ("left", "right"):
                    raise ConfigError(f"direction must be 'left' or 'right', got {p.direction!r}")
            alt = getattr(p, "altitude_m", 1500.0)
            V = getattr(p, "speed_m_s", 120.0)
            if isinstance(p, (Climb, Leg, Level, AlphaDotSTurns, Elevator3211, DoubleDoublet)):
                rho = isa_density(alt)
                vs = math.sqrt(2 * mass * G0 / (rho * a.S_m2 * a.CL_max))
                if isinstance(p, (Climb, Leg, Level)) and V < 1.3 * vs:
                    raise ConfigError(f"phase {p.name}: {V:g} m/s is below 1.3 V_stall = {1.3 * vs:.0f} m/s at "
                                      f"{alt:g} m; fly faster")
                qS = 0.5 * rho * 120.0 ** 2 * a.S_m2
                amp = getattr(p, "doublet_deg", getattr(p, "amplitude_deg", 0.0)) * DEG
                dn = qS * a.CLa * abs(a.Cmde / a.Cma) * amp / (mass * G0)
                if isinstance(p, AlphaDotSTurns):
                    if p.first_side not in ("left", "right"):
                        raise ConfigError(f"first_side must be 'left' or 'right', got {p.first_side!r}")
                    for bank in tuple(p.banks_first_deg) + tuple(p.banks_second_deg):
                        _check_bank(bank, dn, qS, mass, a)
                else:
                    _check_bank(0.0, dn, qS, mass, a)
        return self


def _check_bank(bank_deg: float, dn: float, qS: float, mass: float, a: CitationAero):
    if not 0 <= abs(bank_deg) <= 75:
        raise ConfigError(f"bank angle {bank_deg:g} deg is impossible for the Citation (> 75 deg); "
                          "use 60 deg or less, as the seed's alpha-dot test does")
    n = 1.0 / math.cos(bank_deg * DEG) + dn
    if n > a.limit_load_factor:
        nmax = a.limit_load_factor - dn
        lim = math.degrees(math.acos(1.0 / nmax)) if nmax > 1 else 0.0
        raise ConfigError(f"bank angle {bank_deg:g} deg with a doublet needs load factor {n:.2f}, above the "
                          f"Citation's limit load factor {a.limit_load_factor:g}; use at most {lim:.0f} deg "
                          "or a smaller doublet amplitude")
    CL = n * mass * G0 / qS
    if CL > a.CL_max:
        raise ConfigError(f"bank angle {bank_deg:g} deg needs C_L = {CL:.2f} > C_L,max = {a.CL_max:g} (stall); "
                          "bank less or fly faster")


# ------------------------------------------------------------------------------- the pilot
class _Pilot:
    """Turns the plan's phases into control inputs, phase after phase."""

    def __init__(self, plan: FlightPlan, sim: CitationSim, ap: Autopilot):
        self.plan, self.sim, self.ap = plan, sim, ap
        lat0, lon0, h0 = plan.origin
        self.origin = (lat0 * DEG, lon0 * DEG, h0)
        self.prev_wp = np.zeros(2)
        self.h_c, self.V_c = 0.0, 0.0

    def local(self, latlon) -> np.ndarray:
        d = earth.ned_from_geodetic(latlon[0] * DEG, latlon[1] * DEG, self.origin[2], *self.origin)
        return np.asarray(d[:2], float)

    def run(self, phase):
        """Generator of Cmd for one phase (ends when the phase ends)."""
        return getattr(self, "_" + type(phase).__name__)(phase)

    # --- ground
    def _Parked(self, p: Parked):
        n = round(p.duration_s * self.sim.rate_hz)
        for _ in range(n):
            yield Cmd(thr=0.0, brake=1.0)

    def _GroundCircle(self, p: GroundCircle):
        sim, s = self.sim, self.sim.s
        sgn = 1.0 if p.direction == "right" else -1.0
        psi0 = s.psi
        # centre of the circle, to the side of the main-gear midpoint
        x, y = s.pN, s.pE
        cx, cy = x - sgn * p.radius_m * math.sin(psi0), y + sgn * p.radius_m * math.cos(psi0)
        turned, last = 0.0, s.psi
        i_v = 0.0
        while turned < 2 * math.pi * p.turns:
            s = sim.s
            dpsi = (s.psi - last + math.pi) % (2 * math.pi) - math.pi
            turned += sgn * dpsi
            last = s.psi
            dist = math.hypot(s.pN - cx, s.pE - cy)
            steer = sgn * (math.atan(5.4 / p.radius_m) + 0.8 * (dist - p.radius_m) / p.radius_m)
            e = p.speed_m_s - s.gs
            i_v = max(-20.0, min(20.0, i_v + e * sim.dt))
            thr = 0.06 + 0.05 * e + 0.01 * i_v
            yield Cmd(thr=thr, steer=steer, brake=max(0.0, -0.2 * e))
        self.runway_heading = s.psi

    def _Takeoff(self, p: Takeoff):
        sim, ap = self.sim, self.ap
        psi_rwy = self.plan.heading_deg * DEG
        theta_c = 0.0
        airborne = False
        while sim.s.h < p.until_height_m:
            s = sim.s
            e_psi = (psi_rwy - s.psi + math.pi) % (2 * math.pi) - math.pi
            if s.V >= p.rotate_speed_m_s or airborne:
                theta_c = min(p.pitch_deg * DEG, theta_c + 3 * DEG * sim.dt)
                de = ap.pitch(s, theta_c)
            else:
                de = 0.0
            airborne = airborne or s.h > 1.0
            da, dr = ap.lateral(s, 0.0) if airborne else (0.0, 0.0)
            yield Cmd(de=de, da=da, dr=dr, thr=1.0, steer=0.0 if airborne else 1.5 * e_psi, flaps=1.0)
        ap.engage_elevator(sim.s, p.until_height_m + 10.0, sim.act.de)
        ap.i_V = (1.0 - ap.thr0) / ap.g.ki_V

    def _Climb(self, p: Climb):
        sim = self.sim
        wp = self.local(p.toward)
        self.h_c, self.V_c = p.altitude_m, p.speed_m_s
        while sim.s.h < p.altitude_m - 30.0:
            s = sim.s
            psi_c = math.atan2(wp[1] - s.pE, wp[0] - s.pN)
            yield self._hold(s, psi_c, flaps=1.0 if s.V < 80.0 else 0.0)

    def _hold(self, s, psi_c, phi_max=25 * DEG, flaps=0.0, phi_c=None):
        ap = self.ap
        if phi_c is None:
            phi_c = ap.bank_for_heading(s, psi_c, phi_max)
        da, dr = ap.lateral(s, phi_c)
        return Cmd(de=ap.elevator(s, self.h_c), da=da, dr=dr, thr=ap.throttle(s, self.V_c), flaps=flaps)

    def _Leg(self, p: Leg):
        sim = self.sim
        self.h_c, self.V_c = p.altitude_m, p.speed_m_s
        wp = self.local(p.to)
        start = self.prev_wp if p.track else np.array([sim.s.pN, sim.s.pE])
        d = wp - start
        course = math.atan2(d[1], d[0])
        unit = d / max(np.linalg.norm(d), 1.0)
        while True:
            s = sim.s
            pos = np.array([s.pN, s.pE])
            if np.dot(wp - pos, unit) < 0.0:
                break
            if p.track:
                xt = float(-unit[1] * (pos[0] - start[0]) + unit[0] * (pos[1] - start[1]))
                psi_c = course + max(-0.5, min(0.5, -0.004 * xt))
            else:
                psi_c = math.atan2(wp[1] - s.pE, wp[0] - s.pN)
            yield self._hold(s, psi_c)
        self.prev_wp = wp
        self.psi_hold = course

    def _level(self, seconds, psi_c):
        for _ in range(round(seconds * self.sim.rate_hz)):
            yield self._hold(self.sim.s, psi_c)

    def _Level(self, p: Level):
        self.h_c, self.V_c = p.altitude_m, p.speed_m_s
        yield from self._level(p.duration_s, getattr(self, "psi_hold", self.sim.s.psi))

    def _stick(self, inputs, de_hold, thr_hold, psi_c, phi_c=None):
        """Elevator held at de_hold plus ``inputs`` (one value per sample); lateral autopilot on."""
        sim, ap = self.sim, self.ap
        for u in inputs:
            s = sim.s
            if phi_c is None:
                phi = ap.bank_for_heading(s, psi_c, 25 * DEG)
            else:
                phi = phi_c
            da, dr = ap.lateral(s, phi)
            yield Cmd(de=de_hold + u, da=da, dr=dr, thr=thr_hold)

    def _manoeuvre(self, profile, free_s):
        sim, ap = self.sim, self.ap
        psi_c = getattr(self, "psi_hold", sim.s.psi)
        de_hold, thr_hold = sim.act.de, sim.act.thr
        n_free = round(free_s * sim.rate_hz)
        yield from self._stick(np.concatenate([profile, np.zeros(n_free)]), de_hold, thr_hold, psi_c)
        ap.engage_elevator(sim.s, self.h_c, sim.act.de)

    def _Elevator3211(self, p: Elevator3211):
        fs, D = self.sim.rate_hz, p.amplitude_deg * DEG
        seq = [(-D, 3), (D, 2), (-D, 1), (D, 1)]           # pull (nose up) is δe < 0
        prof = np.concatenate([np.full(round(k * p.unit_s * fs), v) for v, k in seq])
        yield from self._manoeuvre(prof, p.free_s)

    def _DoubleDoublet(self, p: DoubleDoublet):
        fs, D = self.sim.rate_hz, p.amplitude_deg * DEG
        psi_c = getattr(self, "psi_hold", self.sim.s.psi)
        yield from self._level(p.lead_s, psi_c)
        half = round(p.period_s / 2 * fs)
        prof = np.concatenate([np.full(half, -D), np.full(half, D)] * 2)
        yield from self._manoeuvre(prof, p.free_s)
        yield from self._level(p.level_s, psi_c)

    def _AlphaDotSTurns(self, p: AlphaDotSTurns):
        sim, ap, fs = self.sim, self.ap, self.sim.rate_hz
        sgn = 1.0 if p.first_side == "right" else -1.0
        half = round(p.doublet_s / 2 * fs)
        D = p.doublet_deg * DEG
        for side, banks in ((sgn, p.banks_first_deg), (-sgn, p.banks_second_deg)):
            for bank in banks:
                phi_c = side * bank * DEG
                # roll to the bank and hold it; altitude held by the column (autopilot)
                for _ in range(round(p.hold_s * fs)):
                    yield self._hold(sim.s, 0.0, phi_c=phi_c)
                de_hold, thr_hold = sim.act.de, sim.act.thr
                prof = np.concatenate([np.full(half, -D), np.full(half, D), np.zeros(round(p.after_s * fs))])
                yield from self._stick(prof, de_hold, thr_hold, 0.0, phi_c=phi_c)
                ap.engage_elevator(sim.s, self.h_c, sim.act.de)
        self.psi_hold = sim.s.psi
        yield from self._level(p.level_s, self.psi_hold)


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
    import time

    from imurig.kernel.progress import progress

    plan = (plan or FlightPlan()).validate()
    t0 = time.perf_counter()
    sim = CitationSim(plan.aero, rate_hz=plan.rate_hz, h0_m=0.0)
    ap = Autopilot(plan.aero, sim.dt)
    pilot = _Pilot(plan, sim, ap)
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
    import contextlib

    bar_cm = (progress(total=len(plan.phases), desc="flying", unit="phase") if progress_bar
              else contextlib.nullcontext(type("NoBar", (), {"update": lambda self, n: None})()))
    with bar_cm as bar:
        for ph in plan.phases:
            t_start = sim.t
            for cmd in pilot.run(ph):
                sim.step(cmd)
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
    import time

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
