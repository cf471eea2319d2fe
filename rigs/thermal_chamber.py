"""The thermal chamber (SW-5101, seed section 4.5) with a two-axis positioner inside.

Profile. From the start temperature the chamber ramps (``ramp_C_per_min``) to each
set-point of a cycle -- low to high in ``step_C`` steps (heating branch), then back down
(cooling branch) -- soaks there (``soak_s``), and then the positioner visits the six
attitudes (+-x, +-y, +-z up), ``attitude_dwell_s`` each. The air follows the programmed
ramp through a first-order lag (``air_tau_s``); the sensors lag the air in turn (see
:class:`imurig.sensors.chain.ThermalLags`).

Truth at the IMU. The IMU is static at each attitude, so its specific force, angular rate
(the Earth's) and magnetic field are those of a rigid body at rest:

    f_C = R_CW (0, 0, g),  w_C = R_CW Omega_E,W,  B_C = R_CW B_W,   R_WC = Ry(theta) Rz(phi)

the same closed form that the tilt-table tests verify against MuJoCo's site sensors to
1e-11 g (the positioner is the tilt table's geometry; theta = 180 deg turns z down).
Records are logged at ``sample_rate_hz`` (10 Hz by default: each sample is an average of
the 1 kHz conversions, so noise above 5 Hz is averaged, not aliased).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from imurig.kernel.errors import ScheduleError
from imurig.kernel.recording import Recording
from imurig.rigs.tilt_table import rot_y, rot_z
from imurig.sensors.thermal import first_order_lag
from imurig.kernel.site import Site, parse_time

ATTITUDES = {"z_up": (0.0, 0.0), "z_down": (math.pi, 0.0), "x_up": (math.pi / 2, math.pi),
             "x_down": (math.pi / 2, 0.0), "y_up": (math.pi / 2, math.pi / 2),
             "y_down": (math.pi / 2, 3 * math.pi / 2)}


def attitude_R_WC(name: str) -> np.ndarray:
    th, ph = ATTITUDES[name]
    return rot_y(np.float64(th)) @ rot_z(np.float64(ph))


@dataclass(frozen=True)
class ThermalProfile:
    low_C: float = -50.0
    high_C: float = 50.0
    step_C: float = 10.0
    cycles: int = 2
    start_C: float = 20.0
    ramp_C_per_min: float = 2.0
    soak_s: float = 2400.0
    attitudes: tuple[str, ...] = tuple(ATTITUDES)
    attitude_dwell_s: float = 60.0
    switch_s: float = 10.0
    air_tau_s: float = 60.0
    sample_rate_hz: float = 10.0

    def setpoints(self) -> list[tuple[float, str, int]]:
        """(set-point C, branch 'up'/'down', cycle) in order."""
        n = int(round((self.high_C - self.low_C) / self.step_C))
        up = [self.low_C + k * self.step_C for k in range(n + 1)]
        out = []
        for c in range(self.cycles):
            # cycle 0 starts by cooling from start_C to low_C; later cycles continue from low_C
            first = up if c == 0 else up[1:]
            for k, T in enumerate(first):
                prev = (self.start_C if c == 0 else self.low_C) if k == 0 else first[k - 1]
                out.append((T, "up" if T > prev else "down", c))
            for T in up[-2::-1]:
                out.append((T, "down", c))
        return out

    def validate(self) -> "ThermalProfile":
        temps = {round(t, 6) for t, _, _ in self.setpoints()} if self.step_C > 0 else set()
        if self.step_C <= 0 or len(temps) < 2:
            raise ScheduleError(f"the thermal profile visits {len(temps)} temperature(s); a temperature "
                                "calibration needs at least two (better four or more) distinct set-points: "
                                "widen low_C..high_C or shrink step_C")
        if self.low_C < -70 or self.high_C > 150 or self.low_C >= self.high_C:
            raise ScheduleError(f"the SW-5101 runs from -70 to +150 C; got {self.low_C}..{self.high_C} C")
        if self.cycles < 1:
            raise ScheduleError("at least one thermal cycle")
        bad = [a for a in self.attitudes if a not in ATTITUDES]
        if bad:
            raise ScheduleError(f"unknown attitude(s) {bad}; choose from {sorted(ATTITUDES)}")
        for name in ("ramp_C_per_min", "attitude_dwell_s", "sample_rate_hz"):
            if not getattr(self, name) > 0:
                raise ScheduleError(f"{name} must be positive")
        if self.switch_s >= self.attitude_dwell_s:
            raise ScheduleError("switch_s must be shorter than attitude_dwell_s")
        return self

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class ThermalChamber:
    site: Site = field(default_factory=Site)

    def simulate(self, profile: ThermalProfile, start_time: str) -> Recording:
        """Air temperature, attitude schedule and static truth; no sensors yet."""
        p = profile.validate()
        dt = 1.0 / p.sample_rate_hz
        when = parse_time(start_time)
        T_prog, att_idx = [], []
        seg = {"start_s": [], "stop_s": [], "T_set": [], "attitude": [], "branch": [], "cycle": [], "step": []}
        names = list(p.attitudes)
        cur = p.start_C
        n = 0
        for k, (T, branch, cyc) in enumerate(p.setpoints()):
            n_ramp = max(1, int(round(abs(T - cur) / (p.ramp_C_per_min / 60) / dt)))
            T_prog.append(np.linspace(cur, T, n_ramp + 1)[1:])
            att_idx.append(np.zeros(n_ramp, int))
            n += n_ramp
            n_soak = int(round(p.soak_s / dt))
            T_prog.append(np.full(n_soak, T))
            att_idx.append(np.zeros(n_soak, int))
            n += n_soak
            n_dw = int(round(p.attitude_dwell_s / dt))
            n_sw = int(round(p.switch_s / dt))
            for j, a in enumerate(names):
                T_prog.append(np.full(n_dw, T))
                att_idx.append(np.full(n_dw, j))
                seg["start_s"].append((n + n_sw) * dt)
                seg["stop_s"].append((n + n_dw) * dt)
                seg["T_set"].append(T + 273.15)
                seg["attitude"].append(a)
                seg["branch"].append(branch)
                seg["cycle"].append(cyc)
                seg["step"].append(k)
                n += n_dw
            cur = T
        T_prog = np.concatenate(T_prog) + 273.15
        att = np.concatenate(att_idx)
        t = np.arange(T_prog.size) * dt
        T_air = first_order_lag(T_prog, t, p.air_tau_s)
        R = np.stack([attitude_R_WC(a) for a in names])  # (m, 3, 3) R_WC per attitude
        g = self.site.gravity_m_s2
        f_att = np.einsum("mji,j->mi", R, np.array([0.0, 0.0, g]))
        w_att = np.einsum("mji,j->mi", R, self.site.earth_rate_W())
        B_att = np.einsum("mji,j->mi", R, self.site.magnetic_field_W(when))
        tsig = {"T_air": T_air}
        tunits = {"T_air": "K"}
        for name, arr, unit in (("f_C", f_att, "m/s^2"), ("w_C", w_att, "rad/s"), ("B_C", B_att, "T")):
            for j, ax in enumerate("xyz"):
                tsig[f"{name}_{ax}"] = arr[att, j]
                tunits[f"{name}_{ax}"] = unit
        th = np.array([ATTITUDES[a][0] for a in names])[att]
        ph = np.array([ATTITUDES[a][1] for a in names])[att]
        segments = {k: np.array(v) for k, v in seg.items()}
        return Recording(
            time_s=t, channels={"T_set": T_prog, "theta": th, "phi": ph},
            units={"T_set": "K", "theta": "rad", "phi": "rad"}, segments=segments,
            segment_units={"start_s": "s", "stop_s": "s", "T_set": "K", "attitude": "", "branch": "", "cycle": "1",
                           "step": "1"},
            meta={"rig": "thermal_chamber", "chamber": "Associated Testing Laboratories SW-5101",
                  "site": self.site.to_dict(), "start_time": when.isoformat(), "sample_rate_hz": p.sample_rate_hz,
                  "averaged_logging": True, "profile": p.to_dict(), "setpoints": ["T_set"],
                  "attitudes": {a: list(ATTITUDES[a]) for a in names}},
            truth={"rig": {"thermal_chamber": p.to_dict()}}, truth_signals=tsig, truth_units=tunits)
