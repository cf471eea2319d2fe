"""The turn table's stages of the streamed sensor chain (:mod:`imurig.sensors.stream`), piece by piece: the
fibre-optic gyros' rate noise and the slip rings' contact noise.

Gyro noise (:class:`imurig.sensors.effects.gyro_noise.GyroNoise`, the whole-record chain's
``FOGTriad.noise_rate`` per contiguous block): per piece and per block within it the white draws (m, 3),
then the Gauss-Markov drive (m, 3), at a block's first row its stationary start (3 draws); the
first-order filter b[k+1] = phi b[k] + drive[k] runs with its state carried from piece to piece and
restarted at each block (the bias decorrelates over a remount gap). V_noise = SF (n + b_gm).

Slip rings (:class:`imurig.sensors.effects.slip_rings.SlipRingNoise`): per piece the profile
P(theta) once, then for each IMU line its own stream ("slip_<line>") draws the piece's n(t):
v += rms P n.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import signal


@dataclass
class GyroNoiseRows:
    """The gyros' output noise (m, 3) V over consecutive pieces (module doc)."""

    noise: object            # GyroNoise
    scale_V_per_rad_s: np.ndarray
    fs: float
    rng: np.random.Generator
    zi: np.ndarray = field(default_factory=lambda: np.zeros((3, 1)))

    def rows(self, m: int, block_starts) -> np.ndarray:
        """The next ``m`` rows; ``block_starts``: the rows (within the piece) where a contiguous block starts."""
        e = self.noise
        if not e.enabled:
            return np.zeros((m, 3))
        cuts = sorted({0, *block_starts, m})
        out = None if len(cuts) == 2 else np.empty((m, 3))   # one block: its rows are the output (no copy)
        for a, b in zip(cuts[:-1], cuts[1:]):
            w = self.rng.standard_normal((b - a, 3))
            w *= e.arw_rad_s_per_sqrt_hz * np.sqrt(self.fs)
            if e.bias_instability_rad_s > 0:
                phi = np.exp(-1.0 / (e.bias_instability_tau_s * self.fs))
                drive = self.rng.standard_normal((b - a, 3))
                drive *= e.bias_instability_rad_s
                drive *= np.sqrt(1 - phi**2)
                if a in block_starts:
                    drive[0] = self.rng.standard_normal(3) * e.bias_instability_rad_s  # stationary start
                    self.zi = np.zeros((3, 1))
                for j in range(3):
                    y, self.zi[j] = signal.lfilter([1.0], [1.0, -phi], drive[:, j], zi=self.zi[j])
                    w[:, j] += y
            if out is None:
                out = w
            else:
                out[a:b] = w
        out *= self.scale_V_per_rad_s
        return out


def block_starts(t: np.ndarray, t_prev: float | None, fs: float) -> list[int]:
    """The rows of the piece's times ``t`` that start a contiguous block (a gap over 1.5 sample periods
    before them; row 0 when the record starts there, ``t_prev`` None)."""
    out = [0] if t_prev is None or t[0] - t_prev > 1.5 / fs else []
    return out + [int(i) + 1 for i in np.flatnonzero(np.diff(t) > 1.5 / fs)]


def scaled_profile(eff, spin_angle: np.ndarray) -> np.ndarray:
    """rms P(theta) of the slip rings ``eff`` over a piece's table angles (no draws: the streamed chain makes
    it ahead, with the piece's rig rows)."""
    return eff.profile(spin_angle) * eff.rms_V


@dataclass
class SlipRows:
    """The slip rings' contact noise on each IMU line, piece by piece (module doc)."""

    eff: object              # SlipRingNoise
    rngs: dict               # line -> its generator ("slip_<line>")

    def draw(self, spin_angle: np.ndarray) -> dict:
        """The piece's noise rms P(theta) n(t) per line of ``rngs`` (P: :func:`scaled_profile` of the piece's
        table angles, once for all lines), drawn ahead of :meth:`add` (in the fronts' worker, each line's
        stream in piece order)."""
        P = scaled_profile(self.eff, spin_angle)
        out = {}
        for line, rng in self.rngs.items():
            n = rng.standard_normal(P.size)
            n *= P
            out[line] = n
        return out

    @staticmethod
    def add(analog: dict, drawn: dict) -> None:
        """analog[line] += the drawn P n of :meth:`draw`: v + P n, the same operations as v + P * n."""
        for line, n in drawn.items():
            n += analog[line]
            analog[line] = n
