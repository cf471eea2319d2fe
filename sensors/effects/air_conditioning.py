"""Building vibration from the lab's air conditioning (seed 4.3.3 and chapter 6), on in working hours.

    f_ac(t) = w(t) c(t) [ n_bb(t) + A d sin(2 pi f_bp t + phi) ]                 [m/s^2, (n, 3)]

w(t) = 1 while the local hour lies in [work_start_h, work_stop_h) (the seed: shut off for the
evening runs after 6 pm); c(t) = 1 while the compressor runs: it cycles with period P and duty D,
c(t) = [((t - t_0 + u) mod P) < D P], u ~ U(0, P) (an unknown phase at the record's start);
n_bb: airflow and compressor turbulence, Gaussian per axis, band-limited to ``band_hz``, rms
``broadband_rms_m_s2`` per axis; the fan's blade-pass tone of amplitude A = sqrt(2) x
``blade_pass_rms_m_s2`` along a fixed unit direction d (uniform on the sphere), phase phi ~ U(0, 2 pi).
As for the pump, a component at or above f_s / 2 is averaged out by a slow (averaging) logger and
left out. Stage "specific_force" (stream "aircon"). Off by default (``enabled`` False).

Per-sample variance per axis, expected over the compressor's phase and the tone's direction
(E[c] = D, E[d_j^2] = 1/3), times the working-hours fraction:

    var = D (rms_bb^2 [f_s/2 > band_hi] + rms_bp^2 / 3 [f_bp < f_s/2])             [(m/s^2)^2]

Summed over the three axes the tone's part is exactly rms_bp^2 whatever d. A long window mean keeps
none of it (neither component has power at DC; the compressor's gating leaks a negligible share).
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from imurig.kernel import random_streams
from imurig.sensors.effects.base import ChainContext, Effect, Param
from imurig.sensors.effects.building_vibration import working_mask
from imurig.sensors.noise import band_noise

random_streams.register("sensor-chain/aircon", "the air conditioning's compressor cycling, airflow and fan tone",
                        child=True)


@dataclass
class AirConditioningVibration(Effect):
    """Air-conditioning vibration (m/s^2 at the IMU): compressor cycling, broadband airflow, blade-pass tone."""

    enabled: bool = False
    broadband_rms_m_s2: float = 5e-3
    band_hz: tuple = (2.0, 30.0)
    blade_pass_hz: float = 37.5
    blade_pass_rms_m_s2: float = 2e-3
    cycle_period_s: float = 900.0
    duty: float = 0.6
    work_start_h: float = 7.0
    work_stop_h: float = 18.0

    name: ClassVar[str] = "air_conditioning_vibration"
    stage: ClassVar[str] = "specific_force"
    stream: ClassVar[str] = "aircon"
    physics: ClassVar[str] = ("the air conditioning shakes the building while its compressor runs: broadband airflow "
                              "vibration and the fan's blade-pass tone, by day")
    seed_section: ClassVar[str] = "4.3.3; chapter 6"
    seed_says: ClassVar[str] = ("the final runs were made 'between 6pm and 10pm, where less staff was present, the "
                                "pump, the transfomer, and the air conditioning were shut off'; 'vibrations caused by "
                                "the air conditioning' were revealed as a source of errors")
    params: ClassVar[tuple] = (
        Param("broadband_rms_m_s2", "m/s^2", note="no seed value; per axis while the compressor runs"),
        Param("blade_pass_hz", "Hz", note="assumed: a 750 rpm fan of 3 blades"),
        Param("blade_pass_rms_m_s2", "m/s^2", note="no seed value; vector rms of the tone"),
        Param("cycle_period_s", "s", note="assumed compressor cycle"), Param("duty", "1", note="assumed"),
        Param("work_start_h", "h", note="assumed"),
        Param("work_stop_h", "h", seed=18.0, note="the seed: off for the runs after 6 pm"))

    def compressor(self, time_s: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """c(t) (n,) bool: the compressor runs (module doc); draws the cycle's phase u."""
        t = np.asarray(time_s, float)
        u = rng.uniform(0.0, self.cycle_period_s)
        return np.mod(t - t[0] + u, self.cycle_period_s) < self.duty * self.cycle_period_s

    def specific_force(self, time_s, hour_of_day, fs, rng) -> np.ndarray:
        """f_ac (n, 3) m/s^2 (module doc)."""
        n = time_s.size
        on = working_mask(np.asarray(hour_of_day, float), self.work_start_h, self.work_stop_h)
        on &= self.compressor(time_s, rng)
        out = np.zeros((n, 3))
        if self.blade_pass_hz < fs / 2:
            d = rng.normal(size=3)
            d /= np.linalg.norm(d)
            phase = rng.uniform(0, 2 * np.pi)
            amp = np.sqrt(2) * self.blade_pass_rms_m_s2
            out += (amp * np.sin(2 * np.pi * self.blade_pass_hz * time_s + phase))[:, None] * d
        if self.broadband_rms_m_s2 > 0 and fs / 2 > self.band_hz[1]:
            out += band_noise(rng, (n, 3), fs, tuple(self.band_hz), self.broadband_rms_m_s2)
        return out * on[:, None]

    def inject(self, f: np.ndarray, ctx: ChainContext, rng: np.random.Generator) -> np.ndarray:
        if not self.enabled or ctx.hour_of_day is None:
            return f
        return f + self.specific_force(ctx.time_s, ctx.hour_of_day, ctx.sample_rate_hz, rng)

    def noise_variance(self, ctx: ChainContext) -> float:
        """Per-axis variance (m/s^2)^2 of one sample (module doc); 0 for a long window mean."""
        if not self.enabled or ctx.window_samples > 1:
            return 0.0
        fs = ctx.sample_rate_hz
        var = ((self.broadband_rms_m_s2**2 if fs / 2 > self.band_hz[1] else 0.0)
               + (self.blade_pass_rms_m_s2**2 / 3 if self.blade_pass_hz < fs / 2 else 0.0))
        return self.duty * var * ctx.working_fraction(self.work_start_h, self.work_stop_h)

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        """{broadband_rms_m_s2, blade_pass_hz, blade_pass_rms_m_s2, duty} of the injected unit (0 sizes without)."""
        e = truth["chain"].get("effects", {}).get(self.name)
        if not e or not e["enabled"]:
            return {"broadband_rms_m_s2": 0.0, "blade_pass_hz": float(self.blade_pass_hz),
                    "blade_pass_rms_m_s2": 0.0, "duty": 0.0}
        return {k: float(e[k]) for k in ("broadband_rms_m_s2", "blade_pass_hz", "blade_pass_rms_m_s2", "duty")}
