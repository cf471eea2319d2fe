"""Magnetometer manoeuvres on a kinematic yaw-pitch-roll gimbal in MuJoCo (seed 4.6-4.7, paper 4.3).

Manoeuvres (typed, all from servo commands):
- :class:`LevelCircle` -- the aircraft's turning circle on the tarmac / the van's circles:
  heading sweeps ``turns`` x 360 deg at ``rate_dps`` with roll and pitch near zero (a small
  random taxi wobble);
- :class:`Tumble` -- a 3-D tumble: yaw, pitch and roll on incommensurate sinusoids that
  cover the sphere of orientations;
- :class:`CompassSwing` -- the classic swing: 12 headings on a compass rose, held still.

Heading convention: psi is the angle of the IMU's x axis from true north, positive towards
east (clockwise seen from above); with W = ENU the gimbal's yaw is 90 deg - psi.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import mujoco
import numpy as np

from imurig.kernel.errors import ScheduleError
from imurig.kernel.recording import Recording
from imurig.rigs.mujoco_rig import load_model, rollout_servo, sensor_slices
from imurig.rigs.tilt_table import rotate_to_body
from imurig.kernel.site import Site, parse_time
from imurig.kernel.units import DEG


@dataclass(frozen=True)
class LevelCircle:
    turns: float = 2.0
    rate_dps: float = 10.0
    start_heading_deg: float = 0.0
    wobble_deg: float = 0.3
    name: str = "level_circle"

    def commands(self, dt, rng):
        T = self.turns * 360.0 / self.rate_dps
        t = np.arange(int(round(T / dt))) * dt
        psi = (self.start_heading_deg + self.rate_dps * t) * DEG
        wob = _smooth_noise(rng, t.size, dt, 0.2, self.wobble_deg * DEG)
        return psi, wob[:, 0], wob[:, 1], [(0, t.size)]


@dataclass(frozen=True)
class Tumble:
    duration_s: float = 300.0
    name: str = "tumble"

    def commands(self, dt, rng):
        t = np.arange(int(round(self.duration_s / dt))) * dt
        psi = 2 * np.pi * t / 37.0
        pitch = 1.3 * np.sin(2 * np.pi * t / 53.0 + 0.4)
        roll = 2.9 * np.sin(2 * np.pi * t / 71.0)
        return psi, pitch, roll, [(0, t.size)]


@dataclass(frozen=True)
class CompassSwing:
    headings_deg: tuple = tuple(range(0, 360, 30))
    dwell_s: float = 20.0
    move_s: float = 8.0
    name: str = "compass_swing"

    def commands(self, dt, rng):
        psi, wins = [], []
        n = 0
        prev = self.headings_deg[0] * DEG
        for h in self.headings_deg:
            target = h * DEG
            n_move = int(round(self.move_s / dt))
            s = (1 - np.cos(np.pi * np.arange(1, n_move + 1) / n_move)) / 2
            psi.append(prev + s * (target - prev))
            n_dw = int(round(self.dwell_s / dt))
            psi.append(np.full(n_dw, target))
            wins.append((n + n_move + n_dw // 4, n + n_move + n_dw))
            n += n_move + n_dw
            prev = target
        psi = np.concatenate(psi)
        z = np.zeros_like(psi)
        return psi, z, z, wins


def _smooth_noise(rng, n, dt, fc, rms):
    from scipy import signal

    w = rng.standard_normal((n, 2))
    sos = signal.butter(2, fc * 2 * dt, output="sos")
    y = signal.sosfiltfilt(sos, w, axis=0)
    return y / np.maximum(np.std(y, axis=0), 1e-12) * rms


@dataclass
class MagRig:
    site: Site = field(default_factory=Site)
    sim_rate_hz: float = 1000.0
    record_rate_hz: float = 100.0

    def simulate(self, manoeuvres: list, start_time: str, rng: np.random.Generator) -> Recording:
        """Run the manoeuvres one after another (each its own block); truth at the IMU."""
        if not manoeuvres:
            raise ScheduleError("no manoeuvre given")
        k = int(round(self.sim_rate_hz / self.record_rate_hz))
        dt = 1.0 / self.sim_rate_hz
        when = parse_time(start_time)
        model = load_model("mag_rig.xml")
        model.opt.timestep = dt
        model.opt.gravity[:] = (0.0, 0.0, -self.site.gravity_m_s2)
        model.opt.magnetic[:] = self.site.magnetic_field_W(when)
        # the gimbal's hinges have no range and no geom collides (contype 0): no contact and no constraint
        # is ever active, so skipping those stages changes no number (~20 % less per step)
        model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT) | int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
        sl = sensor_slices(model)
        parts, seg = [], {"start_s": [], "stop_s": [], "manoeuvre": [], "heading_set": []}
        t0 = 0.0
        for m in manoeuvres:
            psi, pitch, roll, wins = m.commands(dt, rng)
            yaw = np.pi / 2 - psi
            ctrl = np.stack([yaw, pitch, roll], 1)[None]
            sd = rollout_servo([model], ctrl[:, 0].copy(), ctrl, desc=f"{m.name} (MuJoCo)")[0][::k]
            t = t0 + np.arange(sd.shape[0]) * dt * k
            q = sd[:, sl["q_WC"]]
            w = sd[:, sl["w_C"]] + rotate_to_body(q, self.site.earth_rate_W())
            x_W = _body_x_in_world(q)
            heading = np.mod(np.arctan2(x_W[:, 0], x_W[:, 1]), 2 * np.pi)
            parts.append({"t": t, "f": sd[:, sl["f_C"]], "w": w, "B": sd[:, sl["B_C"]], "heading": heading,
                          "pitch": sd[:, sl["pitch_true"]][:, 0], "roll": sd[:, sl["roll_true"]][:, 0],
                          "yaw": sd[:, sl["yaw_true"]][:, 0], "psi_set": psi[::k]})
            for a, b in wins:
                seg["start_s"].append(t0 + a * dt)
                seg["stop_s"].append(t0 + b * dt)
                seg["manoeuvre"].append(m.name)
                seg["heading_set"].append(float(psi[min(b - 1, psi.size - 1)]))
            t0 = t[-1] + 60.0
        cat = lambda key: np.concatenate([p[key] for p in parts])  # noqa: E731
        tsig, tunits = {}, {}
        for name, unit in (("f", "m/s^2"), ("w", "rad/s"), ("B", "T")):
            arr = cat(name)
            for j, ax in enumerate("xyz"):
                tsig[f"{name}_C_{ax}"] = arr[:, j]
                tunits[f"{name}_C_{ax}"] = unit
        for name in ("heading", "pitch", "roll", "yaw"):
            tsig[name] = cat(name)
            tunits[name] = "rad"
        B_W = self.site.magnetic_field_W(when)
        meta = {"rig": "mag_rig", "site": self.site.to_dict(), "start_time": when.isoformat(),
                "sample_rate_hz": self.record_rate_hz, "setpoints": ["heading_set"],
                "manoeuvres": [dict(asdict(m), kind=type(m).__name__) for m in manoeuvres],
                "igrf_field_W_T": B_W.tolist(), "igrf_horizontal_T": float(math.hypot(B_W[0], B_W[1])),
                "igrf_total_T": float(np.linalg.norm(B_W)),
                "heading_convention": "psi from true north towards east; x_C forward"}
        return Recording(time_s=cat("t"), channels={"heading_set": cat("psi_set")}, units={"heading_set": "rad"},
                         segments={k_: np.array(v) for k_, v in seg.items()},
                         segment_units={"start_s": "s", "stop_s": "s", "manoeuvre": "", "heading_set": "rad"},
                         meta=meta, truth={"rig": {"mag_rig": {"manoeuvres": meta["manoeuvres"]}}},
                         truth_signals=tsig, truth_units=tunits)


def _body_x_in_world(q: np.ndarray) -> np.ndarray:
    """First column of R_WC for (n,4) wxyz quaternions: the body x axis in W."""
    w, x, y, z = q.T
    return np.stack([1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)], 1)
