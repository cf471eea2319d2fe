"""The streamed chain's noise draws, made ahead in a thread of their own (:func:`imurig.sensors.stream.measure_stream`).

Per piece of m rows, in piece order, the same calls on the same generators as the stages would make:

    accelerometers  the current noise's bands (:class:`BandNoise`: its draws and shaping filters)
    magnetometer    standard_normal((m, 3))      (:meth:`imurig.sensors.magnetometer.Fluxgate.output_voltage`)
    temp. sensors   standard_normal(m) each      (:meth:`imurig.sensors.accelerometer.CurrentTemperatureSensor.voltage`)
    adc             standard_normal(m): the common mode's white part (not for DIFF), then one per scanned
                    channel in scan order (:meth:`imurig.sensors.adc.DAQ6036E._quantise`)

The stages then take their draws from a :class:`Drawn` in place of their generator: the same numbers in
the same order, so the data are those of the stages drawing for themselves, bit for bit; only the work
moves to a third thread (the Python of the front, the back and the sinks takes turns for the
interpreter lock, the draws do not need it). A stage asking a :class:`Drawn` for any other draw, or a
draw of another shape, is an error (the sequence above no longer matches the stages).
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np
from scipy import signal

from imurig.sensors.accelerometer import AXES
from imurig.sensors.noise import _shaping_filter, band_power_gain


@dataclass
class BandNoise:
    """The accelerometers' current noise (n, 3) A, piece by piece: each sampled band's white draws
    through its shaping filter, whose state is carried (:func:`imurig.sensors.noise.add_band_noise`)."""

    bands: list
    fs: float
    rng: np.random.Generator
    state: list = field(default_factory=list)

    def __post_init__(self):
        self.filters = []
        for lo, hi, rms in self.bands:
            sos = _shaping_filter(self.fs, (lo, hi))
            scale = rms if sos is None else rms / np.sqrt(band_power_gain(self.fs, (lo, hi)))
            self.filters.append((sos, scale))
            self.state.append(None if sos is None else np.zeros((sos.shape[0], 2, 3)))

    def rows(self, m: int) -> np.ndarray:
        out = np.zeros((m, 3))
        for i, (sos, scale) in enumerate(self.filters):
            y = self.rng.standard_normal((m, 3))
            if sos is not None:
                y, self.state[i] = signal.sosfilt(sos, y, axis=0, zi=self.state[i])
            out += y * scale
        return out


class Drawn:
    """Stand-in for a Generator whose ``standard_normal`` draws were made ahead: gives them back in order."""

    def __init__(self, name: str, arrays):
        self.name, self._q = name, deque(arrays)

    def standard_normal(self, size=None):
        if not self._q:
            raise RuntimeError(f"the streamed chain's '{self.name}' stream asked for more draws than were made "
                               "ahead (sensors/stream_draws.py)")
        x = self._q.popleft()
        shape = () if size is None else tuple(np.atleast_1d(size))
        if x.shape != shape:
            raise RuntimeError(f"the streamed chain's '{self.name}' stream asked for a draw of shape {shape}; "
                               f"{x.shape} was made ahead (sensors/stream_draws.py)")
        return x

    def left(self) -> int:
        return len(self._q)


class Drawer:
    """Makes each piece's draws (module doc), in piece order: :meth:`piece` (m rows) returns them."""

    def __init__(self, lab, rngs: dict, acc_noise):
        adc = lab.adc
        self.rngs, self.acc_noise = rngs, acc_noise
        scan = set(adc.scan_list)
        self.mag = any(f"mag_{x}" in scan for x in AXES)
        self.acc = any(f"acc_{x}" in scan for x in AXES) and bool(acc_noise.filters)
        self.temps = [k for k in lab.temp_sensors if k in scan]
        self.common = adc.common_mode.grounding != "DIFF" and adc.common_mode.rms_V > 0
        self.nchan = len(adc.scan_list)

    def piece(self, m: int) -> dict:
        out = {"acc": self.acc_noise.rows(m) if self.acc else None}
        if self.mag:
            out["magnetometer"] = Drawn("magnetometer", [self.rngs["magnetometer"].standard_normal((m, 3))])
        for k in self.temps:
            out[k] = Drawn(k, [self.rngs[k].standard_normal(m)])
        adc = self.rngs["adc"]
        out["adc"] = Drawn("adc", [adc.standard_normal(m) for _ in range(int(self.common) + self.nchan)])
        return out
