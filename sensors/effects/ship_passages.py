"""Ships passing on the canals near the building (seed chapter 6): rare low-frequency wave packets.

    f_sh(t) = sum_e a d_e exp(-(t - t_e)^2 / (2 sigma^2)) sin(2 pi f_e (t - t_e) + phi_e)   [m/s^2, (n, 3)]

Passages t_e: a Poisson process of ``rate_per_hour`` in continuous time, kept where the local hour
of t_e lies in [start_h, stop_h) (boats run by day and in the evening), drawn from 6 sigma before
the record to 6 sigma after it so that packets straddle its ends; per passage a frequency
f_e ~ U(``band_hz``) (1-5 Hz: the hull's wake and the quay's response), a unit direction d_e
uniform on the sphere, phi_e ~ U(0, 2 pi); the packet's Gaussian envelope has the standard
deviation ``envelope_s`` (a passage of tens of seconds) and the peak ``peak_m_s2``. Each packet is
evaluated within 6 sigma of its centre. Stage "specific_force" (stream "ships"). Impulsive (rare
transients). Off by default.

Per-sample variance per axis (Campbell's theorem; E[d_j^2] = 1/3, the phase average of
sin^2 under the envelope = 1/2, so int exp(-u^2 / sigma^2) sin^2 du = sigma sqrt(pi) / 2):

    var = lambda peak^2 sigma sqrt(pi) / 6,   lambda = rate_per_hour / 3600 x the scheduled fraction

(the sampled sum equals the integral to exp(-(pi f_s sigma)^2)). A long window mean holds none of
it: the packet's spectrum at DC is exp(-(2 pi f_e sigma)^2 / 2) <= exp(-(2 pi 15)^2 / 2) of its peak.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from imurig.kernel import random_streams
from imurig.sensors.effects.base import ChainContext, Effect, Param
from imurig.sensors.effects.building_vibration import working_mask

random_streams.register("sensor-chain/ships", "ships passing on the canals (times, frequencies, directions)",
                        child=True)

#: a packet is evaluated within this many envelope sigmas of its centre
SUPPORT_SIGMAS = 6.0


@dataclass
class ShipPassages(Effect):
    """Poisson passages of low-frequency wave packets (m/s^2 at the IMU), day and evening."""

    enabled: bool = False
    rate_per_hour: float = 2.0
    peak_m_s2: float = 5e-3
    band_hz: tuple = (1.0, 5.0)
    envelope_s: float = 15.0
    start_h: float = 6.0
    stop_h: float = 22.0

    name: ClassVar[str] = "ship_passages"
    stage: ClassVar[str] = "specific_force"
    stream: ClassVar[str] = "ships"
    impulsive: ClassVar[bool] = True
    physics: ClassVar[str] = "ships passing on the nearby canals shake the building with slow wave packets"
    seed_section: ClassVar[str] = "chapter 6"
    seed_says: ClassVar[str] = ("'vibrations caused by the air conditioning for example or even ships which are "
                                "driving past close-by canals were able to be revealed as a source of errors'")
    params: ClassVar[tuple] = (Param("rate_per_hour", "1/h", note="no seed value"),
                               Param("peak_m_s2", "m/s^2", note="no seed value; the packet's peak"),
                               Param("band_hz", "Hz", note="assumed 1-5 Hz"),
                               Param("envelope_s", "s", note="assumed: a passage of tens of seconds"),
                               Param("start_h", "h", note="assumed"), Param("stop_h", "h", note="assumed"))

    def passages(self, t0: float, t1: float, hour0: float, rng: np.random.Generator) -> dict[str, np.ndarray]:
        """The passages near the record [t0, t1] s (hour0: the local hour at t0): times t_e (s),
        frequencies (Hz), directions (k, 3), phases (rad) (module doc)."""
        pad = SUPPORT_SIGMAS * self.envelope_s
        span = (t1 - t0) + 2 * pad
        k = rng.poisson(self.rate_per_hour / 3600.0 * span)
        t_e = np.sort(t0 - pad + rng.uniform(0.0, span, k))
        freq = rng.uniform(*self.band_hz, k)
        d = rng.normal(size=(k, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        phase = rng.uniform(0, 2 * np.pi, k)
        keep = working_mask((hour0 + (t_e - t0) / 3600.0) % 24.0, self.start_h, self.stop_h)
        return {"time_s": t_e[keep], "frequency_hz": freq[keep], "direction": d[keep], "phase_rad": phase[keep]}

    def specific_force(self, time_s, hour0: float, rng) -> np.ndarray:
        """f_sh (n, 3) m/s^2 (module doc)."""
        t = np.asarray(time_s, float)
        out = np.zeros((t.size, 3))
        p = self.passages(float(t[0]), float(t[-1]), hour0, rng)
        half = SUPPORT_SIGMAS * self.envelope_s
        for te, fe, d, ph in zip(p["time_s"], p["frequency_hz"], p["direction"], p["phase_rad"]):
            i0, i1 = np.searchsorted(t, [te - half, te + half])
            u = t[i0:i1] - te
            out[i0:i1] += (self.peak_m_s2 * np.exp(-0.5 * (u / self.envelope_s) ** 2)
                           * np.sin(2 * np.pi * fe * u + ph))[:, None] * d
        return out

    def inject(self, f: np.ndarray, ctx: ChainContext, rng: np.random.Generator) -> np.ndarray:
        if not self.enabled or ctx.hour_of_day is None:
            return f
        return f + self.specific_force(ctx.time_s, float(np.asarray(ctx.hour_of_day)[0]), rng)

    def noise_variance(self, ctx: ChainContext) -> float:
        """Per-axis variance (m/s^2)^2 of one sample (module doc); 0 for a long window mean."""
        if not self.enabled or ctx.window_samples > 1:
            return 0.0
        lam = self.rate_per_hour / 3600.0 * ctx.working_fraction(self.start_h, self.stop_h)
        return float(lam * self.peak_m_s2**2 * self.envelope_s * np.sqrt(np.pi) / 6.0)

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        """{rate_per_hour, peak_m_s2, envelope_s} of the injected passages (0 rate and peak without)."""
        e = truth["chain"].get("effects", {}).get(self.name)
        if not e or not e["enabled"]:
            return {"rate_per_hour": 0.0, "peak_m_s2": 0.0, "envelope_s": float(self.envelope_s)}
        return {k: float(e[k]) for k in ("rate_per_hour", "peak_m_s2", "envelope_s")}
