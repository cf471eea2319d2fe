"""The two-axis tilt table (seed section 4.3.1): protocol, imperfections, MuJoCo truth, reference.

Geometry (seed eq. 4.33-4.38). The table tilts by theta about the base y axis, then turns
the platform by phi about its own z axis. With the IMU case frame C on the platform, the
specific force at rest is

    f_C = R_CM^T Rz(phi)^T Ry(theta)^T R_WB^T (0, 0, g)      [m/s^2, (3,)]

where R_WB is the base levelling error and R_CM... the mounting (run) rotation. For a
perfect table and the "z_up" mount this is g (-cos(phi) sin(theta), sin(phi) sin(theta),
cos(theta)) -- seed eq. 4.36-4.38 with the seed's sign conventions for x and y.

Imperfections (truth, injected): theta zero (levelling) error ~1 arcmin, a levelling error
about x below the inclinometer's accuracy, the phi-plane error 80-105 arcmin that depends
on the mounting, and a finite angle setting resolution. The lab knows the first three
only through its inclinometer survey (:class:`TableSurvey`), which the reference uses.
Optionally (``TiltTable.backlash``, off by default) the adjusting wheels' gear clearance shifts
each position reached by turning a wheel back (seed 4.3.1, effect ``table_backlash``).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

import mujoco
import numpy as np

from imurig.kernel.errors import ConfigError, ScheduleError
from imurig.kernel.import_lab import available_memory_bytes
from imurig.kernel.recording import Recording
from imurig.rigs.mujoco_rig import load_model, sensor_slices
from imurig.kernel.site import Site, parse_time
from imurig.kernel.units import ARCMIN, DEG
from imurig.sensors.effects.table_backlash import TableBacklash
from imurig.rigs.tilt_kinematics import (MOUNTS, TableSurvey, reference_specific_force,  # noqa: F401 (re-exported)
                                         reference_with_jacobian, rot_x, rot_y, rot_z, rotate_to_body,
                                         setting_error_covariance, specific_force_C)
from imurig.rigs.tilt_schedule import command_profile as _command_profile  # noqa: F401 (imported from here too)
from imurig.rigs.tilt_schedule import position_counts as _position_counts, position_index as _position_index
from imurig.rigs.tilt_truth import SIGNALS as SIGNAL_NAMES
from imurig.rigs.tilt_truth import full_truth, stitched_pieces
from imurig.rigs.truth_pieces import TruthPieces


def _quat_wxyz(R: np.ndarray) -> np.ndarray:
    import mujoco

    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(R, dtype=float).ravel())
    return q


@dataclass(frozen=True)
class TiltTableProtocol:
    """The measurement schedule (seed 4.3.1): every theta x phi, in each run (mounting).

    Angles in degrees here (lab units at the constructor); see ``positions()`` for SI.
    """

    theta_deg: tuple[float, ...] = (0, 10, 20, 30, 40, 50, 60, 70, 80, 90)
    phi_deg: tuple[float, ...] = (0, 30, 60, 90, 120, 150, 180, 210, 240, 270, 300, 330)
    runs: tuple[str, ...] = ("z_down", "z_up")
    dwell_s: float = 15.0
    settle_s: float = 2.0
    slew_rate_deg_s: float = 6.0
    remount_s: float = 900.0
    sample_rate_hz: float = 1000.0

    def validate(self) -> "TiltTableProtocol":
        if not self.theta_deg or not self.phi_deg:
            raise ScheduleError("the protocol needs at least one theta and one phi angle")
        if not self.runs:
            raise ScheduleError("the protocol needs at least one run (mounting), e.g. runs=('z_up',)")
        bad = [r for r in self.runs if r not in MOUNTS]
        if bad:
            raise ScheduleError(f"unknown mounting(s) {bad}; choose from {sorted(MOUNTS)}")
        if any(abs(t) > 95 for t in self.theta_deg):
            raise ScheduleError(f"theta must lie within +-95 deg (the table's travel); got {self.theta_deg}")
        for name in ("dwell_s", "sample_rate_hz", "slew_rate_deg_s"):
            if not getattr(self, name) > 0:
                raise ScheduleError(f"{name} must be positive, got {getattr(self, name)}")
        if self.settle_s < 0 or self.remount_s < 0:
            raise ScheduleError("settle_s and remount_s cannot be negative")
        if self.dwell_s * self.sample_rate_hz < 10:
            raise ScheduleError(f"a dwell of {self.dwell_s} s at {self.sample_rate_hz} Hz gives fewer than 10 "
                                "samples per position; lengthen the dwell or raise the rate")
        # the rig's run and the stream keep the record's time axis and row index (16 bytes a sample)
        n = self.n_positions * self.dwell_s * self.sample_rate_hz
        have = available_memory_bytes()
        if 16 * n > have:
            raise ScheduleError(f"{self.n_positions} positions of {self.dwell_s:g} s at {self.sample_rate_hz:g} Hz "
                                f"are {n:.3g} samples: about {16 * n / 1e9:.3g} GB of memory for the time axis alone "
                                f"({have / 1e9:.3g} GB available) and {40 * n / 1e9:.3g} GB of recording on disk; "
                                "shorten --dwell, lower --rate or take fewer --theta/--phi positions")
        return self

    def positions(self) -> list[tuple[str, float, float]]:
        """(run, theta_rad, phi_rad) in measurement order."""
        return [(r, t * DEG, p * DEG) for r in self.runs for t in self.theta_deg for p in self.phi_deg]

    @property
    def n_positions(self) -> int:
        return len(self.runs) * len(self.theta_deg) * len(self.phi_deg)

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class TiltTableErrors:
    """Injected table imperfections (truth), SI radians.

    theta_zero_rad: levelling error about the theta (y) axis; the table's true tilt is
        theta_set + theta_zero. phi_zero_rad: the phi-plane error per mounting (true
        phi = phi_set + phi_zero[run]). level_x_rad: base tilt about x.
        setting_resolution_rad: each set angle lands uniformly within +-res/2 of the target.
    """

    theta_zero_rad: float = 1.0 * ARCMIN
    level_x_rad: float = 0.2 * ARCMIN
    phi_zero_rad: dict = field(default_factory=lambda: {"z_down": 80 * ARCMIN, "z_up": 105 * ARCMIN})
    setting_resolution_rad: float = 0.25 * ARCMIN

    @classmethod
    def draw(cls, rng: np.random.Generator, runs=("z_down", "z_up")) -> "TiltTableErrors":
        """Draw a plausible table (seed 4.3.1 ranges)."""
        return cls(theta_zero_rad=float(rng.normal(0, 1.0)) * ARCMIN,
                   level_x_rad=float(rng.normal(0, 0.2)) * ARCMIN,
                   phi_zero_rad={r: float(rng.uniform(80, 105)) * ARCMIN for r in runs},
                   setting_resolution_rad=0.25 * ARCMIN)

    def to_dict(self) -> dict:
        return asdict(self)


#: the coarse MuJoCo step in the moves and the fastest slew it is validated for ("auto")
AUTO_MOVE_STEP_S = 0.01
AUTO_MAX_SLEW_DEG_S = 6.0


@dataclass
class TiltTable:
    """The virtual tilt table: MuJoCo model plus its imperfections and survey."""

    errors: TiltTableErrors = field(default_factory=TiltTableErrors)
    survey: TableSurvey | None = None
    site: Site = field(default_factory=Site)
    azimuth_deg: float = 0.0  # heading of the base x axis, from east towards north
    #: the adjusting wheels' gear clearance (effect ``table_backlash``; none by default)
    backlash: TableBacklash = field(default_factory=TableBacklash)
    #: the truth in the acquisition windows: "closed_form" (MuJoCo steps only the moves, module
    #: :mod:`imurig.rigs.tilt_truth`) or "mujoco" (MuJoCo steps every sample; same truth to 1e-11 g)
    dwell_truth: str = "closed_form"
    #: MuJoCo's time step in the moves (s; None: the sample period). Coarser steps are interpolated
    #: linearly between stepped samples (:mod:`imurig.rigs.tilt_truth`); the windows are exact either way.
    #: "auto": 10 ms where that is validated (slews up to the seed's 6 deg/s: f_C within half an ADC
    #: step, tests/test_tilt_table.py), the sample period for faster slews (at 30 deg/s a 10 ms step
    #: leaves ~3e-3 m/s^2 against a 1 ms replay, which the slew analyses would see)
    move_step_s: float | None | str = "auto"

    def _move_substeps(self, dt: float, slew_rate_deg_s: float) -> int:
        """Samples per MuJoCo step in the moves (>= 1)."""
        step = self.move_step_s
        if step == "auto":
            step = AUTO_MOVE_STEP_S if slew_rate_deg_s <= AUTO_MAX_SLEW_DEG_S else None
        if step is None:
            return 1
        if isinstance(step, str) or not step > 0:
            raise ConfigError(f"move_step_s must be positive (s), 'auto' or None, got {self.move_step_s!r}")
        return max(1, int(round(step / dt)))

    def _backlash_offsets(self, set_theta, set_phi, runs) -> dict | None:
        """Per mounting, the (m, 2) rad shift of the true from the read (theta, phi) by the gear
        clearance, from the wheels' moves over all runs in order (None without clearance)."""
        b = self.backlash
        if b.beta_theta_rad == 0.0 and b.beta_phi_rad == 0.0:
            return None
        m = set_theta.size
        off = b.offsets(np.tile(set_theta, len(runs)), np.tile(set_phi, len(runs)))
        return {r: off[i * m:(i + 1) * m] for i, r in enumerate(runs)}

    def _run_commands(self, base_model, runs, R_WB, cmd_nom, windows, n_pos, rng, backlash=None):
        """Per mounting: the model (base and mount attitudes), the servo command (n, 2) rad (rows of one
        (mountings, n, 2) array) with the
        table's zero errors, each position's setting error (uniform within +-res/2, held from
        slew end to next slew) and the gear clearance's shift (``backlash``: per mounting, (m, 2)
        rad, or None), and its initial joint position."""
        bid_base = base_model.body("base").id
        bid_mount = base_model.body("imu_mount").id
        nstep = cmd_nom.shape[0]
        bounds = np.concatenate(([0], np.cumsum(_position_counts(nstep, windows)))).tolist()   # a position's rows
        models, qpos0, setting_err = [], [], {}
        ctrl = np.empty((len(runs), nstep, 2))   # filled in place: no list of copies
        res = self.errors.setting_resolution_rad
        for i, r in enumerate(runs):
            m = _copy_model(base_model)
            m.body_quat[bid_base] = _quat_wxyz(R_WB)
            m.body_quat[bid_mount] = _quat_wxyz(MOUNTS[r])
            models.append(m)
            err = rng.uniform(-res / 2, res / 2, size=(n_pos, 2)) if res > 0 else np.zeros((n_pos, 2))
            setting_err[r] = err
            off = np.array([self.errors.theta_zero_rad, self.errors.phi_zero_rad[r]])
            c = ctrl[i]
            np.add(cmd_nom, off, out=c)
            # each position's constants over its rows, slice by slice: the sums of np.repeat's rows, without
            # its (n, 2) temporary
            for shift in (err,) if backlash is None else (err, backlash[r]):
                for lo, hi, d in zip(bounds[:-1], bounds[1:], shift):
                    c[lo:hi] += d
            qpos0.append(c[0].copy())
        return models, ctrl, qpos0, setting_err

    @staticmethod
    def _segments(runs, windows, set_theta, set_phi, dt, run_span_s):
        """One segment per position and mounting: start/stop (s), run index, set-points (rad), mounting."""
        seg_start, seg_stop, seg_run, seg_mount = [], [], [], []
        for i, r in enumerate(runs):
            t0 = i * run_span_s
            for a, b in windows:
                seg_start.append(t0 + a * dt)
                seg_stop.append(t0 + b * dt)
                seg_run.append(i)
                seg_mount.append(r)
        segments = {"start_s": np.array(seg_start), "stop_s": np.array(seg_stop),
                    "run": np.array(seg_run), "theta": np.tile(set_theta, len(runs)),
                    "phi": np.tile(set_phi, len(runs)), "mount": np.array(seg_mount)}
        return segments, {"start_s": "s", "stop_s": "s", "run": "1", "theta": "rad", "phi": "rad", "mount": ""}

    def simulate(self, protocol: TiltTableProtocol, start_time: str, rng: np.random.Generator) -> Recording:
        """Run the protocol (MuJoCo for the moves, the closed form at rest unless ``dwell_truth`` is
        "mujoco", :mod:`imurig.rigs.tilt_truth`); return a Recording with set-points and truth, no sensors yet.

        Channels: ``theta``, ``phi`` (commanded set-points, rad). Truth signals at the IMU
        case frame C, 1/sample: ``f_C_x/y/z`` specific force (m/s^2), ``w_C_x/y/z`` angular
        rate including the Earth's rotation (rad/s), ``B_C_x/y/z`` IGRF field (T),
        ``theta_true``/``phi_true`` (rad). The whole record of :meth:`run`.
        """
        return self.run(protocol, start_time, rng).recording()

    def run(self, protocol: TiltTableProtocol, start_time: str, rng: np.random.Generator,
            defer=None) -> "TiltRun":
        """Run the protocol as :meth:`simulate` does, and keep its truth as pieces (:class:`TiltRun`):
        any sample range of the record on demand, in memory of the moves' knots, not the record.
        ``defer``: MuJoCo's moves later, ``defer(job)`` given the job that steps them (the closed-form
        truth at rest only; :func:`imurig.rigs.tilt_truth.stitched_pieces`): the run is returned before
        its moves are stepped, and its truth rows wait for them."""
        protocol.validate()
        dt = 1.0 / protocol.sample_rate_hz
        when = parse_time(start_time)
        runs = list(protocol.runs)
        if self.survey is None:
            self.survey = TableSurvey.measure(self.errors, rng)
        missing = [r for r in runs if r not in self.errors.phi_zero_rad]
        if missing:
            raise ScheduleError(f"table errors define no phi-plane error for mounting(s) {missing}")
        if self.dwell_truth not in ("closed_form", "mujoco"):
            raise ConfigError(f"dwell_truth must be 'closed_form' or 'mujoco', got {self.dwell_truth!r}")

        base_model = load_model("tilt_table.xml")
        base_model.opt.timestep = dt
        base_model.opt.gravity[:] = (0.0, 0.0, -self.site.gravity_m_s2)
        B_W = self.site.magnetic_field_W(when)
        R_WB = rot_z(np.float64(self.azimuth_deg * DEG)) @ rot_x(np.float64(self.errors.level_x_rad))
        base_model.opt.magnetic[:] = B_W
        # the joints stay within their ranges (theta within +-95 deg) and nothing touches: no constraint
        # is ever active, so skipping the constraint stage changes no number (and saves ~15 % per step)
        base_model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONSTRAINT

        nt, nphi = len(protocol.theta_deg), len(protocol.phi_deg)
        set_theta = np.repeat(np.asarray(protocol.theta_deg, float) * DEG, nphi)
        set_phi = np.tile(np.asarray(protocol.phi_deg, float) * DEG, nt)
        cmd_nom, windows = _command_profile(protocol, set_theta, set_phi, dt)
        nstep = cmd_nom.shape[0]
        backlash = self._backlash_offsets(set_theta, set_phi, runs)
        models, ctrl, qpos0, setting_err = self._run_commands(base_model, runs, R_WB, cmd_nom, windows,
                                                               set_theta.size, rng, backlash)
        del cmd_nom
        sl = sensor_slices(base_model)
        earth_W = self.site.earth_rate_W()
        if self.dwell_truth == "mujoco":
            truth = full_truth(models, np.array(qpos0), ctrl, sl, earth_W)
        else:
            truth = stitched_pieces(models, runs, R_WB, ctrl, windows, sl, self.site.gravity_m_s2,
                                    earth_W, B_W, self._move_substeps(dt, protocol.slew_rate_deg_s), defer)
        del ctrl

        gap = protocol.remount_s
        segments, seg_units = self._segments(runs, windows, set_theta, set_phi, dt, nstep * dt + gap)
        meta = {
            "rig": "tilt_table",
            "site": self.site.to_dict(),
            "start_time": when.isoformat(),
            "sample_rate_hz": protocol.sample_rate_hz,
            "runs": runs,
            "protocol": protocol.to_dict(),
            "table_survey": self.survey.to_dict(),
            "table_azimuth_deg": self.azimuth_deg,
            "setpoints": ["theta", "phi"],
            "frames": "W: local level ENU; C: IMU case (site 'imu'); specific force and rates in C",
        }
        truth_dict = {"rig": {"tilt_table": self.errors.to_dict(),
                              "setting_error_rad": {r: setting_err[r].tolist() for r in runs},
                              "magnetic_field_W_T": B_W.tolist()}}
        if backlash is not None:
            truth_dict["rig"][self.backlash.name] = self.backlash.settings()
        return TiltRun(nstep=nstep, nruns=len(runs), dt=dt, gap_s=gap, windows=windows, set_theta=set_theta,
                       set_phi=set_phi, truth_source=truth, segments=segments, segment_units=seg_units, meta=meta,
                       truth=truth_dict)


@dataclass
class TiltRun:
    """A simulated tilt-table record whose samples are made on demand (:meth:`TiltTable.run`).

    The runs follow one another with the remount time as a gap: sample i of run r is at
    t = i dt + r (nstep dt + gap_s). Channels ``theta``, ``phi``: the set-points (rad) of the position
    each sample belongs to (a slew belongs to the position it goes to); truth signals from
    ``truth_source`` (:class:`imurig.rigs.truth_pieces.TruthPieces`, or whole arrays)."""

    nstep: int
    nruns: int
    dt: float
    gap_s: float
    windows: list
    set_theta: np.ndarray
    set_phi: np.ndarray
    truth_source: object
    segments: dict
    segment_units: dict
    meta: dict
    truth: dict
    units: dict = field(default_factory=lambda: {"theta": "rad", "phi": "rad"})
    events: dict = field(default_factory=dict)

    @property
    def n(self) -> int:
        return self.nstep * self.nruns

    @property
    def truth_units(self) -> dict:
        return {k: {"f": "m/s^2", "w": "rad/s", "B": "T"}.get(k[0], "rad") for k in SIGNAL_NAMES}

    def time_rows(self, a: int, b: int) -> np.ndarray:
        """time_s over samples [a, b) (the same values as the whole record's)."""
        out = np.empty(b - a)
        for r in range(self.nruns):
            lo, hi = max(a, r * self.nstep), min(b, (r + 1) * self.nstep)
            if lo < hi:
                out[lo - a:hi - a] = np.arange(lo - r * self.nstep, hi - r * self.nstep) * self.dt \
                    + r * (self.nstep * self.dt + self.gap_s)
        return out

    def channel_rows(self, a: int, b: int) -> dict:
        """The set-point channels over samples [a, b)."""
        pos = _position_index(self.nstep, self.windows, np.arange(a, b) % self.nstep)
        return {"theta": self.set_theta[pos], "phi": self.set_phi[pos]}

    def truth_rows(self, a: int, b: int) -> dict:
        """The truth signals over samples [a, b)."""
        src = self.truth_source
        if isinstance(src, TruthPieces):
            return src.rows(a, b)
        return {k: v[a:b] for k, v in src.items()}

    def recording(self) -> Recording:
        """The whole record as a Recording (set-points and truth, no sensors)."""
        truth_signals = self.truth_rows(0, self.n)
        return Recording(time_s=self.time_rows(0, self.n), channels=self.channel_rows(0, self.n),
                         units=dict(self.units), segments=self.segments, segment_units=self.segment_units,
                         meta=self.meta, truth=self.truth, truth_signals=truth_signals,
                         truth_units={k: self.truth_units[k] for k in truth_signals})


def _copy_model(m):
    import copy

    return copy.copy(m)
