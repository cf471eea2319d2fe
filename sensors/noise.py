"""Coloured noise generators (vectorised, explicit Generator)."""
from __future__ import annotations

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
    nyq = fs / 2
    white = rng.standard_normal(shape)
    if lo <= 0 and hi >= nyq:
        return white * rms
    if lo <= 0:
        sos = signal.butter(4, hi / nyq, "lowpass", output="sos")
    elif hi >= nyq * 0.98:
        sos = signal.butter(4, lo / nyq, "highpass", output="sos")
    else:
        sos = signal.butter(4, [lo / nyq, hi / nyq], "bandpass", output="sos")
    y = signal.sosfilt(sos, white, axis=0)
    # theoretical power gain of the filter for unit white noise
    _, h = signal.sosfreqz(sos, worN=8192)
    gain = np.sqrt(np.mean(np.abs(h) ** 2))
    return y * (np.asarray(rms) / gain)
