"""Vibration rectification of the Q-Flex accelerometers (datasheet, seed appendix A.1): vibration
shifts the mean output in proportion to its mean square, by a coefficient that depends on the band.

    delta_a_j(t) = sum_b k_b,j <(P_b a_vib,j)^2>_W (t)                            [m/s^2, (n, 3)]

a_vib,j: the disturbance specific force on axis j (the building's vibration, the sum of the
specific-force effects the chain injected before this one); P_b: the band-pass to band b,
lo_b < f <= hi_b (a mask on the record's FFT; DC never belongs to a band); <.>_W: the moving mean
over ``window_s`` (edges: the nearest sample repeated). A pure tone A sin(2 pi f t) in band b
gives the offset k_b A^2 / 2 (whole periods in the window).

Datasheet (A.1): at most 50 ug/g^2 rms from 50 to 200 Hz, 100 from 200 to 750 Hz, 150 from 750 to
2000 Hz; k [1 / (m/s^2)] = k [ug/g^2] 1e-6 / g. Below 50 Hz the datasheet is silent: the triad's
own square-law nonlinearity k2 (<= 48 ug/g^2, :class:`ScaleNonlinearity`) already rectifies every
frequency, so this effect's coefficients are the rectification beyond k2 and the lowest band's
prior is 0. At the pump's 0.03 m/s^2 rms a 50 ug/g^2 coefficient gives 5e-9 m/s^2.

Stage "specific_force" (the offset enters the sensor with the vibration, through its scale
factor); list it after the vibration sources in a lab's ``effects``. Only what the record samples
(below f_s / 2) is rectified: a source above f_s / 2 (left out of the record by an averaging
logger) must be fed at a higher rate to :func:`rectified_offset`. A deterministic offset: no
noise variance of its own. Off by default (all k = 0).
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
from scipy.ndimage import uniform_filter1d

from imurig.kernel.units import G_STANDARD
from imurig.sensors.effects.base import ChainContext, Effect, Param

#: the datasheet's bands (Hz) and their maximum coefficients (ug/g^2 rms; None: not specified)
BANDS_HZ = ((1.0, 50.0), (50.0, 200.0), (200.0, 750.0), (750.0, 2000.0))
DATASHEET_UG_PER_G2 = (None, 50.0, 100.0, 150.0)


def ug_per_g2_to_si(k_ug_per_g2: float) -> float:
    """k in 1 / (m/s^2) for a datasheet coefficient in ug/g^2: 1e-6 g / g^2 = 1e-6 / g."""
    return float(k_ug_per_g2) * 1e-6 / G_STANDARD


def band_mean_square(a: np.ndarray, fs: float, band_hz: tuple[float, float], window_s: float) -> np.ndarray:
    """<(P_b a)^2>_W (n, ...) (module doc): the band's moving mean square along axis 0."""
    a = np.asarray(a, float)
    n = a.shape[0]
    freqs = np.fft.rfftfreq(n, 1.0 / fs)
    mask = (freqs > band_hz[0]) & (freqs <= band_hz[1])
    if not mask.any():
        return np.zeros_like(a)
    spec = np.fft.rfft(a, axis=0)
    xb = np.fft.irfft(spec * mask.reshape((-1,) + (1,) * (a.ndim - 1)), n=n, axis=0)
    return uniform_filter1d(xb * xb, max(1, int(round(window_s * fs))), axis=0, mode="nearest")


def rectified_offset(a_vib: np.ndarray, fs: float, coeff_per_m_s2: np.ndarray, bands_hz=BANDS_HZ,
                     window_s: float = 1.0) -> np.ndarray:
    """delta_a (n, 3) m/s^2 for the vibration a_vib (n, 3) sampled at fs, coefficients (3, n_bands)."""
    a_vib = np.asarray(a_vib, float)
    k = np.asarray(coeff_per_m_s2, float)
    out = np.zeros_like(a_vib)
    for b, band in enumerate(bands_hz):
        if band[0] >= fs / 2 or not np.any(k[:, b]):
            continue
        out += k[:, b] * band_mean_square(a_vib, fs, band, window_s)
    return out


@dataclass
class VibrationRectification(Effect):
    """Rectification coefficients (3 axes x bands) in 1 / (m/s^2); moving mean over ``window_s``."""

    coeff_per_m_s2: np.ndarray = field(default_factory=lambda: np.zeros((3, len(BANDS_HZ))))
    bands_hz: tuple = BANDS_HZ
    window_s: float = 1.0

    name: ClassVar[str] = "vibration_rectification"
    stage: ClassVar[str] = "specific_force"
    physics: ClassVar[str] = ("vibration rectification: the accelerometer's mean output shifts by a band-dependent "
                              "coefficient times the vibration's mean square")
    seed_section: ClassVar[str] = "A.1 (Q-Flex datasheet, Vibration Rectification)"
    seed_says: ClassVar[str] = ("'50 ug/g squared rms (maximum) from 50 to 200 Hz. 100 ug/g squared rms (maximum) from "
                                "200 to 750 Hz. 150 ug/g squared rms (maximum) from 750 to 2000 Hz.'")
    params: ClassVar[tuple] = tuple(
        Param(f"k_{lo:g}_{hi:g}_hz", "1/(m/s^2)", datasheet=None if d is None else ug_per_g2_to_si(d),
              note="bound (maximum magnitude); beyond the triad's k2" if d is not None else
              "not in the datasheet: the triad's k2 (<= 48 ug/g^2) covers it; prior 0")
        for (lo, hi), d in zip(BANDS_HZ, DATASHEET_UG_PER_G2)) + (Param("window_s", "s", note="averaging window"),)

    def __post_init__(self):
        k = np.asarray(self.coeff_per_m_s2, float)
        self.bands_hz = tuple(tuple(float(v) for v in b) for b in self.bands_hz)
        self.coeff_per_m_s2 = np.broadcast_to(k if k.ndim == 2 else k[None, :], (3, len(self.bands_hz))).copy()

    @classmethod
    def from_datasheet(cls, rng: np.random.Generator | None = None, **kw) -> "VibrationRectification":
        """The datasheet's maxima on every axis (lowest band 0); with ``rng`` each uniform within +- its bound."""
        k = np.array([ug_per_g2_to_si(d or 0.0) for d in DATASHEET_UG_PER_G2])
        k = np.tile(k, (3, 1)) if rng is None else rng.uniform(-1.0, 1.0, (3, k.size)) * k
        return cls(coeff_per_m_s2=k, **kw)

    def inject(self, f: np.ndarray, ctx: ChainContext, rng=None) -> np.ndarray:
        """f + delta_a(f) (module doc): ``f`` (n, 3) is the vibration injected so far."""
        if not np.any(self.coeff_per_m_s2):
            return f
        return f + rectified_offset(f, ctx.sample_rate_hz, self.coeff_per_m_s2, self.bands_hz, self.window_s)

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        """{k_<lo>_<hi>_hz: k_b,j} on accelerometer ``channel`` ("acc_x" ...), from the lab's effects."""
        e = truth["chain"].get("effects", {}).get(self.name)
        j = "xyz".index(channel[-1]) if channel else 0
        bands = e["bands_hz"] if e else self.bands_hz
        k = np.asarray(e["coeff_per_m_s2"], float)[j] if e else np.zeros(len(bands))
        return {f"k_{lo:g}_{hi:g}_hz": float(v) for (lo, hi), v in zip(bands, k)}
