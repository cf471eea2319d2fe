"""The effect contract: one physical effect, one object, everything the project knows about it.

An :class:`Effect` is a small dataclass of SI parameters with class-level facts and up to four
behaviours, each optional:

    inject(x, ctx, rng) -> x'       the sensor chain: add the effect to the signal of its ``stage``
    candidates(view)    -> [Candidate]   the diagnosis: regression columns with any scanned
                                     nonlinear parameter, for one diagnosis view
    test(view)          -> {statistics, "finding": ...}   the diagnosis where no regression
                                     serves (a spectral peak, spikes): the effect's own test statistic
    noise_variance(ctx) -> float    the noise covariance: per-sample variance the effect adds to
                                     one channel, in that channel's unit (bounds, budgets, priors)
    fitted(truth, channel) -> {param: value}   the map from injected truth (the recording's
                                     ``truth`` dict) to the parameter the diagnosis fits on ``channel``

and the class-level facts: ``name`` (the one name used by the truth, the diagnosis findings and
the filter states), ``stage``, ``physics`` (plain words), ``seed_section`` and ``seed_says``
(the sentence of the seed that supports it), ``params`` (unit, datasheet and seed priors),
``stream`` (the name of the effect's random stream, ``child_rng(seed, stream)``, the same for
the life of the project so that a seed reproduces its data) and ``impulsive`` (rare non-Gaussian
transients that the medians reject: the Gaussian bounds leave them out).

Effects of the "sensor" stage are parameters of the sensor model itself (the Q-Flex triad's
misalignment, nonlinearity, temperature coefficients): the triad injects them; the effect object
owns their diagnosis and truth map, and its ``inject`` applies the parameter to a signal (tests).
Effects of the "analog" stage act per line: ``lines(names, ctx)`` says which analog lines they
touch and ``line_stream(line)`` names each line's random stream.

The chain composes a list of effects per stage, as dm_control composes corruptors
``corruptor(value, random_state)``; the diagnosis asks the same objects for candidates; the
Cramér-Rao bounds and Monte-Carlo budgets ask them for ``noise_variance``. A new effect is one
new module of :mod:`imurig.sensors.effects` registered in its ``LIBRARY``. Effect modules import
the kernel, :mod:`imurig.sensors.noise` and this module only (the sensor models import them).
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
    channel name, so an effect can state its size in the sensor's unit; imu_lines: the analog
    lines that leave the IMU (they cross the slip rings; the rig's own lines do not);
    window_samples: for ``noise_variance``, the observation is the mean of this many consecutive
    logged samples (1: one sample; more: the long-window limit, the noise's power at DC / N).
    """

    time_s: np.ndarray
    sample_rate_hz: float
    hour_of_day: np.ndarray | None = None
    truth_signals: Mapping[str, np.ndarray] = field(default_factory=dict)
    adc: object | None = None
    sensitivity_V_per_SI: Mapping[str, float] = field(default_factory=dict)
    imu_lines: tuple[str, ...] = ()
    window_samples: int = 1

    def working_fraction(self, start_h: float, stop_h: float) -> float:
        """The fraction of the samples whose local hour lies in [start_h, stop_h) (1 without a clock)."""
        if self.hour_of_day is None:
            return 1.0
        h = np.asarray(self.hour_of_day, float)
        return float(np.mean((h >= start_h) & (h < stop_h))) if h.size else 0.0


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
class PositionView:
    """The diagnosis' view of a static record, one row per position (m rows), for one channel.

    readings: indicated specific force per axis name ("ax", "ay", "az"), (m,) m/s^2, through the
    nominal sensitivities; channel_median(name): the per-position level of any recorded channel
    (V; the position statistic, for a temperature channel its clipped mean), or None if it is not
    recorded; scan_list: the ADC's scan order; temperature_K: the sensor's temperature per
    position (K) or None; model_terms: the terms the twin already has;
    reference: the twin's reference specific force on ``axis`` per position (m/s^2) or None.
    crosstalk_sources: where the scan order is unknown, the recorded channels that may leak into
    this one (each is tested, the choice among them counted in the threshold).
    """

    channel: str
    axis: str
    readings: Mapping[str, np.ndarray]
    channel_median: Callable[[str], np.ndarray | None]
    scan_list: tuple[str, ...] = ()
    temperature_K: np.ndarray | None = None
    model_terms: frozenset = frozenset()
    #: the twin's reference on this view's axis per position (m/s^2), or None (clipping candidates need it)
    reference: np.ndarray | None = None
    crosstalk_sources: tuple[str, ...] = ()
    kind: ClassVar[str] = "positions"


@dataclass
class ScatterView:
    """The diagnosis' view of the samples inside each static position, for one channel.

    samples (n,) V: the channel's record; positions: one slice of ``samples`` per position (m);
    sample_rate_hz; hour_of_day (m,): local hours at each position's middle; sensitivity_V_per_SI:
    the channel's nominal sensitivity (V per m/s^2 ...), to state sizes in SI, or None;
    quantum_V: the ADC step q of the recorded channel (V; 0 when unknown): no noise level a test
    uses is below q / sqrt(12).
    """

    channel: str
    samples: np.ndarray
    positions: list
    sample_rate_hz: float
    hour_of_day: np.ndarray
    sensitivity_V_per_SI: float | None = None
    quantum_V: float = 0.0
    kind: ClassVar[str] = "position_scatter"

    def centred(self, i: int) -> np.ndarray:
        """Position i's samples about their median (V)."""
        x = self.samples[self.positions[i]]
        return x - np.median(x)


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
    #: the diagnosis views this effect offers candidates or a test for (PositionView.kind, ...)
    views: ClassVar[tuple[str, ...]] = ()
    #: where the diagnosis offers this effect's candidates among the others (lower first; ties by name)
    order: ClassVar[int] = 100
    #: the name of the effect's random stream in the chain (child_rng(seed, stream))
    stream: ClassVar[str] = ""
    #: rare, non-Gaussian transients (the medians reject most): the Gaussian bounds leave them out
    impulsive: ClassVar[bool] = False

    def inject(self, x: np.ndarray, ctx: ChainContext, rng: np.random.Generator) -> np.ndarray:
        """The signal with the effect added (default: unchanged)."""
        return x

    def candidates(self, view) -> list[Candidate]:
        """Candidate columns for the diagnosis view ``view`` (default: none)."""
        return []

    def test(self, view) -> dict:
        """The effect's own test on ``view`` (default: none): statistics to report, with the
        finding under "finding" when the test fires."""
        return {}

    def lines(self, names, ctx: ChainContext) -> list[str]:
        """Analog stage: the lines of ``names`` the effect acts on (default: none)."""
        return []

    def line_stream(self, line: str) -> str:
        """Analog stage: the random stream of ``line`` (default: the effect's one stream)."""
        return self.stream

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


def recording_truth(rec) -> dict:
    """The truth mapping the effects' ``fitted`` read, from a Recording: its ``truth`` dict plus,
    under "conditions", what the measurement itself fixed: the accelerometers' mean temperature
    over the record (K, truth signal T_imu, or T_acc in a chamber) and the nominal sensitivities
    the lab converts volts with (V per m/s^2), and the site the rig stood at (meta "site")."""
    ts = rec.truth_signals
    T = ts["T_imu"] if "T_imu" in ts else ts.get("T_acc")
    cond = {"mean_temperature_K": None if T is None else float(np.mean(T)),
            "acc_nominal_sensitivity_V_per_m_s2": rec.meta.get("acc_nominal_sensitivity_V_per_m_s2"),
            "site": rec.meta.get("site")}
    return {**(rec.truth or {}), "conditions": cond}
