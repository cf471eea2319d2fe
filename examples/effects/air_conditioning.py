"""A new effect in one file: the lab's air conditioning (seed 4.3.3 and chapter 6).

This file is the worked example of adding an effect (docs/architecture.md). Copied into
``sensors/effects/`` it joins the library (``imurig.sensors.effects.LIBRARY`` finds it) and every
consumer picks it up with no other edit:

- the sensor chain injects it (``ImuLab(effects=(AirConditioning(...),))`` or a campaign's
  ``lab_effects``), at the specific-force stage, from its own random stream;
- the tilt-table diagnosis runs its ``test`` (with the default timetable, the lab's prior) on
  every channel's within-position scatter and reports a finding with the refitted size ± SE;
- the Monte-Carlo Cramér-Rao bound of the tilt table adds its ``noise_variance``;
- ``fitted`` maps the injected truth to the diagnosis' parameter, so the tests can score it.

Measurement equation (specific force at the IMU, per axis, while the unit runs):

    f_ac(t) = rms * n(t) * on(t)                                              [m/s^2, (n, 3)]

n: unit-variance Gaussian noise low-pass shaped to ``band_hz`` (airflow and compressor
turbulence), independent per axis; on(t) = 1 while the local hour lies in [on_h, off_h).
Per-sample variance rms^2 on(t); a window mean of N samples keeps rms^2 / (g^2 N)
(:func:`imurig.sensors.noise.window_mean_variance`).
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from scipy import stats

from imurig.kernel import random_streams
from imurig.sensors.effects.base import ChainContext, Effect, Param, ScatterView
from imurig.sensors.noise import band_noise, window_mean_variance

# the effect's own random stream, a child of every sensor chain's stream (one registry: no two
# stages can share a stream)
random_streams.register("sensor-chain/air_conditioning", "the air conditioning's vibration", child=True)


@dataclass
class AirConditioning(Effect):
    """Broadband specific force (m/s^2 rms per axis) from the air conditioning while it runs."""

    enabled: bool = True
    rms_m_s2: float = 5e-3
    band_hz: tuple = (0.0, 20.0)
    on_h: float = 8.0
    off_h: float = 18.0
    alpha: float = 0.01

    name: ClassVar[str] = "air_conditioning"
    stage: ClassVar[str] = "specific_force"
    stream: ClassVar[str] = "air_conditioning"
    physics: ClassVar[str] = "broadband vibration from the lab's air conditioning while it runs"
    seed_section: ClassVar[str] = "4.3.3, chapter 6"
    seed_says: ClassVar[str] = ("disturbances such as the air conditioning, the transformer in the basement and "
                                "passing ships shake the building")
    params: ClassVar[tuple] = (Param("rms_m_s2", "m/s^2", note="per axis, while the unit runs"),
                               Param("on_h", "h"), Param("off_h", "h"))
    views: ClassVar[tuple] = ("position_scatter",)
    finding_key: ClassVar[str] = "finding_air_conditioning"

    def running(self, hour_of_day) -> np.ndarray:
        h = np.asarray(hour_of_day, float)
        return (h >= self.on_h) & (h < self.off_h)

    def inject(self, f_C: np.ndarray, ctx: ChainContext, rng: np.random.Generator) -> np.ndarray:
        """f_C + f_ac (module doc): the noise is drawn for the whole record, then gated."""
        if not self.enabled or ctx.hour_of_day is None:
            return f_C
        on = self.running(ctx.hour_of_day)
        noise = band_noise(rng, f_C.shape, ctx.sample_rate_hz, tuple(self.band_hz), self.rms_m_s2)
        return f_C + noise * on[:, None]

    def noise_variance(self, ctx: ChainContext) -> float:
        """Per-axis variance (m/s^2)^2 of one sample, or of a window mean of ctx.window_samples."""
        if not self.enabled:
            return 0.0
        n = int(ctx.window_samples)
        var = (self.rms_m_s2**2 if n <= 1 else
               window_mean_variance(((*self.band_hz, self.rms_m_s2),), ctx.sample_rate_hz, n))
        return var * ctx.working_fraction(self.on_h, self.off_h)

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        """{rms_m_s2}: the injected rms (its band lies inside the diagnosis' 50 Hz analysis band)."""
        return {"rms_m_s2": float(truth["chain"]["effects"][self.name]["rms_m_s2"])}

    def test(self, view: ScatterView) -> dict:
        """One-sided Welch t-test on the log variance of each position's samples, positions while the
        unit runs against the others; if it fires (p < alpha), the refit: rms^2 = mean(v_on) -
        mean(v_off) ± SE (the groups' spreads), stated in V and, through the nominal sensitivity, m/s^2."""
        on = self.running(view.hour_of_day)
        if on.sum() < 2 or (~on).sum() < 2:
            return {}
        v = np.array([np.var(view.centred(i)) for i in range(len(view.positions))])
        t, p = stats.ttest_ind(np.log(v[on]), np.log(v[~on]), equal_var=False, alternative="greater")
        out = {"air_conditioning_p": float(p)}
        if p < self.alpha:
            d = float(v[on].mean() - v[~on].mean())
            se = math.sqrt(v[on].var(ddof=1) / on.sum() + v[~on].var(ddof=1) / (~on).sum())
            rms_V = math.sqrt(max(d, 0.0))
            se_V = se / (2 * rms_V) if rms_V > 0 else float("inf")
            s = view.sensitivity_V_per_SI or float("nan")
            out["finding"] = {"effect": self.name, "physics": self.physics, "statistic": float(t), "p_value": float(p),
                              "positions_affected": int(on.sum()),
                              "parameters": [{"name": "rms_V", "estimate": rms_V, "std_error": se_V, "unit": "V"},
                                             {"name": "rms_m_s2", "estimate": rms_V / s, "std_error": se_V / s,
                                              "unit": "m/s^2"}],
                              "scatter_rms_V_before": float(math.sqrt(v[on].mean())),
                              "scatter_rms_V_after": float(math.sqrt(max(v[on].mean() - d, 0.0)))}
        return out
