"""The Citation's autopilot: PID loops on altitude (through the flight path, rate-limited to a
load factor), airspeed, heading (through the bank) and bank, with a yaw damper.

    elevator  δe = δe0 + δe_ff(φ) − k_γ e_γ − k_iγ ∫e_γ + k_q q,   e_γ = γ_ref − γ        [rad]
    throttle  δt = δt0 + k_V e_V + k_iV ∫e_V,                      e_V = V_c − V          [0-1]
    aileron   δa = −(C_lp/C_lδa) (b/2V) p_c + k_p (p_c − p) + k_iφ ∫e_φ,  p_c = sat(k_φ e_φ)
    rudder    δr = k_r (r − g sin φ cos θ / V) − k_β β
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from imurig.flights.aircraft import G0, CitationAero, isa_density
from imurig.flights.vehicle import State


@dataclass
class AutopilotGains:
    k_gamma: float = 1.5       # rad elevator per rad flight-path error
    ki_gamma: float = 0.8
    k_q: float = 0.6           # rad elevator per rad/s pitch rate
    k_theta: float = 1.2       # pitch hold (take-off rotation)
    k_h: float = 0.12          # 1/s, climb rate per metre of altitude error
    gamma_max: float = 0.12
    dn_max: float = 0.3        # incremental load factor the altitude loop may command
    k_V: float = 0.06          # throttle per m/s
    ki_V: float = 0.01
    k_psi: float = 1.2         # bank per heading error
    k_phi: float = 1.0         # roll-rate command per rad bank error
    p_max: float = 0.26        # rad/s (15 deg/s)
    ki_phi: float = 0.3
    k_p: float = 0.3
    k_r: float = 1.0           # yaw damper
    k_beta: float = 1.5


class Autopilot:
    """PID loops: altitude -> flight path (rate-limited to ±dn_max g) -> elevator, airspeed -> throttle, heading -> bank ->
    aileron, yaw damper + sideslip -> rudder. Integrators persist across phases; hand-over
    from a held stick is bumpless (:meth:`engage_elevator`)."""

    def __init__(self, aero: CitationAero, dt: float, gains: AutopilotGains | None = None):
        self.aero, self.dt, self.g = aero, dt, gains or AutopilotGains()
        self.i_gamma = self.i_V = self.i_phi = self.gamma_ref = 0.0
        self.de0, self.thr0 = 0.01, 0.35

    def _de_ff(self, s: State) -> float:
        """Elevator feed-forward for the extra lift of a banked level turn."""
        a = self.aero
        n = 1.0 / max(math.cos(s.phi), 0.3)
        CL1 = 2 * 6000 * G0 / (isa_density(s.h) * max(s.V, 30.0) ** 2 * a.S_m2)
        dalpha = CL1 * (n - 1) / a.CLa
        qturn = G0 * math.sin(s.phi) ** 2 / (max(s.V, 30.0) * max(math.cos(s.phi), 0.3))
        return -(a.Cma * dalpha + a.Cmq * qturn * a.c_m / max(s.V, 30.0)) / a.Cmde

    def elevator(self, s: State, h_c: float) -> float:
        g = self.g
        V = max(s.V, 30.0)
        gamma_c = max(-g.gamma_max, min(g.gamma_max, g.k_h * (h_c - s.h) / V))
        step = g.dn_max * G0 / V * self.dt            # flight-path rate limit = load-factor limit
        self.gamma_ref += max(-step, min(step, gamma_c - self.gamma_ref))
        e = self.gamma_ref - s.gamma
        self.i_gamma = max(-0.3, min(0.3, self.i_gamma + e * self.dt))
        return self.de0 + self._de_ff(s) - g.k_gamma * e - g.ki_gamma * self.i_gamma + g.k_q * s.q

    def engage_elevator(self, s: State, h_c: float, de_now: float):
        """Set the integrator so that :meth:`elevator` returns ``de_now`` now (bumpless)."""
        self.i_gamma = 0.0
        self.gamma_ref = s.gamma
        de0 = self.elevator(s, h_c)
        self.i_gamma = (de0 - de_now) / self.g.ki_gamma

    def pitch(self, s: State, theta_c: float) -> float:
        return self.de0 + self.g.k_theta * (s.theta - theta_c) + self.g.k_q * s.q

    def throttle(self, s: State, V_c: float) -> float:
        e = V_c - s.V
        self.i_V = max(-30.0, min(30.0, self.i_V + e * self.dt))
        return max(0.0, min(1.0, self.thr0 + self.g.k_V * e + self.g.ki_V * self.i_V))

    def bank_for_heading(self, s: State, psi_c: float, phi_max: float) -> float:
        e = (psi_c - s.psi + math.pi) % (2 * math.pi) - math.pi
        return max(-phi_max, min(phi_max, self.g.k_psi * e))

    def lateral(self, s: State, phi_c: float) -> tuple[float, float]:
        """Bank hold through a roll-rate command limited to ``p_max`` (aileron feed-forward from
        C_lp/C_lδa), yaw damper and sideslip feedback on the rudder."""
        g, a = self.g, self.aero
        e = phi_c - s.phi
        if abs(e) < 0.1:   # conditional integration: no wind-up during large bank changes
            self.i_phi = max(-0.2, min(0.2, self.i_phi + e * self.dt))
        p_c = max(-g.p_max, min(g.p_max, g.k_phi * e))
        V = max(s.V, 30.0)
        da = -a.Clp / a.Clda * a.b_m / (2 * V) * p_c + g.k_p * (p_c - s.p) + g.ki_phi * self.i_phi
        r_c = G0 * math.sin(s.phi) * math.cos(s.theta) / V
        dr = g.k_r * (s.r - r_c) - g.k_beta * s.beta
        return da, dr
