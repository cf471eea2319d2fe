"""A phi-plane error of the tilt table that the seed's reference leaves out (seed 4.3.1, listing C.1.1).

The seed levels the table with an inclinometer and finds a phi-plane error "between 120' and 145',
dependent on the position in that the IMU is mounted"; its calibration program (appendix C.1.1)
then computes the true accelerations from the nominal angles only (``TrueData = sin(TiltVertical)
cos(RotHorizontal) g0``, ``RotHorizontal = (0:30:350)/180*pi``). Whatever part delta of the
phi-plane error the setting did not take out is therefore left in: the platform stands at
phi_set + phi_zero + delta while the reference assumes phi_set + phi_zero (imurig's reference: its
surveyed phi_zero; the seed's: nominal angles after compensating the error when setting). delta is
a turn of the platform about the table's phi axis, the same in both mountings; in the IMU case
frame C it is a turn about +z in one mounting and about -z in the other (the "z_down" mounting is
turned 180 deg about x):

    f_C,true = M_m' Rz(delta)' M_m f_C,ref = Rz(s_m delta)' f_C,ref,     s_m = +1 (z_up), -1 (z_down)
    to first order: delta f_C = s_m delta (f_y, -f_x, 0)                                  [m/s^2]

One set of calibration coefficients absorbs the part common to both mountings, not the part of
opposite sign: its residual is +-delta a_y in A_x and -+delta a_x in A_y, which products with a_z
(a_z flips with the mounting) partly remove. Only the mean over the two mountings (in the table's
frame) acts so; their difference is an IMU misalignment the linear model absorbs. The seed's
tables therefore constrain that mean (``delta_phi_rad``) and cannot separate the two mountings.

Stage "rig": :meth:`ReferencePhiError.apply_to_table` turns the drawn table (an
:class:`imurig.rigs.tilt_table.TiltTableErrors`; duck-typed, effect modules do not import rigs) by
delta in each mounting after its survey, so the survey and the reference do not know it. Off by
default (delta = 0: the table is untouched). Physical bound: the seed quotes the phi-plane error
only to 5 arcmin steps (120'-145') and the levelling error as "typically around 01'"; a
compensation left a few arcmin off is within that reading, while the uncompensated 120' would give
residuals of ~0.4 m/s^2, 60x the seed's.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np

from imurig.kernel.units import ARCMIN
from imurig.sensors.effects.base import Effect, Param

#: the mounting's turn sign about the IMU's z (the "z_down" mounting is turned 180 deg about x)
MOUNT_SIGN = {"z_up": 1.0, "z_down": -1.0}
#: physical bound on |delta| (module doc): half the 5 arcmin step of the seed's quoted phi-plane error
#: plus the levelling error it calls typical (1 arcmin), per mounting
BOUND_RAD = 3.5 * ARCMIN


def turn_z(delta_rad: float, mount: str) -> np.ndarray:
    """Rz(s_m delta)' (3, 3): f_C,true = turn_z @ f_C,ref (module doc)."""
    a = MOUNT_SIGN[mount] * delta_rad
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass
class ReferencePhiError(Effect):
    """The phi-plane error delta (rad) left out of the reference, common to both mountings."""

    delta_phi_rad: float = 0.0

    name: ClassVar[str] = "reference_phi_error"
    stage: ClassVar[str] = "rig"
    physics: ClassVar[str] = ("a phi-plane error of the tilt table that the reference leaves out: the IMU turns about +z "
                              "in one mounting and about -z in the other, which one set of coefficients cannot absorb")
    seed_section: ClassVar[str] = "4.3.1, appendix C.1.1"
    seed_says: ClassVar[str] = ("4.3.1: 'This error ranges between 120' and 145', dependent on the position in that "
                                "the IMU is mounted on the tilt table.' Listing C.1.1 computes the reference from the "
                                "nominal angles: 'TrueData = (sin(TiltVertical) * cos(RotHorizontal) * g0)', "
                                "'RotHorizontal = (0:30:350)./180*pi'.")
    params: ClassVar[tuple] = (
        Param("delta_phi_rad", "rad", note=f"no datasheet; bound |delta| <= {BOUND_RAD / ARCMIN:.1f} arcmin (module "
                                           "doc); fitted to Tabs. 4.4-4.5 in the Delft 2005 preset"),)

    def apply_to_table(self, errors):
        """The table ``errors`` (TiltTableErrors) turned by delta in each mounting; the survey, taken
        before, keeps the old phi_zero (module doc)."""
        if self.delta_phi_rad == 0.0:
            return errors
        return replace(errors, phi_zero_rad={m: v + self.delta_phi_rad for m, v in errors.phi_zero_rad.items()})

    def inject(self, x: np.ndarray, ctx=None, rng=None) -> np.ndarray:
        """The true angles (m, 2) rad for the reference's (theta, phi) ``x`` (m, 2): phi + delta."""
        x = np.asarray(x, float)
        return x + np.array([0.0, self.delta_phi_rad])

    def specific_force(self, f_ref_C: np.ndarray, mount: str) -> np.ndarray:
        """The true specific force (n, 3) m/s^2 in C for the reference's ``f_ref_C`` (n, 3) (module doc)."""
        return np.asarray(f_ref_C, float) @ turn_z(self.delta_phi_rad, mount).T

    def fitted(self, truth, channel: str | None = None) -> dict[str, float]:
        """{delta_phi_rad} the rig recorded (truth["rig"]["reference_phi_error"]; 0 without)."""
        b = ((truth or {}).get("rig") or {}).get(self.name) or {}
        return {"delta_phi_rad": float(b.get("delta_phi_rad", 0.0))}
