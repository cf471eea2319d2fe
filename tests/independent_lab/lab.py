"""The independent lab's own logger: converter, noise, CSV and manifest (numpy and stdlib only).

This lab knows nothing of imurig. Its conventions, used everywhere in this package:

- Voltages are what the logger's converter read: an input ``u`` (V) plus the converter's own input
  noise ``n_adc`` (``adc_noise_lsb`` LSB rms, Gaussian), rounded to the step ``q = span / 2**bits``
  and held at the rails: ``code = clip(round((u + n_adc) / q), -2**(bits-1), 2**(bits-1) - 1)``,
  written as ``code * q`` volts. The quantisation error is ``q / sqrt(12)`` rms.
- Time tags are ``n / fs`` (the logger's clock; ``fs`` may be non-integer, e.g. 102.4 Hz).
- The manifest beside each CSV (same stem, ``.json``) holds the concealed effects (empty list for a
  null), the converter and the sensors' true parameters, in SI.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

G_LAB = 9.81242231                 # local gravity the geodesists gave the lab (m/s^2), seed 4.3.1
OMEGA_EARTH = 7.2921150e-5         # the Earth's rate (rad/s)
LAB_SITE = {"name": "delft", "latitude_deg": 52.0, "longitude_deg": 4.37, "altitude_m": 0.0}


@dataclass(frozen=True)
class Converter:
    """A multiplexed bipolar ADC: ``bits`` over ``-half_range_V .. +half_range_V``."""
    bits: int
    half_range_V: float
    noise_lsb: float = 0.3

    @property
    def step_V(self) -> float:
        """q = 2 * half_range / 2**bits (V)."""
        return 2.0 * self.half_range_V / 2 ** self.bits

    def read(self, u_V: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Volts written by the logger: q * clip(round((u + n) / q)), n ~ N(0, (noise_lsb q)^2)."""
        q = self.step_V
        code = np.rint((u_V + self.noise_lsb * q * rng.standard_normal(u_V.shape)) / q)
        code = np.clip(code, -2 ** (self.bits - 1), 2 ** (self.bits - 1) - 1)
        return code * q

    def as_dict(self) -> dict:
        return {"bits": self.bits, "half_range_V": self.half_range_V, "step_V": self.step_V,
                "input_noise_lsb_rms": self.noise_lsb}


#: the converters the lab owns (name -> converter)
CONVERTERS = {
    "16bit_5V": Converter(16, 5.0),        # step 153 uV: coarser than the accelerometers' noise
    "12bit_10V": Converter(12, 10.0),      # step 4.9 mV
    "24bit_10V": Converter(24, 10.0),      # a fine one
    "18bit_2V5": Converter(18, 2.5),
}


def time_tags(n: int, fs_hz: float) -> np.ndarray:
    """t_n = n / fs (s)."""
    return np.arange(n) / fs_hz


def _decimals(step: float) -> int:
    """Decimals that keep a value on a grid of ``step`` exact to print."""
    return max(0, int(math.ceil(-math.log10(step))) + 3)


def write_csv(path: Path, meta: dict, columns: dict[str, np.ndarray], steps: dict[str, float]) -> None:
    """The lab CSV: ``# key: value`` lines, one header, numbers; column ``c`` printed with enough
    decimals for its grid ``steps[c]`` (so the written volts are the converter's codes times q)."""
    names = list(columns)
    fmts = [f"%.{_decimals(steps[c])}f" for c in names]
    data = np.column_stack([columns[c] for c in names])
    lines = [f"# {k}: {v}" for k, v in meta.items()]
    lines.append(",".join(names))
    body = "\n".join(",".join(f % x for f, x in zip(fmts, row)) for row in data)
    Path(path).write_text("\n".join(lines) + "\n" + body + "\n")


def write_manifest(path: Path, manifest: dict) -> None:
    """The truth beside the CSV (sorted keys, so equal truths give equal bytes)."""
    Path(path).write_text(json.dumps(manifest, indent=1, sort_keys=True) + "\n")


def white(rng: np.random.Generator, n: int, rms: float) -> np.ndarray:
    """White Gaussian noise of standard deviation ``rms``."""
    return rms * rng.standard_normal(n)


def smooth_ramp(t_s: np.ndarray, knots_t: np.ndarray, knots_v: np.ndarray) -> np.ndarray:
    """Piecewise-linear set-point through (knots_t, knots_v)."""
    return np.interp(t_s, knots_t, knots_v)
