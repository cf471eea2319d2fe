"""The van of the paper's ground test (section 4.3): its MuJoCo model on four sprung wheels with
tyre forces (:mod:`imurig.flights.vehicle`), the test's phases, and a driver.
"""
from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field

import mujoco

from imurig.flights.truth import cabin_temperature_K, truth_from_kinematics
from imurig.flights.vehicle import Cmd, TyreModel, VehicleSim, Wheel
from imurig.kernel.errors import ConfigError

VAN_ORIGIN = (52.0, 4.38, 45.0)        # an open field near Delft; lat, lon deg, ellipsoidal height m
WHEELBASE_M = 3.0


@dataclass(frozen=True)
class VanParked:
    duration_s: float = 20.0
    name: str = "parked"


@dataclass(frozen=True)
class VanStraight:
    duration_s: float = 20.0
    speed_m_s: float = 10.0
    name: str = "straight"


@dataclass(frozen=True)
class VanCircle:
    radius_m: float = 20.0
    speed_m_s: float = 6.0
    turns: float = 2.0
    direction: str = "right"
    name: str = "circle"


@dataclass(frozen=True)
class VanHardBrake:
    speed_m_s: float = 14.0
    name: str = "hard_braking"


@dataclass(frozen=True)
class VanRamp:
    angle_deg: float = 5.0
    approach_m: float = 12.0
    park_s: float = 30.0
    name: str = "parked_on_ramp"


def default_van_phases(ramp_angle_deg: float = 5.0) -> tuple:
    """The paper's ground test (section 4.3): straight runs, circles both ways, hard braking, and
    parked on a ramp at the end (~4 min); the paper calls it "a small ramp" and gives no angle (the
    Delft 2005 preset fits it to Fig. 9: :mod:`imurig.montecarlo.delft_fit_van`)."""
    return (VanParked(20.0), VanStraight(20.0, 10.0), VanCircle(20.0, 6.0, 2.0, "right"), VanStraight(15.0, 12.0),
            VanCircle(15.0, 5.0, 1.0, "left"), VanStraight(10.0, 10.0), VanHardBrake(14.0), VanParked(5.0),
            VanStraight(15.0, 8.0), VanRamp(angle_deg=ramp_angle_deg), )


@dataclass(frozen=True)
class VanPlan:
    phases: tuple = field(default_factory=default_van_phases)
    origin: tuple = VAN_ORIGIN
    heading_deg: float = 0.0
    start_time: str = "2005-06-14T14:00:00+02:00"
    rate_hz: float = 100.0

    def validate(self) -> VanPlan:
        for p in self.phases:
            if isinstance(p, VanCircle):
                rmin = WHEELBASE_M / math.tan(0.6)
                if p.radius_m < rmin:
                    raise ConfigError(f"van circle radius {p.radius_m:g} m is below the turning radius {rmin:.1f} m")
                if p.speed_m_s ** 2 / p.radius_m > 0.6 * 9.81:
                    raise ConfigError(f"circle at {p.speed_m_s:g} m/s, radius {p.radius_m:g} m needs "
                                      f"{p.speed_m_s ** 2 / p.radius_m / 9.81:.2f} g lateral: the van would skid "
                                      "or roll over; drive slower or widen the circle")
                if p.direction not in ("left", "right"):
                    raise ConfigError(f"direction must be 'left' or 'right', got {p.direction!r}")
            if getattr(p, "speed_m_s", 1.0) <= 0 or getattr(p, "speed_m_s", 1.0) > 30:
                raise ConfigError(f"{p.name}: speed must be in (0, 30] m/s")
            if isinstance(p, VanRamp) and not 0 < p.angle_deg <= 15:
                raise ConfigError(f"ramp angle {p.angle_deg:g} deg: use 0 < angle <= 15 deg")
        return self

    def to_dict(self) -> dict:
        return {"origin": list(self.origin), "heading_deg": self.heading_deg, "start_time": self.start_time,
                "rate_hz": self.rate_hz, "phases": [{"kind": type(p).__name__, **asdict(p)} for p in self.phases]}


class VanSim(VehicleSim):
    """The van: four sprung wheels with tyre forces, rear-wheel drive, brakes on all wheels,
    front-wheel steering; a parking hold (wheel chocks: a stiff spring to the parked spot)."""

    body_name = "van"
    drive_force_N = 8000.0
    n_driven = 2

    def __init__(self, rate_hz=100.0, substeps=1):
        tyre = TyreModel(cornering_stiffness_N_per_rad=60_000.0, mu=0.9, rolling_resistance=0.012)
        wheels = [Wheel("wheel_fl", "strut_fl", 0.33, tyre, steered=True),
                  Wheel("wheel_fr", "strut_fr", 0.33, tyre, steered=True),
                  Wheel("wheel_rl", "strut_rl", 0.33, tyre, driven=True),
                  Wheel("wheel_rr", "strut_rr", 0.33, tyre, driven=True)]
        self.hold = None
        super().__init__("van.xml", wheels, rate_hz, substeps, 0.0)

    def body_forces(self, cmd):
        if self.hold is None:
            return (0.0,) * 6
        s, C = self.s, self.s.C
        k, c = 2500.0 * 100.0, 2500.0 * 10.0       # 10 rad/s chocks (brakes add damping), horizontal
        fN = (-k * (s.pN - self.hold[0]) - c * s.vN, -k * (s.pE - self.hold[1]) - c * s.vE, 0.0)
        fB = tuple(C[i] * fN[0] + C[3 + i] * fN[1] for i in range(3))
        return (*fB, 0.0, 0.0, 0.0)

    def place_ramp(self, angle_rad, distance_m):
        """Put the ramp's foot ``distance_m`` ahead of the van, rising along its heading."""
        m, s, d = self.model, self.s, self.data
        gid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "ramp")
        bid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "ramp_body")
        mid_ = int(m.body_mocapid[bid])
        L, th = 2 * m.geom_size[gid][0], 0.1
        cp, sp = math.cos(s.psi), math.sin(s.psi)
        foot = (s.pN + cp * distance_m, s.pE + sp * distance_m)
        mid = L / 2 * math.cos(angle_rad)
        d.mocap_pos[mid_] = (foot[0] + cp * (mid + th * math.sin(angle_rad)),
                             foot[1] + sp * (mid + th * math.sin(angle_rad)),
                             -L / 2 * math.sin(angle_rad) + th * math.cos(angle_rad) + 0.03)  # foot 3 cm sunk
        # yaw psi, then pitch up by the ramp angle about the rotated y axis (box x rises)
        cy, sy = math.cos(s.psi / 2), math.sin(s.psi / 2)
        ca, sa = math.cos(angle_rad / 2), math.sin(angle_rad / 2)
        d.mocap_quat[mid_] = (cy * ca, -sy * sa, cy * sa, sy * ca)


class _Driver:
    """The van's driver: speed and heading held by simple loops, the wheel turned at a limited rate,
    each phase turned into commands sample by sample."""

    def __init__(self, sim):
        self.sim = sim
        self.i_v = 0.0
        self.delta = 0.0
        self.psi_hold = sim.s.psi

    def speed(self, v_c):
        s = self.sim.s
        v = s.C[0] * s.vN + s.C[3] * s.vE + s.C[6] * s.vD
        e = v_c - v
        self.i_v = max(-10.0, min(10.0, self.i_v + e * self.sim.dt))
        u = 0.25 * e + 0.05 * self.i_v + 0.012 * 2500 * 9.81 / 8000.0
        return (max(0.0, min(1.0, u)), min(0.3, -0.08 * e) if e < -0.5 else 0.0)   # gentle service braking

    def heading(self, psi_c):
        s = self.sim.s
        e = (psi_c - s.psi + math.pi) % (2 * math.pi) - math.pi
        return max(-0.5, min(0.5, 1.5 * e - 0.3 * s.r))

    def steer(self, delta_c):
        """The driver turns the wheel at most 0.4 rad/s at the road wheels."""
        step = 0.4 * self.sim.dt
        self.delta += max(-step, min(step, delta_c - self.delta))
        return self.delta

    def run(self, p):
        for cmd in self._run(p):
            cmd.steer = self.steer(cmd.steer)
            yield cmd

    def _run(self, p):
        sim, fs = self.sim, self.sim.rate_hz
        if isinstance(p, VanParked):
            for _ in range(round(p.duration_s * fs)):
                yield Cmd(brake=1.0)
        elif isinstance(p, VanStraight):
            for _ in range(round(p.duration_s * fs)):
                thr, br = self.speed(p.speed_m_s)
                yield Cmd(thr=thr, brake=br, steer=self.heading(self.psi_hold))
        elif isinstance(p, VanCircle):
            sgn = 1.0 if p.direction == "right" else -1.0
            while True:                                     # slow to the circle's speed, straight on
                s = sim.s
                v = s.C[0] * s.vN + s.C[3] * s.vE
                if abs(v - p.speed_m_s) < 0.3:
                    break
                thr, br = self.speed(p.speed_m_s)
                yield Cmd(thr=thr, brake=br, steer=self.heading(self.psi_hold))
            s = sim.s
            cx, cy = s.pN - sgn * p.radius_m * math.sin(s.psi), s.pE + sgn * p.radius_m * math.cos(s.psi)
            turned, last = 0.0, s.psi
            while turned < 2 * math.pi * p.turns:
                s = sim.s
                turned += sgn * ((s.psi - last + math.pi) % (2 * math.pi) - math.pi)
                last = s.psi
                dist = math.hypot(s.pN - cx, s.pE - cy)
                thr, br = self.speed(p.speed_m_s)
                steer = sgn * (math.atan(WHEELBASE_M / p.radius_m) + 0.5 * (dist - p.radius_m) / p.radius_m)
                yield Cmd(thr=thr, brake=br, steer=steer)
            self.psi_hold = sim.s.psi
        elif isinstance(p, VanHardBrake):
            for _ in range(round(12.0 * fs)):               # accelerate
                thr, br = self.speed(p.speed_m_s)
                yield Cmd(thr=thr, brake=br, steer=self.heading(self.psi_hold))
            while sim.s.gs > 0.05:                          # stamp on the brake
                yield Cmd(brake=1.0, steer=self.heading(self.psi_hold))
        elif isinstance(p, VanRamp):
            sim.place_ramp(math.radians(p.angle_deg), p.approach_m)
            start = (sim.s.pN, sim.s.pE)
            while math.hypot(sim.s.pN - start[0], sim.s.pE - start[1]) < p.approach_m + 4.0:
                thr, br = self.speed(2.0)
                yield Cmd(thr=thr, brake=br, steer=self.heading(self.psi_hold))
            while sim.s.gs > 0.05:
                yield Cmd(brake=1.0)
            sim.hold = (sim.s.pN, sim.s.pE)
            for _ in range(round(p.park_s * fs)):
                yield Cmd(brake=1.0)
        else:
            raise TypeError(f"unknown van phase {p!r}")


def drive(plan: VanPlan | None = None, substeps: int = 1):
    """Drive the van through ``plan``; returns (BodyKinematics, phases, sites, wall_s)."""
    plan = (plan or VanPlan()).validate()
    t0 = time.perf_counter()
    sim = VanSim(plan.rate_hz, substeps)
    h = math.radians(plan.heading_deg)
    sim.data.qpos[3:7] = (math.cos(h / 2), 0.0, 0.0, math.sin(h / 2))
    sim.settle(3.0)
    drv = _Driver(sim)
    labels = []
    for ph in plan.phases:
        ts = sim.t
        for cmd in drv.run(ph):
            sim.step(cmd)
        labels.append((ph.name, ts, sim.t))
    sites = {nm: sim.model.site_pos[mujoco.mj_name2id(sim.model, mujoco.mjtObj.mjOBJ_SITE, nm)].copy()
             for nm in ("gps_antenna", "magnetometer")}
    return sim.kinematics(), tuple(labels), sites, time.perf_counter() - t0


def simulate_van(plan: VanPlan | None = None, substeps: int = 1):
    """The van's ground test as a :class:`imurig.kernel.navdata.FlightTruth` (vehicle "van")."""
    plan = plan or VanPlan()
    kin, phases, sites, wall = drive(plan, substeps)
    T = cabin_temperature_K(kin.time_s, -kin.p_N[:, 2], start_K=295.15, warm_K=4.0, lapse_K_per_m=0.0)
    meta = {"plan": plan.to_dict(), "sim_wall_s": wall,
            "real_time_factor": float((kin.time_s[-1] + 1 / plan.rate_hz) / wall), "substeps": substeps}
    return truth_from_kinematics(kin, plan.origin, plan.start_time, "van", sites["gps_antenna"],
                                 sites["magnetometer"], phases, meta, T)
