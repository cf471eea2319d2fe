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
