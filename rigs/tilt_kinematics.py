"""Tilt-table kinematics and the lab's reference (seed 4.3.1, eq. 4.33-4.38): mountings, elementary
rotations, the inclinometer survey, the specific force at rest, and the reference with its Jacobian
and setting-error covariance. Pure numpy: the MuJoCo table (:mod:`imurig.rigs.tilt_table`) and the
calibration share it.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace

import numpy as np

from imurig.kernel.quaternion import q_conj, q_rotate
from imurig.kernel.units import ARCSEC


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
    def measure(cls, errors, rng: np.random.Generator,
                accuracy_rad: float = 2 * ARCSEC) -> "TableSurvey":
        """Survey the table (``errors``: :class:`imurig.rigs.tilt_table.TiltTableErrors`) with an
        inclinometer reversal of ``accuracy_rad`` (1 sigma).

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


def rotate_to_body(q_WC: np.ndarray, v_W: np.ndarray) -> np.ndarray:
    """Express a world vector in the body: R_CW v_W for (n, 4) wxyz quaternions q_WC -> (n, 3).

    :func:`imurig.kernel.quaternion.q_rotate` by the conjugate quaternion (w, u) = (w, -q_xyz).
    """
    return q_rotate(q_conj(q_WC), v_W)


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
