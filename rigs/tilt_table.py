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
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from imurig.kernel.errors import ScheduleError
from imurig.kernel.recording import Recording
from imurig.rigs.mujoco_rig import load_model, rollout_servo, sensor_slices
from imurig.kernel.site import Site, parse_time
from imurig.kernel.units import ARCMIN, ARCSEC, DEG

# Mountings: rotation R_MC from the IMU case frame C to the platform mount frame M.
MOUNTS = {
    "z_up": np.eye(3),                                # IMU z along the platform normal (+g reading at theta=0)
    "z_down": np.diag([1.0, -1.0, -1.0]),             # upside down: turned 180 deg about x
}


def rot_x(a):
    c, s = np.cos(a), np.sin(a)
    z, o = np.zeros_like(c), np.ones_like(c)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1), np.stack([z, s, c], -1)], -2)


def rot_y(a):
    c, s = np.cos(a), np.sin(a)
    z, o = np.zeros_like(c), np.ones_like(c)
    return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1)], -2)


def rot_z(a):
    c, s = np.cos(a), np.sin(a)
    z, o = np.zeros_like(c), np.ones_like(c)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


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


@dataclass(frozen=True)
class TableSurvey:
    """What the lab knows of the table errors: the inclinometer procedure of seed 4.3.1."""

    theta_zero_rad: float = 0.0
    level_x_rad: float = 0.0
    phi_zero_rad: dict = field(default_factory=dict)
    accuracy_rad: float = 0.0
    #: the table's stated angle-setting resolution (paper: "known with an accuracy of 0.25 arc
    #: minute"); each set angle lands uniformly within +-res/2. 0: unknown (the reference is then
    #: treated as exact apart from the survey, and the fit is ordinary least squares).
    setting_resolution_rad: float = 0.0

    @classmethod
    def measure(cls, errors: TiltTableErrors, rng: np.random.Generator,
                accuracy_rad: float = 2 * ARCSEC) -> "TableSurvey":
        """Survey the table with an inclinometer reversal of ``accuracy_rad`` (1 sigma).

        The setting resolution is the table's specification, which the simulation injects as is.
        """
        e = lambda: float(rng.normal(0.0, accuracy_rad)) if accuracy_rad > 0 else 0.0  # noqa: E731
        return cls(theta_zero_rad=errors.theta_zero_rad + e(), level_x_rad=errors.level_x_rad + e(),
                   phi_zero_rad={k: v + e() for k, v in errors.phi_zero_rad.items()},
                   accuracy_rad=accuracy_rad, setting_resolution_rad=errors.setting_resolution_rad)

    def to_dict(self) -> dict:
        return asdict(self)


def specific_force_C(theta_rad, phi_rad, mount: str, g: float, theta_zero=0.0, phi_zero=0.0,
                     level_x=0.0) -> np.ndarray:
    """Specific force at rest in the IMU case frame C, (n, 3) m/s^2, for angle arrays (n,).

    f_C = R_MC^T Rz(phi + phi_zero)^T Ry(theta + theta_zero)^T Rx(level_x)^T (0, 0, g).
    """
    theta = np.asarray(theta_rad, float) + theta_zero
    phi = np.asarray(phi_rad, float) + phi_zero
    up = np.array([0.0, 0.0, g])
    f_B = rot_x(np.float64(level_x)).T @ up
    f_T = np.einsum("...ji,j->...i", rot_y(theta), f_B)
    f_P = np.einsum("...ji,...j->...i", rot_z(phi), f_T)
    return f_P @ MOUNTS[mount]  # R_MC^T f_P, row-vector form


def reference_specific_force(segments: dict, g: float, survey: TableSurvey | dict | None) -> np.ndarray:
    """Reference specific force of every segment (n_seg, 3) from its set-points and the survey.

    This is what the lab computes (seed eq. 4.36-4.38), corrected for the surveyed table
    errors. ``segments`` needs 'theta', 'phi' (rad) and 'run' (index into meta run names
    given as segments['mount'] strings or the default order z_down, z_up).
    """
    if isinstance(survey, dict):
        survey = TableSurvey(**survey)
    survey = survey or TableSurvey()
    mounts = segments["mount"]
    out = np.empty((len(mounts), 3))
    for m in np.unique(mounts):
        sel = mounts == m
        out[sel] = specific_force_C(segments["theta"][sel], segments["phi"][sel], str(m), g,
                                    survey.theta_zero_rad, survey.phi_zero_rad.get(str(m), 0.0),
                                    survey.level_x_rad)
    return out


def _command_profile(protocol: TiltTableProtocol, set_theta, set_phi, dt: float):
    """Commanded (theta, phi) per sample and acquisition windows for one run.

    Between positions the table slews on a cosine profile whose peak rate is
    ``slew_rate_deg_s``, then settles, then acquires for ``dwell_s``.
    Returns cmd (nstep, 2) rad, list of (start_idx, stop_idx), total steps.
    """
    pieces, windows = [], []
    n_settle = int(round(protocol.settle_s / dt))
    n_dwell = int(round(protocol.dwell_s / dt))
    rate = protocol.slew_rate_deg_s * DEG
    prev = np.array([set_theta[0], set_phi[0]])
    n = 0
    for k, target in enumerate(np.stack([set_theta, set_phi], 1)):
        delta = float(np.max(np.abs(target - prev)))
        if k > 0 and delta > 0:
            n_slew = max(int(round(0.5 / dt)), int(math.ceil(delta / rate * math.pi / 2 / dt)))
            s = (1 - np.cos(np.pi * np.arange(1, n_slew + 1) / n_slew)) / 2
            pieces.append(prev + s[:, None] * (target - prev))
            n += n_slew
        hold = n_settle + n_dwell + (n_settle if k == 0 else 0)
        pieces.append(np.repeat(target[None], hold, 0))
        windows.append((n + hold - n_dwell, n + hold))
        n += hold
        prev = target
    return np.concatenate(pieces), windows


@dataclass
class TiltTable:
    """The virtual tilt table: MuJoCo model plus its imperfections and survey."""

    errors: TiltTableErrors = field(default_factory=TiltTableErrors)
    survey: TableSurvey | None = None
    site: Site = field(default_factory=Site)
    azimuth_deg: float = 0.0  # heading of the base x axis, from east towards north

    def _run_commands(self, base_model, runs, R_WB, cmd_nom, windows, n_pos, rng):
        """Per mounting: the model (base and mount attitudes), the servo command (n, 2) rad with the
        table's zero errors and each position's setting error (uniform within +-res/2, held from
        slew end to next slew), and its initial joint position."""
        bid_base = base_model.body("base").id
        bid_mount = base_model.body("imu_mount").id
        nstep = cmd_nom.shape[0]
        pos_idx = _position_index(nstep, windows)
        models, ctrl, qpos0, setting_err = [], [], [], {}
        res = self.errors.setting_resolution_rad
        for r in runs:
            m = _copy_model(base_model)
            m.body_quat[bid_base] = _quat_wxyz(R_WB)
            m.body_quat[bid_mount] = _quat_wxyz(MOUNTS[r])
            models.append(m)
            err = rng.uniform(-res / 2, res / 2, size=(n_pos, 2)) if res > 0 else np.zeros((n_pos, 2))
            setting_err[r] = err
            off = np.array([self.errors.theta_zero_rad, self.errors.phi_zero_rad[r]])
            c = cmd_nom + off + err[pos_idx]
            ctrl.append(c)
            qpos0.append(c[0])
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
        """Run the protocol in MuJoCo; return a Recording with set-points and truth, no sensors yet.

        Channels: ``theta``, ``phi`` (commanded set-points, rad). Truth signals at the IMU
        case frame C, 1/sample: ``f_C_x/y/z`` specific force (m/s^2), ``w_C_x/y/z`` angular
        rate including the Earth's rotation (rad/s), ``B_C_x/y/z`` IGRF field (T),
        ``theta_true``/``phi_true`` (rad).
        """
        protocol.validate()
        dt = 1.0 / protocol.sample_rate_hz
        when = parse_time(start_time)
        runs = list(protocol.runs)
        if self.survey is None:
            self.survey = TableSurvey.measure(self.errors, rng)
        missing = [r for r in runs if r not in self.errors.phi_zero_rad]
        if missing:
            raise ScheduleError(f"table errors define no phi-plane error for mounting(s) {missing}")

        base_model = load_model("tilt_table.xml")
        base_model.opt.timestep = dt
        base_model.opt.gravity[:] = (0.0, 0.0, -self.site.gravity_m_s2)
        B_W = self.site.magnetic_field_W(when)
        R_WB = rot_z(np.float64(self.azimuth_deg * DEG)) @ rot_x(np.float64(self.errors.level_x_rad))
        base_model.opt.magnetic[:] = B_W

        nt, nphi = len(protocol.theta_deg), len(protocol.phi_deg)
        set_theta = np.repeat(np.asarray(protocol.theta_deg, float) * DEG, nphi)
        set_phi = np.tile(np.asarray(protocol.phi_deg, float) * DEG, nt)
        cmd_nom, windows = _command_profile(protocol, set_theta, set_phi, dt)
        nstep = cmd_nom.shape[0]
        models, ctrl, qpos0, setting_err = self._run_commands(base_model, runs, R_WB, cmd_nom, windows,
                                                               set_theta.size, rng)
        sd = rollout_servo(models, np.array(qpos0), np.array(ctrl), desc="tilt table (MuJoCo)")
        sl = sensor_slices(base_model)

        # assemble the record: runs one after the other, with the remount time as a gap
        n_total = nstep * len(runs)
        gap = protocol.remount_s
        t_run = np.arange(nstep) * dt
        time_s = np.concatenate([t_run + i * (nstep * dt + gap) for i in range(len(runs))])
        f_C = sd[:, :, sl["f_C"]].reshape(n_total, 3)
        w_C = sd[:, :, sl["w_C"]].reshape(n_total, 3)
        B_C = sd[:, :, sl["B_C"]].reshape(n_total, 3)
        q_WC = sd[:, :, sl["q_WC"]].reshape(n_total, 4)
        w_C = w_C + rotate_to_body(q_WC, self.site.earth_rate_W())  # Earth rate, R_CW Omega_W

        segments, seg_units = self._segments(runs, windows, set_theta, set_phi, dt, nstep * dt + gap)
        pos_idx = _position_index(nstep, windows)
        theta_set = np.tile(set_theta[pos_idx], len(runs))
        phi_set = np.tile(set_phi[pos_idx], len(runs))

        truth_signals = {"theta_true": sd[:, :, sl["theta_true"]].reshape(n_total),
                         "phi_true": sd[:, :, sl["phi_true"]].reshape(n_total)}
        units = {"theta_true": "rad", "phi_true": "rad"}
        for name, arr, unit in (("f_C", f_C, "m/s^2"), ("w_C", w_C, "rad/s"), ("B_C", B_C, "T")):
            for j, ax in enumerate("xyz"):
                truth_signals[f"{name}_{ax}"] = arr[:, j]
                units[f"{name}_{ax}"] = unit

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
        truth = {"rig": {"tilt_table": self.errors.to_dict(),
                         "setting_error_rad": {r: setting_err[r].tolist() for r in runs},
                         "magnetic_field_W_T": B_W.tolist()}}
        return Recording(time_s=time_s, channels={"theta": theta_set, "phi": phi_set},
                         units={"theta": "rad", "phi": "rad"}, segments=segments,
                         segment_units=seg_units, meta=meta, truth=truth,
                         truth_signals=truth_signals, truth_units=units)


def _position_index(nstep: int, windows) -> np.ndarray:
    """Index of the position each step belongs to (a slew belongs to the position it goes to)."""
    ends = np.array([b for _, b in windows])
    return np.minimum(np.searchsorted(ends, np.arange(nstep), side="right"), len(windows) - 1)


def _copy_model(m):
    import copy

    return copy.copy(m)


def rotate_to_body(q_WC: np.ndarray, v_W: np.ndarray) -> np.ndarray:
    """Express a world vector in the body: R_CW v_W for (n, 4) wxyz quaternions q_WC -> (n, 3).

    Uses v' = v + 2 w (u x v) + 2 u x (u x v) with the conjugate quaternion (w, u) = (w, -q_xyz).
    """
    w = q_WC[:, :1]
    u = -q_WC[:, 1:]
    v = np.broadcast_to(v_W, u.shape)
    t = 2 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def reference_with_jacobian(segments: dict, g: float, survey: TableSurvey | dict):
    """Reference (n_seg, 3), its Jacobian (n_seg, 3, q) w.r.t. the surveyed table errors, and
    their 1-sigma uncertainty (q,) -- the survey's inclinometer accuracy.

    Parameters, in order: theta_zero, level_x, phi_zero[mount] for each mount in the survey.
    """
    if isinstance(survey, dict):
        survey = TableSurvey(**survey)
    ref = reference_specific_force(segments, g, survey)
    mounts = sorted(survey.phi_zero_rad)
    h = 1e-6

    def shifted(k, d):
        kw = dict(theta_zero_rad=survey.theta_zero_rad, level_x_rad=survey.level_x_rad,
                  phi_zero_rad=dict(survey.phi_zero_rad))
        if k == 0:
            kw["theta_zero_rad"] += d
        elif k == 1:
            kw["level_x_rad"] += d
        else:
            kw["phi_zero_rad"][mounts[k - 2]] += d
        return reference_specific_force(segments, g, replace(survey, **kw))

    q = 2 + len(mounts)
    J = np.stack([(shifted(k, h) - shifted(k, -h)) / (2 * h) for k in range(q)], axis=-1)
    sigma = np.full(q, survey.accuracy_rad)
    return ref, J, sigma


def setting_error_covariance(segments: dict, g: float, survey: TableSurvey | dict) -> np.ndarray:
    """Covariance (n_seg, 3, 3) of each segment's reference error from the angle-setting resolution.

    Each set angle lands uniformly within +-res/2 (variance res^2 / 12), independently for theta
    and phi and from position to position, so the reference error of segment k is
    J_k (d_theta, d_phi) with J_k = d f_C / d(theta, phi) (3, 2), and

        Sigma_k = res^2 / 12 * J_k J_k'        [(m/s^2)^2]

    It is heteroscedastic (zero for an axis along the theta axis' derivative null, e.g. f_z near
    theta = 0) and correlated across the three axes. Zero when the survey gives no resolution.
    """
    if isinstance(survey, dict):
        survey = TableSurvey(**survey)
    n = len(segments["theta"])
    res = survey.setting_resolution_rad
    if res <= 0:
        return np.zeros((n, 3, 3))
    h = 1e-6
    cols = []
    for key in ("theta", "phi"):
        up, down = dict(segments), dict(segments)
        up[key] = np.asarray(segments[key], float) + h
        down[key] = np.asarray(segments[key], float) - h
        cols.append((reference_specific_force(up, g, survey) - reference_specific_force(down, g, survey)) / (2 * h))
    J = np.stack(cols, axis=-1)  # (n, 3, 2)
    return res ** 2 / 12.0 * np.einsum("kia,kja->kij", J, J)
