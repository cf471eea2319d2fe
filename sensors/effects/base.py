"""The effect contract: one physical effect, one object, everything the project knows about it.

An :class:`Effect` is a small dataclass of SI parameters with class-level facts and up to four
behaviours, each optional:

    inject(x, ctx, rng) -> x'       the sensor chain: add the effect to the signal of its ``stage``
    candidates(view)    -> [Candidate]   the diagnosis: regression columns (or a test statistic)
                                     with any scanned nonlinear parameter, for one diagnosis view
    noise_variance(ctx) -> float    the noise covariance: per-sample variance the effect adds to
                                     one channel, in that channel's unit (bounds, budgets, priors)
    fitted(truth, channel) -> {param: value}   the map from injected truth (the recording's
                                     ``truth`` dict) to the parameter the diagnosis fits on ``channel``

and the class-level facts: ``name`` (the one name used by the truth, the diagnosis findings and
the filter states), ``stage``, ``physics`` (plain words), ``seed_section`` and ``seed_says``
(the sentence of the seed that supports it), and ``params`` (unit, datasheet and seed priors).

The chain composes a list of effects per stage, as dm_control composes corruptors
``corruptor(value, random_state)``; the diagnosis asks the same objects for candidates; the
Cramér-Rao bounds and Monte-Carlo budgets ask them for ``noise_variance``. A new effect is one
new module of :mod:`imurig.sensors.effects` registered in its ``LIBRARY``.
"""
from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields
from typing import ClassVar

import numpy as np

#: where in the chain an effect acts, in chain order
STAGES = ("rig",              # the rig's physics or environment in its truth, before the chain (table rate,
                              # the Earth's rotation, the local field, event times)
          "specific_force",   # (n, 3) m/s^2 at the IMU, added to the rig's f_C before the sensors
          "analog",           # (n,) V on one analog line, after the sensor physics
          "conversion",       # inside the multiplexed ADC scan: one slot's input u_j (V)
          "digital",          # (n,) V after the ADC
          "events",           # event time tags (s)
          "sensor")           # a parameter of the sensor model itself (bias, scale, axes, temperature)


@dataclass(frozen=True)
class Param:
    """One parameter of an effect: SI unit, the datasheet's 1-sigma (or bound) and the seed's value."""

    name: str
    unit: str
    datasheet: float | None = None
    seed: float | None = None
    note: str = ""


@dataclass
class Candidate:
    """A named physical mechanism for the diagnosis, linear in its amplitude(s) for a fixed scan value.

    The diagnosis observable is y = X0 beta0 + C(theta) gamma + e: ``columns(theta)`` gives C (m, k)
    for each value theta of the scanned nonlinear parameter ``scan`` (a lag, a change point ...).
    """

    name: str
    physics: str                                     # what was left out, in words
    param_names: tuple[str, ...]
    columns: Callable[[object], np.ndarray]          # theta -> (m, k)
    scan: tuple = (None,)                            # values of the nonlinear parameter
    scan_name: str | None = None

    def design(self, theta) -> np.ndarray:
        c = np.asarray(self.columns(theta), float)
        return c[:, None] if c.ndim == 1 else c


@dataclass
class ChainContext:
    """What an effect may know about the chain when it injects or states its noise.

    time_s (n,) s; sample_rate_hz; hour_of_day (n,) local hours (working-hours schedules);
    truth_signals: the rig's truth (f_C_*, w_C_*, spin_angle ...); adc: the converter settings
    (:class:`imurig.sensors.adc.DAQ6036E`) or None; sensitivity_V_per_SI: nominal sensitivity per
    channel name, so an effect can state its size in the sensor's unit.
    """

    time_s: np.ndarray
    sample_rate_hz: float
    hour_of_day: np.ndarray | None = None
    truth_signals: Mapping[str, np.ndarray] = field(default_factory=dict)
    adc: object | None = None
    sensitivity_V_per_SI: Mapping[str, float] = field(default_factory=dict)


@dataclass
class ScanSlot:
    """One slot of the multiplexed ADC scan, for conversion-stage effects.

    index: the slot j in the scan list; mux_frequency_hz: f_mux (Hz); previous_V (n,): the input
    of the previously converted slot (for slot 0, the last slot of the previous scan); slope_V_s:
    the noise-free signal's time derivative (n,) V/s, or None.
    """

    index: int
    mux_frequency_hz: float
    previous_V: np.ndarray | None = None
    slope_V_s: np.ndarray | None = None


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
    samples (the white part; the slow ripple removed); alpha: the test's threshold p.
    """

    channel: str
    angle_rad: np.ndarray
    residual_V: np.ndarray
    alpha: float = 0.01
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
class PositionView:
    """The diagnosis' view of a static record, one row per position (m rows), for one channel.

    readings: indicated specific force per axis name ("ax", "ay", "az"), (m,) m/s^2, through the
    nominal sensitivities; channel_median(name): the per-position median of any recorded channel
    (V), or None if it is not recorded; scan_list: the ADC's scan order; temperature_K: the
    sensor's temperature per position (K) or None; model_terms: the terms the twin already has.
    """

    channel: str
    axis: str
    readings: Mapping[str, np.ndarray]
    channel_median: Callable[[str], np.ndarray | None]
    scan_list: tuple[str, ...] = ()
    temperature_K: np.ndarray | None = None
    model_terms: frozenset = frozenset()
    kind: ClassVar[str] = "positions"


class Effect:
    """Base of every effect (see the module docstring for the contract).

    Subclasses are dataclasses with SI fields; ``enabled`` switches the injection off without
    changing any other stage's random stream.
    """

    name: ClassVar[str] = ""
    stage: ClassVar[str] = "analog"
    physics: ClassVar[str] = ""
    seed_section: ClassVar[str] = ""
    seed_says: ClassVar[str] = ""
    params: ClassVar[tuple[Param, ...]] = ()
    #: the diagnosis views this effect offers candidates for (PositionView.kind, ...)
    views: ClassVar[tuple[str, ...]] = ()

    def inject(self, x: np.ndarray, ctx: ChainContext, rng: np.random.Generator) -> np.ndarray:
        """The signal with the effect added (default: unchanged)."""
        return x

    def candidates(self, view) -> list[Candidate]:
        """Candidate columns for the diagnosis view ``view`` (default: none)."""
        return []

    def noise_variance(self, ctx: ChainContext) -> float:
        """Per-sample variance the effect adds to a channel, in the channel's unit squared (default 0)."""
        return 0.0

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        """The parameters the diagnosis fits on ``channel``, implied by the injected truth (default: none)."""
        return {}

    #: the name a diagnosis reports the effect's findings under, where it differs from ``name``:
    #: sensors share mechanisms (the fluxgate's and the accelerometers' temperature drift), so the
    #: library's ``name`` carries the sensor to stay unique while the finding keeps the mechanism's
    #: name on the sensor's channel
    finding: ClassVar[str] = ""

    @classmethod
    def finding_name(cls) -> str:
        """The effect's name in a diagnosis' findings (``finding`` or, by default, ``name``)."""
        return cls.finding or cls.name

    def settings(self) -> dict:
        """The effect's parameters as plain JSON-able values (the recording's truth)."""
        out = {}
        for f in fields(self):  # type: ignore[arg-type]
            v = getattr(self, f.name)
            out[f.name] = v.tolist() if isinstance(v, np.ndarray) else (list(v) if isinstance(v, tuple) else v)
        return out

    @classmethod
    def describe(cls) -> dict:
        """The effect in words, for reports and the diagnosis: name, physics, seed section and sentence."""
        return {"effect": cls.name, "stage": cls.stage, "physics": cls.physics, "seed_section": cls.seed_section,
                "seed_says": cls.seed_says,
                "parameters": [{"name": p.name, "unit": p.unit, "datasheet": p.datasheet, "seed": p.seed,
                                "note": p.note} for p in cls.params]}
