"""A loose cable or connector: rectangular voltage spikes on one analog line (seed 4.3.3, Fig. 4.12).

    v(t) = sum_e a_e rect((t - t_e) / L_e)          [V],  on ``channel`` only

Spike starts: a Bernoulli draw per sample with probability rate / f_s; lengths L_e =
max(1, floor(U(min, max) f_s)) samples; amplitudes a_e ~ N(0, amplitude). Stage "analog" (stream
"cable"). Impulsive: the position medians reject it and the Gaussian bounds leave it out.

Variance on its line (shot noise of rectangular pulses, p = rate / f_s):
per sample p amplitude^2 E[L]; mean of N samples p amplitude^2 E[L^2] / N (long-window limit).

Diagnosis (within-position scatter), on the quantised scale: a spike is a sample farther than

    8 s + q / 2,   s = max(1.4826 MAD_position, median_positions(1.4826 MAD), q / sqrt(12))

from its position's median (q: the ADC step, ``ScatterView.quantum_V``). When the step exceeds
the noise the MAD is 0 (most samples share the median code); the floor q / sqrt(12) (the rounding
error's own spread) and the half step keep every sample of a clean quantised record, which lies
within a code or two of the median, inside. Three or more spikes name the effect
(P(|z| > 8) ~ 1e-15 per Gaussian sample).
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from imurig.sensors.effects.base import ChainContext, Effect, Param, ScatterView


@dataclass
class LooseCable(Effect):
    """A faulty connector on ``channel``: rectangular spikes (V)."""

    enabled: bool = False
    channel: str = "acc_y"
    rate_hz: float = 0.5
    amplitude_V: float = 0.3
    min_duration_s: float = 0.005
    max_duration_s: float = 0.05

    name: ClassVar[str] = "cable_fault_spikes"
    stage: ClassVar[str] = "analog"
    stream: ClassVar[str] = "cable"
    impulsive: ClassVar[bool] = True
    physics: ClassVar[str] = "a loose cable or connector spikes one channel"
    seed_section: ClassVar[str] = "4.3.3, Fig. 4.12"
    seed_says: ClassVar[str] = ("moving the cables, 'a peak in channel two could be seen, which is the channel of the "
                                "output of the y-accelerometer'; the junction box's connector was re-soldered")
    params: ClassVar[tuple] = (Param("rate_hz", "1/s"), Param("amplitude_V", "V"))
    views: ClassVar[tuple] = ("position_scatter",)
    finding_key: ClassVar[str] = "finding_spikes"
    #: a spike lies this many robust sigma from its position's median; this many name the effect
    spike_sigma: ClassVar[float] = 8.0
    min_spikes: ClassVar[int] = 3

    def voltage(self, n: int, fs: float, rng) -> np.ndarray:
        """v (n,) V (module doc)."""
        out = np.zeros(n)
        if not self.enabled:
            return out
        starts = np.flatnonzero(rng.random(n) < self.rate_hz / fs)
        if starts.size == 0:
            return out
        lengths = np.maximum(1, (rng.uniform(self.min_duration_s, self.max_duration_s, starts.size) * fs)
                             .astype(int))
        amps = rng.normal(0, self.amplitude_V, starts.size)
        delta = np.zeros(n + 1)
        np.add.at(delta, starts, amps)
        np.add.at(delta, np.minimum(starts + lengths, n), -amps)
        return np.cumsum(delta)[:n]

    def lines(self, names, ctx: ChainContext | None = None) -> list[str]:
        if not self.enabled:
            return []
        if self.channel not in names:
            raise ValueError(f"loose cable on '{self.channel}', which is not an analog line; "
                             f"choose one of {sorted(names)}")
        return [self.channel]

    def inject(self, v: np.ndarray, ctx: ChainContext, rng: np.random.Generator) -> np.ndarray:
        if not self.enabled:
            return v
        return v + self.voltage(v.size, ctx.sample_rate_hz, rng)

    def length_moments(self, fs: float) -> tuple[float, float]:
        """(E[L], E[L^2]) of the spike length in samples, L = max(1, floor(U fs)), U ~ U(min, max)."""
        lo, hi = self.min_duration_s * fs, self.max_duration_s * fs
        if hi <= lo:
            L = max(1, int(lo))
            return float(L), float(L * L)
        edges = np.arange(np.floor(lo), np.floor(hi) + 1)          # L = k on [k, k + 1) within [lo, hi)
        w = (np.minimum(edges + 1, hi) - np.maximum(edges, lo)) / (hi - lo)
        L = np.maximum(edges, 1)
        return float(w @ L), float(w @ L**2)

    def noise_variance(self, ctx: ChainContext) -> float:
        """Variance (V^2) on its line: one sample, or a long window mean (module doc)."""
        if not self.enabled:
            return 0.0
        fs = ctx.sample_rate_hz
        m1, m2 = self.length_moments(fs)
        p = self.rate_hz / fs
        if ctx.window_samples > 1:
            return p * self.amplitude_V**2 * m2 / ctx.window_samples
        return p * self.amplitude_V**2 * m1

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        """{rate_hz}: the spike rate on ``channel`` (0 on the other lines or with the cable sound)."""
        c = truth["chain"]["cable"]
        on = bool(c["enabled"]) and (channel is None or channel == c["channel"])
        return {"rate_hz": float(c["rate_hz"]) if on else 0.0}

    def test(self, view: ScatterView) -> dict:
        """The spike count (module doc); 'finding' with three or more."""
        sl, x = view.positions, view.samples
        q = float(getattr(view, "quantum_V", 0.0) or 0.0)
        robust = np.array([1.4826 * np.median(np.abs(x[s] - np.median(x[s]))) for s in sl])
        floor = max(float(np.median(robust)), q / 12.0 ** 0.5)
        flags = [np.abs(x[s] - np.median(x[s])) > self.spike_sigma * max(r, floor) + 0.5 * q for s, r in zip(sl, robust)]
        spikes = np.array([int(np.sum(f)) for f in flags])
        # events: runs of consecutive flagged samples (one contact fault may last a few samples)
        events = int(sum(np.count_nonzero(np.diff(np.concatenate(([0], f.astype(np.int8)))) == 1) for f in flags))
        duration = sum(s.stop - s.start for s in sl) / float(view.sample_rate_hz)
        out = {"robust_sigma_V": float(floor), "adc_step_V": q, "spikes_total": int(spikes.sum()),
               "positions_with_spikes": int(np.sum(spikes > 0))}
        if spikes.sum() >= self.min_spikes:
            # the events' rate over the positions' time, a Poisson count: SE = sqrt(events) / duration
            rate = events / duration
            out["finding"] = {"effect": self.name,
                              "physics": f"a loose cable or connector spikes '{view.channel}' (seed 4.3.3)",
                              "spikes": int(spikes.sum()), "positions": int(np.sum(spikes > 0)),
                              "parameters": [{"name": "rate_hz", "estimate": rate,
                                              "std_error": np.sqrt(max(events, 1)) / duration},
                                             {"name": "events", "estimate": float(events), "std_error": None},
                                             {"name": "samples_flagged", "estimate": float(spikes.sum()),
                                              "std_error": None}]}
        return out
