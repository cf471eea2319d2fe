"""The Citation's pilot: each phase of a flight plan (:mod:`imurig.flights.phases`) turned into
control inputs by a scripted hand on the stick and the autopilot
(:class:`imurig.flights.autopilot.Autopilot`); nothing is prescribed kinematically.

The pilot and the autopilot run at their own rate, ``control_hz`` (50 Hz by default, as a
digital autopilot): each control update reads the state, sets the commands and holds them for
the next ``n`` samples (``round(rate_hz / control_hz)``, fewer at the end of a timed segment),
which the aircraft flies with its forces updated at every physics step
(:meth:`imurig.flights.aircraft.CitationSim.run`). The autopilot's integrators and rate limits
step by the held interval n Δt (rectangle rule, error sampled at the update). A stick profile
(the 3-2-1-1, doublets) is split at its steps, so the column moves at its sample exactly.
Phase ends that depend on the state (height reached, waypoint passed, circle closed) are
checked at the control updates.
"""
from __future__ import annotations

import math

import numpy as np

from imurig.flights import earth
from imurig.flights.aircraft import CitationSim
from imurig.flights.autopilot import Autopilot
from imurig.flights.phases import (
    DEG,
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
)
from imurig.flights.vehicle import Cmd


class Pilot:
    """Turns the plan's phases into control inputs, phase after phase."""

    def __init__(self, plan: FlightPlan, sim: CitationSim, ap: Autopilot, control_hz: float = 50.0):
        self.plan, self.sim, self.ap = plan, sim, ap
        self.n_tick = max(1, round(sim.rate_hz / control_hz))   # samples per control update
        lat0, lon0, h0 = plan.origin
        self.origin = (lat0 * DEG, lon0 * DEG, h0)
        self.prev_wp = np.zeros(2)
        self.h_c, self.V_c = 0.0, 0.0

    def local(self, latlon) -> np.ndarray:
        d = earth.ned_from_geodetic(latlon[0] * DEG, latlon[1] * DEG, self.origin[2], *self.origin)
        return np.asarray(d[:2], float)

    def run(self, phase):
        """Generator of (Cmd, n): the commands to hold for the next n samples, for one phase (ends
        when the phase ends)."""
        return getattr(self, "_" + type(phase).__name__)(phase)

    def _tick(self, n: int | None = None) -> int:
        """The next control interval (``n_tick`` samples unless given): the autopilot steps by it."""
        n = self.n_tick if n is None else n
        self.ap.dt = n * self.sim.dt
        return n

    def _ticks(self, n_samples: int):
        """The control intervals covering ``n_samples`` samples: n_tick each, the last one shorter."""
        while n_samples > 0:
            n = self._tick(min(self.n_tick, n_samples))
            yield n
            n_samples -= n

    # --- ground
    def _Parked(self, p: Parked):
        for n in self._ticks(round(p.duration_s * self.sim.rate_hz)):
            yield Cmd(thr=0.0, brake=1.0), n

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
            n = self._tick()
            s = sim.s
            dpsi = (s.psi - last + math.pi) % (2 * math.pi) - math.pi
            turned += sgn * dpsi
            last = s.psi
            dist = math.hypot(s.pN - cx, s.pE - cy)
            steer = sgn * (math.atan(5.4 / p.radius_m) + 0.8 * (dist - p.radius_m) / p.radius_m)
            e = p.speed_m_s - s.gs
            i_v = max(-20.0, min(20.0, i_v + e * n * sim.dt))
            thr = 0.06 + 0.05 * e + 0.01 * i_v
            yield Cmd(thr=thr, steer=steer, brake=max(0.0, -0.2 * e)), n
        self.runway_heading = s.psi

    def _Takeoff(self, p: Takeoff):
        sim, ap = self.sim, self.ap
        psi_rwy = self.plan.heading_deg * DEG
        theta_c = 0.0
        airborne = False
        while sim.s.h < p.until_height_m:
            n = self._tick()
            s = sim.s
            e_psi = (psi_rwy - s.psi + math.pi) % (2 * math.pi) - math.pi
            if s.V >= p.rotate_speed_m_s or airborne:
                theta_c = min(p.pitch_deg * DEG, theta_c + 3 * DEG * n * sim.dt)
                de = ap.pitch(s, theta_c)
            else:
                de = 0.0
            airborne = airborne or s.h > 1.0
            da, dr = ap.lateral(s, 0.0) if airborne else (0.0, 0.0)
            yield Cmd(de=de, da=da, dr=dr, thr=1.0, steer=0.0 if airborne else 1.5 * e_psi, flaps=1.0), n
        ap.engage_elevator(sim.s, p.until_height_m + 10.0, sim.act.de)
        ap.i_V = (1.0 - ap.thr0) / ap.g.ki_V

    def _Climb(self, p: Climb):
        sim = self.sim
        wp = self.local(p.toward)
        self.h_c, self.V_c = p.altitude_m, p.speed_m_s
        while sim.s.h < p.altitude_m - 30.0:
            n = self._tick()
            s = sim.s
            psi_c = math.atan2(wp[1] - s.pE, wp[0] - s.pN)
            yield self._hold(s, psi_c, flaps=1.0 if s.V < 80.0 else 0.0), n

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
            n = self._tick()
            if p.track:
                xt = float(-unit[1] * (pos[0] - start[0]) + unit[0] * (pos[1] - start[1]))
                psi_c = course + max(-0.5, min(0.5, -0.004 * xt))
            else:
                psi_c = math.atan2(wp[1] - s.pE, wp[0] - s.pN)
            yield self._hold(s, psi_c), n
        self.prev_wp = wp
        self.psi_hold = course

    def _level(self, seconds, psi_c):
        for n in self._ticks(round(seconds * self.sim.rate_hz)):
            yield self._hold(self.sim.s, psi_c), n

    def _Level(self, p: Level):
        self.h_c, self.V_c = p.altitude_m, p.speed_m_s
        yield from self._level(p.duration_s, getattr(self, "psi_hold", self.sim.s.psi))

    def _stick(self, inputs, de_hold, thr_hold, psi_c, phi_c=None):
        """Elevator held at de_hold plus ``inputs`` (one value per sample, split at its steps);
        lateral autopilot on."""
        sim, ap = self.sim, self.ap
        inputs = np.asarray(inputs, float)
        edges = np.concatenate([[0], np.flatnonzero(np.diff(inputs)) + 1, [inputs.size]])
        for i0, i1 in zip(edges[:-1].tolist(), edges[1:].tolist()):
            u = float(inputs[i0])
            for n in self._ticks(i1 - i0):
                s = sim.s
                if phi_c is None:
                    phi = ap.bank_for_heading(s, psi_c, 25 * DEG)
                else:
                    phi = phi_c
                da, dr = ap.lateral(s, phi)
                yield Cmd(de=de_hold + u, da=da, dr=dr, thr=thr_hold), n

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
                for n in self._ticks(round(p.hold_s * fs)):
                    yield self._hold(sim.s, 0.0, phi_c=phi_c), n
                de_hold, thr_hold = sim.act.de, sim.act.thr
                prof = np.concatenate([np.full(half, -D), np.full(half, D), np.zeros(round(p.after_s * fs))])
                yield from self._stick(prof, de_hold, thr_hold, 0.0, phi_c=phi_c)
                ap.engage_elevator(sim.s, self.h_c, sim.act.de)
        self.psi_hold = sim.s.psi
        yield from self._level(p.level_s, self.psi_hold)
