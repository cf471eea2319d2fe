"""Gear clearance (backlash) of the tilt table's adjusting wheels (seed 4.3.1).

The angle scales read the wheel; the platform lags the wheel by half the gear clearance in the
direction of the wheel's last move. Per wheel (theta and phi separately), at position k:

    theta_true,k = theta_read,k - s_theta,k beta_theta / 2                       [rad]
    phi_true,k   = phi_read,k   - s_phi,k   beta_phi   / 2

s_k = sign(x_k - x_(k-1)) of the last position where the wheel's reading changed
(:func:`approach_signs`), +-1; before the first move it is the wheel's ``initial_direction``
(the direction it was last turned while levelling). A wheel turned one way only keeps s = +1 and
its backlash is one constant zero offset (the inclinometer survey's theta zero absorbs it); a wheel
that reverses shifts every position reached the other way by beta. The tilt-table protocol visits
every phi for each theta and winds phi back for the next theta, so phi reverses once per theta.

Stage "rig": the tilt table (:class:`imurig.rigs.tilt_table.TiltTable`, ``backlash``) adds
:meth:`TableBacklash.offsets` of its set-point sequence (all runs in order, so a remount's wind-back
counts) to the servo command, and writes the settings under truth["rig"]["table_backlash"]; the
truth signals theta_true and phi_true hold the shift, the set-point channels do not. Off by default
(beta = 0: the rig is untouched).

Diagnosis (not offered through a view: the position view holds no set-points): to first order in
beta the specific force at position k changes by

    delta f_k = -1/2 s_theta,k df/dtheta beta_theta - 1/2 s_phi,k df/dphi beta_phi

so :func:`backlash_columns` gives the two regression columns (-s df/dtheta / 2, -s df/dphi / 2)
whose amplitudes are beta_theta and beta_phi (rad); the caller supplies the reference's Jacobian.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from imurig.kernel.units import ARCMIN
from imurig.sensors.effects.base import Effect, Param


def approach_signs(readings, initial_direction: int = 1) -> np.ndarray:
    """s_k (int, +-1) for a sequence of one wheel's scale readings (rad, per position or per
    sample): the sign of the last nonzero change up to and including k; ``initial_direction``
    (+1 or -1) until the wheel first moves."""
    if initial_direction not in (1, -1):
        raise ValueError(f"initial_direction is +1 or -1, got {initial_direction!r}")
    x = np.asarray(readings, float)
    step = np.sign(np.diff(x, prepend=x[:1])).astype(int) if x.size else np.zeros(0, int)
    if step.size == 0:
        return step
    step[0] = initial_direction
    last = np.maximum.accumulate(np.where(step != 0, np.arange(step.size), 0))  # index of the last move
    return step[last]


def backlash_columns(sign_theta, sign_phi, df_dtheta, df_dphi) -> np.ndarray:
    """The regression columns of beta_theta and beta_phi (module doc): (-s_theta df/dtheta / 2,
    -s_phi df/dphi / 2) stacked on a new last axis; df_* (m,) or (m, 3) in m/s^2 per rad."""
    st = np.asarray(sign_theta, float)
    sp = np.asarray(sign_phi, float)
    dt, dp = np.asarray(df_dtheta, float), np.asarray(df_dphi, float)
    if dt.ndim == 2:
        st, sp = st[:, None], sp[:, None]
    return np.stack([-0.5 * st * dt, -0.5 * sp * dp], axis=-1)


@dataclass
class TableBacklash(Effect):
    """Gear clearances beta_theta, beta_phi (rad) of the two adjusting wheels."""

    beta_theta_rad: float = 0.0
    beta_phi_rad: float = 0.0
    initial_direction_theta: int = 1
    initial_direction_phi: int = 1

    name: ClassVar[str] = "table_backlash"
    stage: ClassVar[str] = "rig"
    physics: ClassVar[str] = ("gear clearance of the tilt table's adjusting wheels: a wheel turned back shifts the "
                              "platform by the clearance against its scale reading")
    seed_section: ClassVar[str] = "4.3.1"
    seed_says: ClassVar[str] = ("'It is crucial that the adjusting wheels of the tilt table are only turned in one "
                                "direction before taking readings of the angle scale. Otherwise, the clearance ratio "
                                "of the gear is falsifying the scale readings.'")
    params: ClassVar[tuple] = (
        Param("beta_theta_rad", "rad", note="no datasheet or seed value; it matters where it exceeds the table's "
                                            f"0.25 arcmin ({0.25 * ARCMIN:.2e} rad) setting accuracy"),
        Param("beta_phi_rad", "rad", note="as beta_theta, for the phi wheel"),
        Param("initial_direction_theta", "1", seed=1.0, note="the direction the wheel was last turned "
                                                             "while levelling (+1 or -1)"),
        Param("initial_direction_phi", "1", seed=1.0))

    def signs(self, theta_read, phi_read) -> tuple[np.ndarray, np.ndarray]:
        """(s_theta, s_phi) per position (module doc)."""
        return (approach_signs(theta_read, self.initial_direction_theta),
                approach_signs(phi_read, self.initial_direction_phi))

    def offsets(self, theta_read, phi_read) -> np.ndarray:
        """(m, 2) rad: true minus read angle per position, (-s_theta beta_theta / 2, -s_phi beta_phi / 2)."""
        st, sp = self.signs(theta_read, phi_read)
        return np.column_stack([-0.5 * self.beta_theta_rad * st, -0.5 * self.beta_phi_rad * sp])

    def inject(self, x: np.ndarray, ctx=None, rng=None) -> np.ndarray:
        """The true angles (m, 2) rad for the scale readings ``x`` (m, 2) = (theta, phi) (module doc)."""
        x = np.asarray(x, float)
        if self.beta_theta_rad == 0.0 and self.beta_phi_rad == 0.0:
            return x
        return x + self.offsets(x[:, 0], x[:, 1])

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        """{beta_theta_rad, beta_phi_rad} the rig recorded (truth["rig"]["table_backlash"]; 0 without)."""
        b = ((truth or {}).get("rig") or {}).get(self.name) or {}
        return {"beta_theta_rad": float(b.get("beta_theta_rad", 0.0)),
                "beta_phi_rad": float(b.get("beta_phi_rad", 0.0))}
