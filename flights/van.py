"""Tyre forces for wheeled contact (the van and the Citation's landing gear), and the van.

Tyre model (per wheel, horizontal body axes, SI):

    alpha  = atan2(v_lat, max(|v_long|, v_min))                  [rad]  slip angle (regularised)
    F_lat  = -mu N tanh(C_alpha alpha / (mu N))                  [N]    saturating cornering force
    F_long = F_drive - (b mu + c_rr) N tanh(v_long / v_stick)    [N]    brake fraction b, rolling resistance

v_long, v_lat: the contact point's velocity along / across the wheel (steered by delta).
N: the wheel load, from the sprung strut (stiffness k, damping c, deflection q < 0 when
compressed): N = max(0, -k q - c dq/dt). The wheels themselves are frictionless spheres in
MuJoCo (condim 1): MuJoCo carries the vertical contact, these forces carry the rest, so
steering, drive and braking are real control inputs and pitch/roll arise from the struts.
"""
from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class TyreModel:
    """Linear-then-saturating tyre (parameters in SI)."""

    cornering_stiffness_N_per_rad: float = 60_000.0
    mu: float = 0.8
    rolling_resistance: float = 0.015
    v_min_m_s: float = 3.0
    v_stick_m_s: float = 0.3

    def force(self, v_long: float, v_lat: float, load_N: float, drive_N: float = 0.0,
              brake: float = 0.0) -> tuple[float, float]:
        """(F_long, F_lat) N on the vehicle, in the wheel's axes."""
        if load_N <= 0.0:
            return 0.0, 0.0
        fmax = self.mu * load_N
        alpha = math.atan2(v_lat, max(abs(v_long), self.v_min_m_s))
        f_lat = -fmax * math.tanh(self.cornering_stiffness_N_per_rad * alpha / fmax)
        f_long = drive_N - (brake * self.mu + self.rolling_resistance) * load_N * math.tanh(v_long / self.v_stick_m_s)
        return f_long, f_lat
