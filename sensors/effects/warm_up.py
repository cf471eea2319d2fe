"""The accelerometers' warm-up transient: after turn-on the bias settles exponentially (Q-Flex
datasheet, seed appendix A.1; the lab warmed the IMU up for 15 min, seed Tab. 4.7).

    b_j(t) = db_j exp(-(t_rec + t_start) / tau)                                 [m/s^2, (n, 3)]

t_rec = t - t_0 the time into the record, t_start (``start_after_turn_on_s``) the time from turn-on
to the record's first sample. Datasheet: "within 100 ug of its steady-state value in no more than
4 minutes after turn on", so |db_j| exp(-240 s / tau) <= 100 ug (:meth:`WarmUp.meets_datasheet`,
:func:`max_delta_bias`); the datasheet bounds the pair (db, tau), not each. With the seed's 15 min
warm-up the remaining offset is db exp(-900 / tau) <= 100 ug exp(-660 / tau).

Stage "specific_force" (a bias ahead of the sensor's scale factor, as the triad's own bias). A
deterministic transient: no noise variance of its own. Off by default (db = 0).
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from imurig.kernel.units import MICRO_G
from imurig.sensors.effects.base import ChainContext, Effect, Param

#: the datasheet's warm-up bound: within 100 ug of steady state 240 s after turn-on
BOUND_M_S2 = 100.0 * MICRO_G
BOUND_TIME_S = 240.0
#: the seed's warm-up before acquisition (Tab. 4.7, 15 min)
SEED_WARM_UP_S = 900.0


def max_delta_bias(tau_s: float) -> float:
    """The largest |db| (m/s^2) the datasheet allows for a time constant tau: 100 ug exp(240 s / tau)."""
    return BOUND_M_S2 * float(np.exp(BOUND_TIME_S / tau_s))


@dataclass
class WarmUp(Effect):
    """Turn-on bias step db (3,) m/s^2 decaying with ``tau_s``; the record starts ``start_after_turn_on_s`` after."""

    delta_bias_m_s2: np.ndarray = field(default_factory=lambda: np.zeros(3))
    tau_s: float = 120.0
    start_after_turn_on_s: float = SEED_WARM_UP_S

    name: ClassVar[str] = "warm_up"
    stage: ClassVar[str] = "specific_force"
    physics: ClassVar[str] = "the accelerometer bias settles exponentially after turn-on (warm-up transient)"
    seed_section: ClassVar[str] = "A.1 (Q-Flex datasheet, Warm-up Time); 4.8 Tab. 4.7"
    seed_says: ClassVar[str] = ("'The output of the accelerometer is within 100 ug of its steady-state value in no "
                                "more than 4 minutes after turn on'; 'Warming up the IMU 15 min'")
    params: ClassVar[tuple] = (
        Param("delta_bias_m_s2", "m/s^2", datasheet=BOUND_M_S2,
              note="bound on |db| exp(-240 s / tau), not on db alone"),
        Param("tau_s", "s", note="not in the datasheet; assumed 120 s (then |db| <= 100 ug e^2 = 739 ug)"),
        Param("start_after_turn_on_s", "s", seed=SEED_WARM_UP_S, note="the seed warmed up 15 min"))

    def __post_init__(self):
        self.delta_bias_m_s2 = np.broadcast_to(np.asarray(self.delta_bias_m_s2, float), (3,)).copy()
        if not self.tau_s > 0:
            raise ValueError(f"the warm-up time constant must be > 0 s, got {self.tau_s}")

    @classmethod
    def from_datasheet(cls, tau_s: float = 120.0, rng: np.random.Generator | None = None, **kw) -> "WarmUp":
        """db at the datasheet's bound for ``tau_s`` on every axis; with ``rng`` uniform within +- it."""
        b = max_delta_bias(tau_s)
        db = np.full(3, b) if rng is None else rng.uniform(-b, b, 3)
        return cls(delta_bias_m_s2=db, tau_s=tau_s, **kw)

    def bias(self, time_since_turn_on_s) -> np.ndarray:
        """b (n, 3) m/s^2 at the times since turn-on (n,) s."""
        t = np.asarray(time_since_turn_on_s, float)
        return self.delta_bias_m_s2 * np.exp(-t / self.tau_s)[..., None]

    def meets_datasheet(self) -> bool:
        """|db_j| exp(-240 s / tau) <= 100 ug on every axis."""
        return bool(np.all(np.abs(self.bias(BOUND_TIME_S)) <= BOUND_M_S2 * (1 + 1e-12)))

    def inject(self, f: np.ndarray, ctx: ChainContext, rng=None) -> np.ndarray:
        """f + b(t_rec + t_start) (module doc)."""
        if not np.any(self.delta_bias_m_s2):
            return f
        t = np.asarray(ctx.time_s, float)
        return f + self.bias(t - t[0] + self.start_after_turn_on_s)

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        """{offset_m_s2: db_j exp(-t_start / tau), tau_s}: the transient's size at the record's first
        sample on accelerometer ``channel`` and its time constant (0 and tau without the effect)."""
        e = truth["chain"].get("effects", {}).get(self.name)
        if not e:
            return {"offset_m_s2": 0.0, "tau_s": float(self.tau_s)}
        j = "xyz".index(channel[-1]) if channel else 0
        return {"offset_m_s2": float(e["delta_bias_m_s2"][j] * np.exp(-e["start_after_turn_on_s"] / e["tau_s"])),
                "tau_s": float(e["tau_s"])}
