"""Coloured noise generators (vectorised, explicit Generator) and the one rule for how a noise
band appears in a sampled record.

A sensor's noise is given as bands (lo, hi, rms) of Gaussian noise (Hz, Hz, rms in the sensor's
unit). :func:`sampled_bands` folds them into the sampled record (the one place that rule is
written; :func:`band_noise` draws them, :func:`window_mean_variance` states the variance of a
window mean, the filter priors take their low-frequency density):

- direct sampling (no anti-alias filter): a band above f_s/2 aliases into the record as white
  noise of its full rms, (0, f_s/2, rms); a band across f_s/2 keeps its rms in (lo, f_s/2);
- averaged logging (each sample the mean of many fast conversions): what lies above f_s/2
  averages out; a band across f_s/2 keeps the in-band share of its power,
  rms^2 (f_s/2 - lo) / (hi - lo), in (lo, f_s/2).
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy import signal

from imurig.kernel import random_streams


def child_rng(seed_seq: np.random.SeedSequence, name: str) -> np.random.Generator:
    """The generator of the sensor-chain stage ``name`` (pump, people, adc, slip_<line>, ...), a
    child of the chain's stream ``seed_seq`` in the registry (:mod:`imurig.kernel.random_streams`,
    child ``"sensor-chain/<name>"``: spawn key = the chain's key + crc32(name)).

    Each stage has its own stream, so switching a disturbance on or off never changes the noise
    realisation of any other stage. An unregistered stage name raises
    :class:`imurig.kernel.random_streams.UnknownStreamError`.
    """
    return random_streams.child_generator(seed_seq, "sensor-chain/" + name)


def band_noise(rng: np.random.Generator, shape: tuple[int, ...], fs: float, band_hz: tuple[float, float],
               rms: float | np.ndarray) -> np.ndarray:
    """Gaussian noise of the given rms, band-limited to ``band_hz`` (Hz), along axis 0.

    ``band_hz = (0, f)`` is low-pass; ``(f, fs/2)`` or beyond is high-pass; the result is
    scaled so that its theoretical rms equals ``rms`` (scalar or per column).
    """
    lo, hi = band_hz
    white = rng.standard_normal(shape)
    sos = _shaping_filter(fs, band_hz)
    if sos is None:
        return white * rms
    y = signal.sosfilt(sos, white, axis=0)
    gain = np.sqrt(band_power_gain(fs, (lo, hi)))
    return y * (np.asarray(rms) / gain)


def add_band_noise(out: np.ndarray, rng: np.random.Generator, fs: float, band_hz: tuple[float, float],
                   rms: float | np.ndarray, chunk: int = 1 << 18) -> None:
    """``out += band_noise(rng, out.shape, fs, band_hz, rms)``, the same values, in row pieces of
    ``chunk`` (the white draws in the same order, the shaping filter's state carried from piece
    to piece): memory for one piece instead of three copies of ``out``."""
    sos = _shaping_filter(fs, band_hz)
    scale = np.asarray(rms) if sos is None else np.asarray(rms) / np.sqrt(band_power_gain(fs, band_hz))
    zi = None if sos is None else np.zeros((sos.shape[0], 2) + out.shape[1:])
    for a in range(0, out.shape[0], chunk):
        b = min(out.shape[0], a + chunk)
        y = rng.standard_normal((b - a,) + out.shape[1:])
        if sos is not None:
            y, zi = signal.sosfilt(sos, y, axis=0, zi=zi)
        out[a:b] += y * scale


def _shaping_filter(fs: float, band_hz: tuple[float, float]):
    """The Butterworth shaping filter of :func:`band_noise` for ``band_hz`` (None: white)."""
    lo, hi = band_hz
    nyq = fs / 2
    if lo <= 0 and hi >= nyq:
        return None
    if lo <= 0:
        return signal.butter(4, hi / nyq, "lowpass", output="sos")
    if hi >= nyq * 0.98:
        return signal.butter(4, lo / nyq, "highpass", output="sos")
    return signal.butter(4, [lo / nyq, hi / nyq], "bandpass", output="sos")


@lru_cache(maxsize=128)
def _power_gain_cached(fs: float, lo: float, hi: float) -> float:
    sos = _shaping_filter(fs, (lo, hi))
    if sos is None:
        return 1.0
    _, h = signal.sosfreqz(sos, worN=8192)
    return float(np.mean(np.abs(h) ** 2))


def band_power_gain(fs: float, band_hz: tuple[float, float]) -> float:
    """g^2: the mean power gain over [0, f_s/2] of :func:`band_noise`'s shaping filter for
    ``band_hz`` (1 for white noise); band_noise scales by rms / g."""
    return _power_gain_cached(float(fs), float(band_hz[0]), float(band_hz[1]))


def sampled_bands(bands, fs: float, averaged: bool = False) -> list[tuple[float, float, float]]:
    """The noise bands (lo, hi, rms) as the record sampled at ``fs`` holds them (module doc):
    bands of zero rms dropped; direct sampling aliases a band above f_s/2 to white (0, f_s/2,
    rms); averaged logging drops it and keeps a band's in-band power share."""
    nyq = fs / 2
    out = []
    for lo, hi, rms in bands:
        if rms <= 0:
            continue
        if averaged:
            if lo >= nyq:
                continue
            rms = rms * np.sqrt((min(hi, nyq) - lo) / (hi - lo))
            hi = min(hi, nyq)
        if lo >= nyq:
            out.append((0.0, nyq, rms))
        else:
            out.append((lo, min(hi, nyq), rms))
    return out


def window_mean_variance(bands, fs: float, n_window: int, averaged: bool = False) -> float:
    """Variance of the mean of ``n_window`` consecutive samples of the noise ``bands`` (long-window
    limit: the sampled noise's power at DC over the window). White: rms^2 / N; a band reaching DC
    (low-pass shaping, |H(0)| = 1): rms^2 / (g^2 N), g^2 = :func:`band_power_gain`; a band above
    DC (|H(0)| = 0) averages out. Bands folded by :func:`sampled_bands`."""
    nyq = fs / 2
    var = 0.0
    for lo, hi, rms in sampled_bands(bands, fs, averaged):
        if lo <= 0 and hi >= nyq:
            var += rms**2 / n_window
        elif lo <= 0:
            var += rms**2 / (band_power_gain(fs, (lo, hi)) * n_window)
    return var
