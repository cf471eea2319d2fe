"""Quantisation (and jitter) of the round timer (seed 4.4.2-4.4.3).

An event timer tags each index-pulse edge t_k:

    t_k,meas = q round((t_k + d + e_k) / q),   e_k ~ N(0, jitter^2)                 [s]

q: the resolution, d: a constant latency (irrelevant to round times), e: the jitter. Per edge
the error is (nearly) uniform on [-q/2, q/2] plus the jitter: variance q^2/12 + jitter^2; a
round time is the difference of two edges: q^2/6 + 2 jitter^2. A stopwatch that rounds the round
time itself (appendix B) adds q^2/12. Stage "events": :class:`imurig.sensors.timers.EventTimer`
measures through :meth:`TimerQuantisation.inject`.

Diagnosis (appendix-B rows): the twin times rounds exactly; a timer error sigma_T on each round
time T_i adds sigma_T^2 / T_i^2 to the variance of the relative rate mismatch, growing with the
rate^2. It is found by a likelihood-ratio test of that variance term
(:func:`imurig.diagnose.rate_table.timer_quantisation_test`), not by a regression column.
Truth map: sigma_T = q / sqrt(12) for a stopwatch's rounded round time (truth["timer"]), or
sqrt(q^2/6 + 2 jitter^2) for the recorded event timer ``channel`` (truth["chain"]["timers"]).
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from imurig.sensors.effects.base import ChainContext, Effect, Param


@dataclass
class TimerQuantisation(Effect):
    """An event timer of resolution ``resolution_s`` (s), jitter ``jitter_s`` (s, 1 sigma) and latency ``latency_s`` (s)."""

    resolution_s: float = 1e-6
    jitter_s: float = 0.0
    latency_s: float = 0.0

    name: ClassVar[str] = "timer_quantisation"
    order: ClassVar[int] = 206
    stage: ClassVar[str] = "events"
    physics: ClassVar[str] = ("the round times carry a timer error (resolution of the stopwatch or of the pulse "
                              "timing) that a twin timing rounds exactly leaves out: rate scatter growing with the "
                              "rate")
    seed_section: ClassVar[str] = "4.4.2-4.4.3"
    seed_says: ClassVar[str] = ("the achievable accuracy depends on the time facility; the round-time resolution "
                                "limits the high rates")
    params: ClassVar[tuple] = (Param("sigma_T_s", "s", note="the round-time error, 1 sigma"),
                               Param("resolution_s", "s", seed=1e-6, note="the HP stopwatch: 1 us; the ADC: 1 ms"))

    def inject(self, t_s: np.ndarray, ctx=None, rng: np.random.Generator | None = None) -> np.ndarray:
        """The measured time tags (s) of the true event times ``t_s`` (s); ``rng`` draws the jitter."""
        t = np.asarray(t_s, float) + self.latency_s
        if self.jitter_s > 0:
            t = t + self.jitter_s * rng.standard_normal(t.shape)
        return np.round(t / self.resolution_s) * self.resolution_s

    def noise_variance(self, ctx: ChainContext | None = None) -> float:
        """Per time tag: q^2/12 + jitter^2 (s^2)."""
        return self.resolution_s**2 / 12.0 + self.jitter_s**2

    def round_time_variance_s2(self) -> float:
        """Per round time, the difference of two tags: q^2/6 + 2 jitter^2 (s^2)."""
        return 2.0 * self.noise_variance()

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        """{sigma_T_s}: a stopwatch's rounded round times (truth["timer"]["resolution_s"]: q / sqrt(12)),
        else the event timer ``channel`` of the chain (truth["chain"]["timers"][channel])."""
        if "timer" in truth:
            return {"sigma_T_s": truth["timer"]["resolution_s"] / math.sqrt(12)}
        tm = truth["chain"]["timers"][channel]
        eff = type(self)(resolution_s=tm["resolution_s"], jitter_s=tm.get("jitter_s", 0.0))
        return {"sigma_T_s": math.sqrt(eff.round_time_variance_s2())}
