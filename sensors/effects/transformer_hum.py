"""Hum of the basement's voltage transformer (seed 4.3.3 and chapter 6), on in working hours.

    f_tr(t) = w(t) sum_h A_h d_h sin(2 pi h f_hum t + phi_h),  f_hum = 2 f_mains      [m/s^2, (n, 3)]

Magnetostriction makes the core vibrate at twice the mains frequency (100 Hz on the 50 Hz grid)
and its harmonics (200, 300 Hz ...). A_h = rms sqrt(2) w_h / |w| (harmonic weights w, so the
vector rms over the harmonics is ``rms_m_s2``), d_h fixed unit directions uniform on the sphere,
phi_h ~ U(0, 2 pi); w(t) = 1 while the local hour lies in [work_start_h, work_stop_h) (the seed:
shut off for the evening runs after 6 pm). As for the pump, a harmonic at or above f_s / 2 is
averaged out by a slow (averaging) logger and left out (at the seed's 1 kHz all of the first four
are recorded; at 100 Hz none). Stage "specific_force" (stream "transformer"). Off by default.

Per-sample variance per axis (E[d_j^2] = 1/3), times the working-hours fraction:

    var = sum_{h f_hum < f_s/2} A_h^2 / 2 / 3                                       [(m/s^2)^2]

Summed over the axes it is sum A_h^2 / 2 exactly for any directions (whole periods); a long window
mean holds none of it.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from imurig.kernel import random_streams
from imurig.sensors.effects.base import ChainContext, Effect, Param
from imurig.sensors.effects.building_vibration import working_mask

random_streams.register("sensor-chain/transformer", "the basement transformer's hum (phases, directions)",
                        child=True)


@dataclass
class TransformerHum(Effect):
    """Transformer hum at 2 f_mains and harmonics (m/s^2 at the IMU), by day."""

    enabled: bool = False
    mains_hz: float = 50.0
    harmonics: tuple = (1.0, 0.4, 0.2, 0.1)
    rms_m_s2: float = 2e-3
    work_start_h: float = 7.0
    work_stop_h: float = 18.0

    name: ClassVar[str] = "transformer_hum"
    stage: ClassVar[str] = "specific_force"
    stream: ClassVar[str] = "transformer"
    physics: ClassVar[str] = ("the basement transformer hums at twice the mains frequency and its harmonics and "
                              "shakes the building by day")
    seed_section: ClassVar[str] = "4.3.3; chapter 6"
    seed_says: ClassVar[str] = ("'in the basement are a machine for transforming voltages for equipment to be used in "
                                "aircrafts'; the final runs were made 'between 6pm and 10pm, where ... the pump, the "
                                "transfomer, and the air conditioning were shut off'")
    params: ClassVar[tuple] = (Param("mains_hz", "Hz", seed=50.0, note="the Dutch grid"),
                               Param("rms_m_s2", "m/s^2", note="no seed value; vector rms over the harmonics"),
                               Param("harmonics", "1", note="assumed weights of 100, 200, 300, 400 Hz"),
                               Param("work_stop_h", "h", seed=18.0, note="the seed: off after 6 pm"))

    def frequencies(self) -> np.ndarray:
        """h 2 f_mains (Hz) of each harmonic."""
        return 2.0 * self.mains_hz * np.arange(1, len(self.harmonics) + 1)

    def amplitudes(self) -> np.ndarray:
        """A_h (m/s^2): rms sqrt(2) w_h / |w|."""
        w = np.asarray(self.harmonics, float)
        return self.rms_m_s2 * np.sqrt(2) * w / np.sqrt(np.sum(w**2))

    def specific_force(self, time_s, hour_of_day, fs, rng) -> np.ndarray:
        """f_tr (n, 3) m/s^2 (module doc); every harmonic draws its direction and phase."""
        out = np.zeros((time_s.size, 3))
        for f, a in zip(self.frequencies(), self.amplitudes()):
            d = rng.normal(size=3)
            d /= np.linalg.norm(d)
            phase = rng.uniform(0, 2 * np.pi)
            if f < fs / 2:
                out += (a * np.sin(2 * np.pi * f * time_s + phase))[:, None] * d
        on = working_mask(np.asarray(hour_of_day, float), self.work_start_h, self.work_stop_h)
        return out * on[:, None]

    def inject(self, f: np.ndarray, ctx: ChainContext, rng: np.random.Generator) -> np.ndarray:
        if not self.enabled or ctx.hour_of_day is None:
            return f
        return f + self.specific_force(ctx.time_s, ctx.hour_of_day, ctx.sample_rate_hz, rng)

    def noise_variance(self, ctx: ChainContext) -> float:
        """Per-axis variance (m/s^2)^2 of one sample (module doc); 0 for a long window mean."""
        if not self.enabled or ctx.window_samples > 1:
            return 0.0
        keep = self.frequencies() < ctx.sample_rate_hz / 2
        var = float(np.sum(self.amplitudes()[keep] ** 2) / 2 / 3)
        return var * ctx.working_fraction(self.work_start_h, self.work_stop_h)

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        """{frequency_hz: 2 f_mains, amplitude_m_s2: A_1} of the injected hum (amplitude 0 without)."""
        e = truth["chain"].get("effects", {}).get(self.name)
        if not e or not e["enabled"]:
            return {"frequency_hz": 2.0 * self.mains_hz, "amplitude_m_s2": 0.0}
        hum = TransformerHum(**{**e, "harmonics": tuple(e["harmonics"])})
        return {"frequency_hz": float(hum.frequencies()[0]), "amplitude_m_s2": float(hum.amplitudes()[0])}
