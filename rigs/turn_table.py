"""The Genisco C181 turn table (seed section 4.4.1): schedule, table physics, MuJoCo truth.

Table rate. The rate is set on the dial of a ball-and-disc integrator driven by a
synchronous motor built for 60 Hz. On f_mains the true rate is

    Omega(t) = s_dir * dial * (f_mains / 60) * (1 - slip(dial)) * (1 + e_set) * (1 + a_rip sin(theta + phi_rip))

slip(dial) = s0 + s1 * (dial_eff / 1 deg/s)^-alpha: the integrator's rate-dependent
shortfall (defaults fitted by eye to the stopwatch times of seed appendix B); e_set: the
dial setting error of each step; a_rip: once-per-round rate ripple. Wobble: the platform
is tilted by a small fixed angle against the spin axis. Levelling: the spin axis is
tilted against the local vertical.

The optical index sensor gives a pulse (5 V) while the table angle theta (mod 2 pi) lies
in [0, pulse_width); its rising edges are the once-per-round events.

The mains factor and the slip are the effects ``mains_rate_factor`` and ``table_slip`` of
:mod:`imurig.sensors.effects` (which own their diagnosis and truth maps); the table applies them.

Truth at the IMU: MuJoCo's site sensors for the ramps between rates, their closed form while a
rate is held (:mod:`imurig.rigs.turn_truth`); the Earth's rotation is added to the gyro truth
(MuJoCo's world does not rotate).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import mujoco
import numpy as np

from imurig.kernel.errors import ConfigError, ScheduleError
from imurig.kernel.recording import Recording
from imurig.rigs.mujoco_rig import load_model, sensor_slices
from imurig.rigs.tilt_table import _copy_model, _quat_wxyz, rot_x, rot_y
from imurig.rigs.turn_run import TurnRun
from imurig.rigs.turn_truth import full_truth, stitched_states
from imurig.kernel.site import Site, parse_time
from imurig.kernel.units import ARCSEC, DEG
from imurig.sensors.effects.mains_rate_factor import MainsRateFactor
from imurig.sensors.effects.table_slip import TableSlip

#: R_MC: IMU case frame C -> mount frame M (M's z is the spin axis). '<axis>_up' puts that
#: IMU axis (p = x, q = y, r = z of C) along +z of the table, '_down' along -z.
MOUNTS = {
    "r_up": np.eye(3),
    "r_down": np.diag([1.0, -1.0, -1.0]),
    "p_up": rot_y(np.float64(-np.pi / 2)),
    "p_down": rot_y(np.float64(np.pi / 2)),
    "q_up": rot_x(np.float64(np.pi / 2)),
    "q_down": rot_x(np.float64(-np.pi / 2)),
}
AXIS_OF_MOUNT = {k: ("pqr".index(k[0]), 1.0 if k.endswith("up") else -1.0) for k in MOUNTS}


@dataclass(frozen=True)
class RateStep:
    """One step of a schedule: a dial setting held for an acquisition window."""

    dial_dps: float          # signed: the sign is the direction (+ counter-clockwise seen from above)
    mount: str
    window_s: float          # least acquisition time; extended to whole rounds


@dataclass(frozen=True)
class TurnTableProtocol:
    """Rate schedule (seed 4.4.4 default: (1, 2, 4, 8, 10, 20, 40, 80, 100) x 5/6 deg/s on the
    dial x 5/6, both directions, all three axes). Rates in dial deg/s at the constructor."""

    dial_rates_dps: tuple[float, ...] = (1, 2, 4, 8, 10, 20, 40, 80, 100)
    directions: tuple[int, ...] = (1, -1)
    mounts: tuple[str, ...] = ("p_up", "q_up", "r_up")
    radius_m: float = 0.0
    min_rounds: int = 1
    min_window_s: float = 10.0
    settle_s: float = 4.0
    ramp_s: float = 2.0
    remount_s: float = 600.0
    sample_rate_hz: float = 1000.0

    def validate(self, mains_factor: float = 5 / 6) -> "TurnTableProtocol":
        if not self.dial_rates_dps:
            raise ScheduleError("the schedule needs at least one dial rate")
        bad = [r for r in self.dial_rates_dps if not 0.01 <= r <= 1200]
        if bad:
            raise ScheduleError(f"dial rates must lie within the C181's 0.01-1200 deg/s; got {bad}")
        if not self.directions or any(d not in (1, -1) for d in self.directions):
            raise ScheduleError("directions must be a subset of (1, -1)")
        unknown = [m for m in self.mounts if m not in MOUNTS]
        if unknown or not self.mounts:
            raise ScheduleError(f"unknown or no mounting(s) {unknown}; choose from {sorted(MOUNTS)}")
        if self.min_rounds < 1:
            raise ScheduleError("min_rounds must be at least 1 (the rate comes from complete rounds)")
        if self.radius_m < 0 or self.radius_m > 0.6:
            raise ScheduleError(f"radius_m must lie on the table's arm, 0-0.6 m; got {self.radius_m}")
        for name in ("sample_rate_hz", "min_window_s", "ramp_s"):
            if not getattr(self, name) > 0:
                raise ScheduleError(f"{name} must be positive")
        return self

    def steps(self, mains_factor: float = 5 / 6) -> list[RateStep]:
        out = []
        for m in self.mounts:
            for d in self.directions:
                for r in self.dial_rates_dps:
                    out.append(RateStep(d * r, m, self.min_window_s))
        return out

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class TurnTableErrors:
    """Injected table physics (truth)."""

    mains_hz: float = 50.0
    motor_design_hz: float = 60.0
    slip_const: float = 0.012
    slip_coeff: float = 0.03
    slip_exp: float = 0.7
    dial_setting_error: float = 0.003     # relative, 1 sigma, per step
    ripple: float = 1e-3                  # relative once-per-round rate ripple
    ripple_phase_rad: float = 0.3
    wobble_rad: float = 20 * ARCSEC       # platform tilt against the spin axis
    wobble_azimuth_rad: float = 1.0
    level_x_rad: float = 5 * ARCSEC
    level_y_rad: float = -8 * ARCSEC
    pulse_width_rad: float = 2.0 * DEG
    pulse_high_V: float = 5.0

    @property
    def mains_factor(self) -> float:
        return MainsRateFactor(self.mains_hz, self.motor_design_hz).factor

    def slip(self, dial_dps) -> np.ndarray:
        eff = np.abs(np.asarray(dial_dps, float)) * self.mains_factor
        return TableSlip(self.slip_const, self.slip_coeff, self.slip_exp).shortfall(eff)

    def true_rate_dps(self, dial_dps, setting_error=0.0) -> np.ndarray:
        """Mean true rate (deg/s, signed) for a dial setting, before ripple."""
        d = np.asarray(dial_dps, float)
        return d * self.mains_factor * (1 - self.slip(d)) * (1 + np.asarray(setting_error))

    def wobble_rotation(self) -> np.ndarray:
        """R_PM: the mount frame M tilted by the wobble angle about a platform axis at wobble_azimuth."""
        a = self.wobble_azimuth_rad
        k = np.array([math.cos(a), math.sin(a), 0.0])
        K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        w = self.wobble_rad
        return np.eye(3) + math.sin(w) * K + (1 - math.cos(w)) * K @ K

    def to_dict(self) -> dict:
        return asdict(self)


def _profile(steps: list[RateStep], errors: TurnTableErrors, settle_s, ramp_s, dt, set_err, min_rounds):
    """Commanded mean rate per sample (rad/s) and acquisition windows (index ranges) for one
    mounting. Between steps the rate ramps on a cosine, then settles; then, as the operator
    does, acquisition waits for the next index pulse and lasts a whole number of rounds
    (at least ``min_rounds`` and at least the step's window), with a small margin each side."""
    pieces, windows = [], []
    n = 0
    prev = 0.0
    angle = 0.0
    n_ramp = max(1, int(round(ramp_s / dt)))
    n_settle = int(round(settle_s / dt))
    w = errors.pulse_width_rad
    for k, st in enumerate(steps):
        target = float(errors.true_rate_dps(st.dial_dps, set_err[k])) * DEG
        s = (1 - np.cos(np.pi * np.arange(1, n_ramp + 1) / n_ramp)) / 2
        ramp = prev + s * (target - prev)
        pieces.append(ramp)
        angle += ramp.sum() * dt
        angle += target * n_settle * dt
        t_round = 2 * np.pi / abs(target)
        if target > 0:
            wait = (2 * np.pi * np.ceil(angle / (2 * np.pi)) - angle) / target
        else:
            level = 2 * np.pi * np.floor((angle - w) / (2 * np.pi)) + w
            wait = (angle - level) / -target
        rounds = max(min_rounds, int(np.ceil(st.window_s / t_round)))
        margin = 0.02 * t_round + 0.05
        n_wait = int(round(max(0.0, wait - margin) / dt))
        n_win = int(round((rounds * t_round + 2 * margin) / dt))
        hold = n_settle + n_wait + n_win
        pieces.append(np.full(hold, target))
        angle += target * (n_wait + n_win) * dt
        windows.append((n + n_ramp + n_settle + n_wait, n + n_ramp + hold))
        n += n_ramp + hold
        prev = target
    s = (1 - np.cos(np.pi * np.arange(1, n_ramp + 1) / n_ramp)) / 2  # spin down at the end
    pieces.append(prev * (1 - s))
    return np.concatenate(pieces), windows


def rising_edges(angle_rad: np.ndarray, time_s: np.ndarray, width_rad: float):
    """True rising-edge times (s) of the index pulse: theta enters [0, width) mod 2 pi.

    Linear interpolation between samples (the rate is smooth at 1 kHz). Returns sorted times.
    """
    k = np.floor(angle_rad / (2 * np.pi))
    # positive rotation enters the zone at theta = 2 pi k (k increases by one)
    up = np.flatnonzero(np.diff(k) > 0)
    # negative rotation enters the zone at theta = 2 pi k + width, going down
    kk = np.floor((angle_rad - width_rad) / (2 * np.pi))
    down = np.flatnonzero(np.diff(kk) < 0)
    times = []
    for idx, level in ((up, 2 * np.pi * k[up + 1]), (down, 2 * np.pi * kk[down] + width_rad)):
        a0, a1 = angle_rad[idx], angle_rad[idx + 1]
        frac = (level - a0) / (a1 - a0)
        times.append(time_s[idx] + frac * (time_s[idx + 1] - time_s[idx]))
    return np.sort(np.concatenate(times))


@dataclass
class TurnTable:
    """The virtual C181: MuJoCo spindle plus its physics."""

    errors: TurnTableErrors = field(default_factory=TurnTableErrors)
    site: Site = field(default_factory=Site)
    radius_measurement_sigma_m: float = 1e-4  # how well the lab knows the arm radius

    #: the truth: "closed_form" (MuJoCo steps the ramps between rates, the closed form holds each rate,
    #: :mod:`imurig.rigs.turn_truth`) or "mujoco" (MuJoCo steps every sample; the same truth to ~1e-15)
    truth: str = "closed_form"

    def _truth(self, models, profiles, windows, sl, dt):
        """The record's truth, mountings one after the other, each trimmed to its length: whole arrays
        (f_C_x/y/z, w_C_x/y/z with the Earth rate, spin_angle) with MuJoCo at every sample, else the states
        whose rows :class:`imurig.rigs.turn_truth.TurnStates` makes; and the mountings' row offsets."""
        e = self.errors
        if self.truth not in ("closed_form", "mujoco"):
            raise ConfigError(f"truth must be 'closed_form' or 'mujoco', got {self.truth!r}")
        ctrls = []
        for p in profiles:  # once-per-round ripple: needs the angle, which the mean rate integrates to
            ctrls.append(p * (1 + e.ripple * np.sin(np.cumsum(p) * dt + e.ripple_phase_rad)) if e.ripple else p)
        off = np.concatenate(([0], np.cumsum([p.size for p in profiles])))
        earth_W = self.site.earth_rate_W()
        if self.truth == "mujoco":
            arrays = {k: np.empty(off[-1]) for k in (*(f"{s}_{a}" for s in ("f_C", "w_C") for a in "xyz"),
                                                     "spin_angle")}
            ctrl = np.zeros((len(models), max(p.size for p in profiles), 1))
            for b, c in enumerate(ctrls):
                ctrl[b, :c.size, 0] = c
            full_truth(models, ctrl, arrays, off, sl, earth_W)
            return arrays, off
        # a ramp starts each step and ends the record (the spin-down)
        return stitched_states(models, ctrls, [[0] + [z for _, z in w] for w in windows], off, sl, earth_W), off

    def _assemble(self, spin, off, mounts, steps, windows, dt, remount_s):
        """The record's small parts from the truth's spin angle ``spin`` (n,): each mounting's first time,
        the segments (one per step), the dial's settings and the true pulse edges."""
        e = self.errors
        seg = {"start_s": [], "stop_s": [], "run": [], "rate_dial": [], "mount": []}
        t0s, dials, pulse_true = [], [], []
        t0 = 0.0
        for b, m in enumerate(mounts):
            n = off[b + 1] - off[b]
            t0s.append(t0)
            for a in range(0, n - 1, 1 << 18):  # in pieces of one row's overlap: each pair of rows once
                z = min(n, a + (1 << 18) + 1)
                t = t0 + np.arange(a, z) * dt
                pulse_true.append(rising_edges(spin[off[b] + a:off[b] + z], t, e.pulse_width_rad))
            st = [s for s in steps if s.mount == m]
            for s, (a, z) in zip(st, windows[b]):
                seg["start_s"].append(t0 + a * dt)
                seg["stop_s"].append(t0 + z * dt)
                seg["run"].append(b)
                seg["rate_dial"].append(s.dial_dps * DEG)
                seg["mount"].append(m)
            # the dial shows the setting from the start of each ramp to the next
            dials.append(list(zip([0] + [z for _, z in windows[b][:-1]], [s.dial_dps * DEG for s in st])))
            t0 = (t0 + (n - 1) * dt) + dt + remount_s
        return t0s, seg, dials, pulse_true

    def simulate(self, protocol: TurnTableProtocol, start_time: str, rng: np.random.Generator) -> Recording:
        """Run the schedule; Recording with set-points, the index-pulse line, true events and truth.

        Channels: ``rate_dial`` (commanded dial rate, rad/s, signed). Truth signals:
        ``f_C_*`` (m/s^2), ``w_C_*`` (rad/s, with Earth rate), ``spin_angle``
        (rad), ``pulse`` (V, the index sensor's output, an analog line for the ADC).
        Events: ``pulse_true`` (true rising-edge times, s). The rows of :meth:`run`, all at once.
        """
        return self.run(protocol, start_time, rng).recording()

    def run(self, protocol: TurnTableProtocol, start_time: str, rng: np.random.Generator) -> TurnRun:
        """Run the schedule: a :class:`imurig.rigs.turn_run.TurnRun`, whose rows (those of :meth:`simulate`)
        are made on demand."""
        e = self.errors
        protocol.validate(e.mains_factor)
        dt = 1.0 / protocol.sample_rate_hz
        when = parse_time(start_time)
        steps = protocol.steps(e.mains_factor)
        mounts = list(dict.fromkeys(s.mount for s in steps))
        base = load_model("turn_table.xml")
        base.opt.timestep = dt
        base.opt.gravity[:] = (0.0, 0.0, -self.site.gravity_m_s2)
        base.opt.magnetic[:] = self.site.magnetic_field_W(when)
        # a free spindle (no joint range) and nothing touches: no constraint is ever active, so skipping the
        # constraint stage changes no number (and saves ~15 % per step)
        base.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONSTRAINT
        bid_base, bid_mount = base.body("base").id, base.body("imu_mount").id
        R_WB = rot_x(np.float64(e.level_x_rad)) @ rot_y(np.float64(e.level_y_rad))
        R_PM = e.wobble_rotation()
        set_err = {m: rng.normal(0, e.dial_setting_error, size=len(steps)) for m in mounts}
        profiles, windows, models = [], [], []
        for m in mounts:
            st = [s for s in steps if s.mount == m]
            idx = [i for i, s in enumerate(steps) if s.mount == m]
            prof, win = _profile(st, e, protocol.settle_s, protocol.ramp_s, dt, set_err[m][idx], protocol.min_rounds)
            profiles.append(prof)
            windows.append(win)
            mm = _copy_model(base)
            mm.body_quat[bid_base] = _quat_wxyz(R_WB)
            mm.body_quat[bid_mount] = _quat_wxyz(R_PM @ MOUNTS[m])
            mm.body_pos[bid_mount] = (protocol.radius_m, 0.0, 0.1)
            models.append(mm)
        source, off = self._truth(models, profiles, windows, sensor_slices(base), dt)
        del profiles
        # one record: mountings one after the other (remount gaps), each trimmed to its length
        spin = source["spin_angle"] if isinstance(source, dict) else source.theta
        t0s, seg, dials, pulse_true = self._assemble(spin, off, mounts, steps, windows, dt, protocol.remount_s)
        segments = {k: np.array(v) for k, v in seg.items()}
        radius_known = protocol.radius_m + (rng.normal(0, self.radius_measurement_sigma_m)
                                            if protocol.radius_m > 0 else 0.0)
        meta = {"rig": "turn_table", "site": self.site.to_dict(), "start_time": when.isoformat(),
                "sample_rate_hz": protocol.sample_rate_hz, "runs": mounts, "protocol": protocol.to_dict(),
                "setpoints": ["rate_dial"], "analog_lines": ["pulse"],
                "mains_factor_nominal": 5 / 6,
                "arm_radius_m": radius_known, "arm_radius_sigma_m": self.radius_measurement_sigma_m,
                "pulse_threshold_V": 0.5 * e.pulse_high_V,
                "frames": "W: local level ENU; C: IMU case (site 'imu'); rates and specific force in C"}
        truth_d = {"rig": {"turn_table": e.to_dict(),
                           "dial_setting_error": {m: set_err[m].tolist() for m in mounts},
                           "arm_radius_m": protocol.radius_m,
                           "true_mean_rate_dps": [float(e.true_rate_dps(s.dial_dps, set_err[s.mount][i]))
                                                  for i, s in enumerate(steps)]}}
        return TurnRun(off=off, t0=t0s, dt=dt, dial=dials, source=source, pulse_width_rad=e.pulse_width_rad,
                       pulse_high_V=e.pulse_high_V, segments=segments,
                       segment_units={"start_s": "s", "stop_s": "s", "run": "1", "rate_dial": "rad/s", "mount": ""},
                       meta=meta, truth=truth_d, events={"pulse_true": np.concatenate(pulse_true)})
