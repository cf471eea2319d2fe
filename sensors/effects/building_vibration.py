"""Building vibration from the hydraulic pump in the basement (seed 4.3.3), on in working hours.

    f_vib(t) = sum_h A_h e(t) d_h(t) sin(2 pi h f0 t + phi_h) + n_bb(t)       [m/s^2, (n, 3)]

A_h = rms sqrt(2) w_h / |w| (harmonic weights w), e(t) = 1 + 0.5 n_e(t) a slow envelope, d_h(t)
slowly turning unit directions (n_e and d_h band-limited to ``modulation_hz``), phi_h uniform,
n_bb broadband noise (5-40 Hz) of rms ``broadband_rms_m_s2`` per axis; zero outside working hours.
Harmonics at or above f_s/2 are averaged out by a slow (averaging) logger and left out. Stage
"specific_force": the chain adds it at the IMU (stream "pump").

Per-sample variance per axis (E[e^2] = 1.25, E[d_j^2] = 1/3), times the working-hours fraction:

    var = sum_{h f0 < f_s/2} A_h^2 / 2 * 1.25 / 3 + rms_bb^2 [f_s/2 > 40 Hz]         [(m/s^2)^2]

A long window mean holds none of it (no power at DC).

Diagnosis (within-position scatter): the positions' mean Welch spectrum holds a narrow peak more
than 25 times its median; the positions whose peak power stands out locate it in the day. Refit:
a sinusoid at the peak frequency (scanned +- one Welch bin) with its own phase and level per
affected position; the finding gives its frequency (to ~df / 400), the mean amplitude (V and m/s^2) +- its
standard error, and the residual scatter before and after.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from scipy import signal

from imurig.sensors.effects.base import ChainContext, Effect, Param, ScatterView
from imurig.sensors.noise import band_noise


def working_mask(hour_of_day: np.ndarray, start_h: float, stop_h: float) -> np.ndarray:
    return (hour_of_day >= start_h) & (hour_of_day < stop_h)


@dataclass
class PumpVibration(Effect):
    """Building vibration from the hydraulic pump (m/s^2 at the IMU), on in working hours."""

    enabled: bool = True
    fundamental_hz: float = 24.7
    harmonics: tuple = (1.0, 0.5)
    rms_m_s2: float = 0.03
    broadband_rms_m_s2: float = 0.01
    modulation_hz: float = 0.05
    work_start_h: float = 7.5
    work_stop_h: float = 17.5

    name: ClassVar[str] = "building_vibration"
    stage: ClassVar[str] = "specific_force"
    stream: ClassVar[str] = "pump"
    physics: ClassVar[str] = "narrow-band building vibration from the basement's hydraulic pump, by day"
    seed_section: ClassVar[str] = "4.3.3, Fig. 4.13"
    seed_says: ClassVar[str] = ("a hydraulic pump in the basement shook the building by day; 'the vibrations vary "
                                "in time and directions and are not the same for all of the three accelerometers'")
    params: ClassVar[tuple] = (Param("rms_m_s2", "m/s^2", seed=0.03), Param("fundamental_hz", "Hz", seed=24.7),
                               Param("amplitude", "m/s^2", note="refitted: the mean amplitude at the peak "
                                                                "frequency on one axis"))
    views: ClassVar[tuple] = ("position_scatter",)
    finding_key: ClassVar[str] = "finding_vibration"
    #: the spectral peak must stand this far above the spectrum's median
    peak_ratio: ClassVar[float] = 25.0

    def amplitudes(self) -> np.ndarray:
        """A_h (m/s^2) of each harmonic: rms sqrt(2) w_h / |w|."""
        w = np.asarray(self.harmonics, float)
        return self.rms_m_s2 * np.sqrt(2) * w / np.sqrt(np.sum(w**2))

    def specific_force(self, time_s, hour_of_day, fs, rng) -> np.ndarray:
        """f_vib (n, 3) m/s^2 (module doc)."""
        n = time_s.size
        out = np.zeros((n, 3))
        on = working_mask(hour_of_day, self.work_start_h, self.work_stop_h)
        if not self.enabled or not on.any():
            return out
        for h, a in enumerate(self.amplitudes(), start=1):
            if h * self.fundamental_hz >= fs / 2:  # averaged out by a slow (averaging) logger
                continue
            env = 1 + 0.5 * band_noise(rng, (n,), fs, (0, self.modulation_hz), 1.0)
            direction = band_noise(rng, (n, 3), fs, (0, self.modulation_hz), 1.0) + rng.normal(size=3)
            direction /= np.linalg.norm(direction, axis=1, keepdims=True)
            phase = rng.uniform(0, 2 * np.pi)
            out += (a * env * np.sin(2 * np.pi * h * self.fundamental_hz * time_s + phase))[:, None] * direction
        if self.broadband_rms_m_s2 > 0 and fs / 2 > 40.0:
            out += band_noise(rng, (n, 3), fs, (5.0, 40.0), self.broadband_rms_m_s2)
        return out * on[:, None]

    def inject(self, f: np.ndarray, ctx: ChainContext, rng: np.random.Generator) -> np.ndarray:
        if not self.enabled:
            return f
        return f + self.specific_force(ctx.time_s, ctx.hour_of_day, ctx.sample_rate_hz, rng)

    def noise_variance(self, ctx: ChainContext) -> float:
        """Per-axis variance (m/s^2)^2 (module doc); 0 for a long window mean (ctx.window_samples > 1)."""
        if not self.enabled or ctx.window_samples > 1:
            return 0.0
        fs = ctx.sample_rate_hz
        harm = sum(a**2 / 2 for h, a in enumerate(self.amplitudes(), start=1) if h * self.fundamental_hz < fs / 2)
        var = harm * 1.25 / 3 + (self.broadband_rms_m_s2**2 if fs / 2 > 40.0 else 0.0)
        return var * ctx.working_fraction(self.work_start_h, self.work_stop_h)

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        """{frequency_hz: f0, amplitude_m_s2: A_1}: the fundamental and its vector amplitude (an axis
        sees A_1 |d_j| e(t); the refit's frequency estimates f0)."""
        p = truth["chain"]["pump"]
        return {"frequency_hz": float(p["fundamental_hz"]),
                "amplitude_m_s2": float(PumpVibration(**{**p, "harmonics": tuple(p["harmonics"])}).amplitudes()[0])}

    # ------------------------------------------------------------- diagnosis
    def test(self, view: ScatterView) -> dict:
        """The spectral-peak test (module doc); with a finding, its refit."""
        sl, x, fs = view.positions, view.samples, view.sample_rate_hz
        nper = int(min(256, min(s_.stop - s_.start for s_ in sl)))
        psd = np.array([signal.welch(x[s_] - np.median(x[s_]), fs=fs, nperseg=nper)[1] for s_ in sl])
        f = signal.welch(x[sl[0]], fs=fs, nperseg=nper)[0]
        band = (f > 2.0) & (f < 0.45 * fs)
        # never below the ADC's rounding noise: q^2/12 spread over 0 .. fs/2 (one-sided PSD)
        q = float(getattr(view, "quantum_V", 0.0) or 0.0)
        mean_psd = np.maximum(psd.mean(axis=0), q * q / 12.0 / (fs / 2.0))
        k = np.flatnonzero(band)[np.argmax(mean_psd[band])]
        ratio = float(mean_psd[k] / np.median(mean_psd[band]))
        out = {"spectral_peak_to_median": ratio}
        if ratio > self.peak_ratio:
            pk = psd[:, max(k - 1, 0):k + 2].sum(axis=1)
            loud = pk > 10 * np.median(psd[:, band], axis=1) * 3
            hours = np.asarray(view.hour_of_day, float)
            out["finding"] = {"effect": self.name,
                              "physics": "narrow-band building vibration (the basement pump) at "
                                         f"{f[k]:.1f} Hz (seed 4.3.3)",
                              "spectral_peak_hz": float(f[k]), "peak_to_median": ratio,
                              "positions_affected": int(loud.sum()),
                              "window_hours": [float(hours[loud].min()), float(hours[loud].max())]
                              if loud.any() else None}
            out["finding"].update(self.refit(view, float(f[k]), fs / nper, np.flatnonzero(loud)))
        return out

    def refit(self, view: ScatterView, f_peak: float, df: float, positions=None, n_scan: int = 41) -> dict:
        """Sinusoid at the peak: per position x_i(t) = c_i + a_i sin(2 pi f t) + b_i cos(2 pi f t),
        one frequency f scanned over f_peak +- df (then +- one step of that scan) for the least
        total residual. Amplitude per
        position A_i = |(a_i, b_i)|; reported: f, the mean of A_i over the ``positions`` (all if
        none given) +- its standard error (the A_i's spread / sqrt(m), or the fit's own with one
        position), in V and through the nominal sensitivity in SI, and the rms residual about
        each position's median before and about the fit after (V)."""
        idx = np.arange(len(view.positions)) if positions is None or len(positions) == 0 else np.asarray(positions)
        segs = [view.samples[view.positions[i]] for i in idx]
        ts = [np.arange(s.size) / view.sample_rate_hz for s in segs]

        def fit(freq):
            res = []
            for x, t in zip(segs, ts):
                X = np.column_stack([np.ones_like(t), np.sin(2 * np.pi * freq * t), np.cos(2 * np.pi * freq * t)])
                coef, *_ = np.linalg.lstsq(X, x, rcond=None)
                r = x - X @ coef
                cov = np.linalg.inv(X.T @ X) * float(r @ r) / max(x.size - 3, 1)
                res.append((coef, cov, r))
            return res

        f_best, step = f_peak, df
        for _ in range(2):  # a coarse scan over the Welch bin, then a fine one about its best step
            grid = f_best + np.linspace(-step, step, n_scan)
            ss = np.array([sum(float(r @ r) for _, _, r in fit(fr)) for fr in grid])
            f_best, step = float(grid[int(np.argmin(ss))]), 2 * step / (n_scan - 1)
        # the profile about the fine scan's minimum, S(f) ~ S0 + a (f - f0)^2: its vertex is the estimate
        # (between grid points) and var(f) = sigma^2 / a, sigma^2 = S0 / (N - p)
        j = int(np.argmin(ss))
        win = slice(max(j - 3, 0), min(j + 4, len(grid)))
        a2, a1, _ = np.polyfit(grid[win] - grid[j], ss[win], 2) if win.stop - win.start >= 3 else (0.0, 0.0, 0.0)
        if a2 > 0 and abs(a1 / (2 * a2)) <= step:
            f_best = float(grid[j] - a1 / (2 * a2))
        fits = fit(f_best)
        n_tot = sum(x.size for x in segs)
        sigma2 = sum(float(r @ r) for _, _, r in fits) / max(n_tot - 3 * len(segs) - 1, 1)
        se_f = float(np.sqrt(sigma2 / a2)) if a2 > 0 else float("nan")
        A = np.array([np.hypot(c[1], c[2]) for c, _, _ in fits])
        if A.size > 1:
            se = float(np.std(A, ddof=1) / np.sqrt(A.size))
        else:  # delta method on the fit's covariance
            c, cov, _ = fits[0]
            g = np.array([0.0, c[1], c[2]]) / max(A[0], 1e-300)
            se = float(np.sqrt(g @ cov @ g))
        before = np.sqrt(np.mean(np.concatenate([x - np.median(x) for x in segs]) ** 2))
        after = np.sqrt(np.mean(np.concatenate([r for _, _, r in fits]) ** 2))
        out = {"refit_frequency_hz": f_best, "amplitude_V": float(A.mean()), "amplitude_se_V": se,
               "positions_refitted": int(A.size), "scatter_before_V": float(before), "scatter_after_V": float(after),
               "parameters": [{"name": "frequency_hz", "estimate": f_best, "std_error": se_f},
                              {"name": "amplitude_V", "estimate": float(A.mean()), "std_error": se}]}
        s = view.sensitivity_V_per_SI
        if s:
            out.update(amplitude_m_s2=float(A.mean() / s), amplitude_se_m_s2=se / s)
        return out
