"""Flight plans: the manoeuvres of seed section 5.2 as typed phases, the default flight, validation
(flown by :func:`imurig.flights.plan.fly`).

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

from imurig.flights.aircraft import G0, CitationAero, isa_density
from imurig.kernel.errors import ConfigError

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
    """A flight: where and when it starts, and its phases, flown at ``rate_hz`` (the IMU rate and
    the physics step) with the pilot and the autopilot updating the controls at ``control_hz`` (at
    most once per sample)."""

    phases: tuple = field(default_factory=default_phases)
    origin: tuple = SCHIPHOL
    heading_deg: float = RUNWAY_24_DEG
    start_time: str = "2005-06-26T10:00:00+02:00"
    rate_hz: float = 100.0
    control_hz: float = 50.0
    aero: CitationAero = field(default_factory=CitationAero)

    def to_dict(self) -> dict:
        return {"origin": list(self.origin), "heading_deg": self.heading_deg, "start_time": self.start_time,
                "rate_hz": self.rate_hz, "control_hz": self.control_hz,
                "phases": [{"kind": type(p).__name__, **asdict(p)} for p in self.phases]}

    def validate(self) -> FlightPlan:
        """Raise ConfigError (what is wrong, and the fix) for a plan the Citation cannot fly."""
        a = self.aero
        if self.rate_hz < 20 or self.rate_hz > 1000:
            raise ConfigError(f"rate_hz {self.rate_hz:g} is outside 20..1000 Hz; the DAQ-6036E logs at up to "
                              "1000 Hz and the flight dynamics need at least 20 Hz")
        if not 10 <= self.control_hz <= 1000:
            raise ConfigError(f"control_hz {self.control_hz:g} is outside 10..1000 Hz; the autopilot's loops need "
                              "at least 10 Hz (above rate_hz it updates at every sample)")
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
