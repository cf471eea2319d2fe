"""The diagnosis views of the turn-table, appendix-B row, thermal-chamber and magnetometer records.

A view is what a diagnosis shows the effects of one record, one row per observation (a
whole-round window, a timed row, a temperature step, a block mean); each effect's
``candidates(view)`` returns its columns for the views it knows (its ``views``: the views'
``kind``) and none for the others. :class:`~imurig.sensors.effects.base.PositionView` (static
tilt-table positions) lives beside the effect contract.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np


@dataclass
class TurnView:
    """The diagnosis' view of a turn-table record for one gyro, one row per acquisition window
    (whole rounds at one table rate and mounting; m rows).

    channel ("gyro_p"), axis ("p"); on_axis (m,): e_j = +1 / -1 while the gyro lies up / down
    the table's spin axis, 0 otherwise; specific_force_m_s2 (m,): the window's mean specific
    force along the gyro's axis; table_rate_rad_s (m,); mount (m,): the mounting names;
    earth_rate_in_twin: whether the twin's reference rate includes the Earth's vertical rate.
    """

    channel: str
    axis: str
    on_axis: np.ndarray
    specific_force_m_s2: np.ndarray
    table_rate_rad_s: np.ndarray | None = None
    mount: tuple = ()
    earth_rate_in_twin: bool = True
    kind: ClassVar[str] = "turn_windows"


@dataclass
class TurnSampleView:
    """The samples of one channel inside the whole-round windows of a turn-table record (N samples).

    angle_rad (N,): the table angle of each sample in [0, 2 pi), from the index pulses;
    residual_V (N,): the channel less its running mean over the slip-ring effect's ``window``
    samples (the white part; the slow ripple removed); alpha: the test's threshold p; signal_V (N,):
    the channel as logged (a ripple locked to the table angle kept), or None; window (N,), time_s
    (N,): each sample's whole-round window and time, for the per-window mean and trend the ripple
    test removes; quantum_V: the ADC step q (V; 0 unknown), the floor q / sqrt(12) of the noise.
    """

    channel: str
    angle_rad: np.ndarray
    residual_V: np.ndarray
    alpha: float = 0.01
    signal_V: np.ndarray | None = None
    quantum_V: float = 0.0
    window: np.ndarray | None = None
    time_s: np.ndarray | None = None
    kind: ClassVar[str] = "turn_samples"


@dataclass
class RateShortfallView:
    """Appendix-B rows, the rate observable: rate_dps (m,), the stopwatch's table rate (deg/s), for
    the relative shortfall d = measured rate / (factor x dial) - 1 of each timed row."""

    rate_dps: np.ndarray
    kind: ClassVar[str] = "rate_shortfall"


@dataclass
class RateRowView:
    """Appendix-B rows, one gyro's voltmeter readings against the stopwatch rate (m timed rows).

    channel ("gyro_p"); rate_dps (m,) deg/s; first_rows: the rows (0-based, in timed-row order)
    from which a range change is scanned (one when the display grid located it).
    """

    channel: str
    rate_dps: np.ndarray
    first_rows: tuple = ()
    kind: ClassVar[str] = "rate_rows"

    @property
    def row(self) -> np.ndarray:
        """The timed rows' index 0 .. m-1, in the order they were taken."""
        return np.arange(np.asarray(self.rate_dps).size)


@dataclass
class VoltmeterRowView:
    """Appendix-B rows of all gyros read by one voltmeter, stacked gyro after gyro (g m rows).

    gyros ("p", "q", "r"); rate_dps (m,) deg/s; first_rows as in :class:`RateRowView`;
    scale_V_per_dps (g,): each gyro's fitted scale, so one relative gain step acts on all.
    """

    gyros: tuple
    rate_dps: np.ndarray
    first_rows: tuple = ()
    scale_V_per_dps: tuple = ()
    kind: ClassVar[str] = "voltmeter_rows"

    @property
    def row(self) -> np.ndarray:
        return np.arange(np.asarray(self.rate_dps).size)

    def tiled(self, col: np.ndarray) -> np.ndarray:
        """(g m,): ``col`` (m,) repeated for every gyro (one coefficient shared by all)."""
        return np.tile(col, len(self.gyros))

    def per_gyro(self, col: np.ndarray) -> np.ndarray:
        """(g m, g): ``col`` (m,) in block j of column j, zero elsewhere (one coefficient per gyro)."""
        n, g = np.asarray(col).size, len(self.gyros)
        out = np.zeros((g * n, g))
        for j in range(g):
            out[j * n:(j + 1) * n, j] = col
        return out


@dataclass
class ThermalView:
    """A thermal-chamber record's step table for one channel (m temperature steps).

    channel ("acc_x", "gyro_p"); unit of the channel's bias ("m/s^2", "rad/s"); branch (m,):
    +1/2 on steps reached by heating, -1/2 by cooling.
    """

    channel: str
    unit: str
    branch: np.ndarray
    kind: ClassVar[str] = "thermal_steps"


@dataclass
class MagView:
    """The magnetometer diagnosis' view: 1-s block means of the three axes, stacked x blocks, y
    blocks, z blocks (3 n_b rows), in nT.

    twin_model ("nominal": per-axis gains; "calibrated": the full linear calibration);
    field_nT (n_b, 3): the twin's reference field B_ref in the case frame; rate_nT_s (n_b, 3): its
    time derivative; R_CW (n_b, 3, 3): the attitude; time_s (n_b,); temperature_K (n_b,) or None;
    igrf_W_nT (3,): the IGRF field at the site (ENU); calibration (3, 3): the calibration A the
    candidates are linearised about (its diagonal: the gains g_j).
    """

    twin_model: str
    field_nT: np.ndarray
    rate_nT_s: np.ndarray
    R_CW: np.ndarray
    time_s: np.ndarray
    igrf_W_nT: np.ndarray
    calibration: np.ndarray
    temperature_K: np.ndarray | None = None
    kind: ClassVar[str] = "mag_blocks"

    @property
    def n_blocks(self) -> int:
        return int(np.asarray(self.time_s).size)

    def on_axis(self, j: int, col: np.ndarray) -> np.ndarray:
        """(3 n_b,): ``col`` (n_b,) in axis j's rows, zero elsewhere."""
        nb = self.n_blocks
        out = np.zeros(3 * nb)
        out[j * nb:(j + 1) * nb] = col
        return out

    @staticmethod
    def stacked(M: np.ndarray) -> np.ndarray:
        """(n_b, 3) -> (3 n_b,)."""
        return M.T.reshape(-1)

    def gains(self) -> np.ndarray:
        """g_j: the diagonal of the calibration (3,)."""
        return np.diag(self.calibration).copy()

    def predicted_nT(self) -> np.ndarray:
        """The twin's fitted field per axis, A B_ref (n_b, 3) nT."""
        return self.field_nT @ self.calibration.T

    def predicted_rate_nT_s(self) -> np.ndarray:
        """Its time derivative, A dB_ref/dt (n_b, 3) nT/s."""
        return self.rate_nT_s @ self.calibration.T

    def across_field_W(self) -> tuple[np.ndarray, np.ndarray]:
        """Two unit directions in W perpendicular to the IGRF field: u1 horizontal (a declination
        error), u2 in the magnetic meridian (an inclination error)."""
        return across_field(self.igrf_W_nT)


def across_field(B_W: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(u1, u2) perpendicular to the field B_W (ENU): u1 = up x B^ (horizontal), u2 = B^ x u1."""
    up = np.array([0.0, 0.0, 1.0])
    Bhat = np.asarray(B_W, float) / np.linalg.norm(B_W)
    u1 = np.cross(up, Bhat)
    u1 /= np.linalg.norm(u1)
    return u1, np.cross(Bhat, u1)


@dataclass
class RawChannelView:
    """One recorded channel as logged, before any filtering or segmenting (n samples).

    channel; samples (n,) in the channel's unit (V); time_s (n,); quantum_V: the ADC step q (0 when
    unknown); range_V: the converter's full scale +-range (None when unknown); alpha: the tests'
    false-alarm level over the record.
    """

    channel: str
    samples: np.ndarray
    time_s: np.ndarray
    quantum_V: float = 0.0
    range_V: float | None = None
    alpha: float = 0.01
    kind: ClassVar[str] = "raw_samples"
