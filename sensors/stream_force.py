"""The lab's own specific-force effects (:attr:`imurig.sensors.chain.ImuLab.effects`), streamed: row
piece by row piece, for :func:`imurig.sensors.stream.measure_stream`.

The whole-record chain composes the specific-force stage as

    f = 0;  f <- pump(f);  f <- people(f);  f <- e_1(f);  ...;  f <- e_k(f)        (m/s^2, frame C)

with each lab effect e_i drawing from its own stream ``child_rng(seed, e_i.stream)``. Here the same
composition is made piece by piece. Each supported effect is evaluated from its own physics (the effect
object's methods and fields), its draws taken in the order its whole-record ``specific_force`` takes them,
so that over the record the rows are the whole-record values to the bit:

- ``air_conditioning_vibration``: the compressor's phase u, the blade-pass tone's direction and phase, then the
  broadband white draws piece by piece through the shaping filter with its state carried
  (:func:`imurig.sensors.noise.band_noise`);
  f_ac = [A sin(2 pi f_b t + phi) d + n_band(t)] on(t),  on = working hours AND compressor cycle;
- ``transformer_hum``: each harmonic's direction and phase drawn once; f_tr = sum_h A_h sin(2 pi h 2 f_mains t
  + phi_h) d_h, in working hours;
- ``ship_passages``: the passages over the whole record drawn once (small), each added to the rows it spans;
- ``warm_up``: b(t - t_0 + t_start), deterministic;
- ``vibration_rectification``: delta_a = sum_b k_b <(P_b f)^2>_W of the vibration before it. P_b is the
  record's FFT band-pass in the whole-record chain (non-causal); here it is the FFT of the piece with
  :func:`rectification_margin` rows of context on each side. The ideal band-pass's impulse response
  decays as 1 / (pi t): beyond the margin T_M the energy left out is 1 / (pi^2 T_M Delta f) of the band's
  (Delta f its width), ~2e-5 at T_M = 32 s for the 50-200 Hz band. So the offset is the whole-record one
  to that relative size, not to the bit (tests/test_stream_force.py bounds it).

The base of the composition (pump, people transients) is the streamed chain's own (:class:`imurig.sensors.
stream._People`); the people transients are drawn on the same pieces as without lab effects, so a lab's
effects do not change the other draws. Analog-stage lab effects (a persistent cable fault) are not streamed
(:func:`unsupported_effects` names them).
"""
from __future__ import annotations

import math
from collections import deque

import numpy as np
from scipy import signal
from scipy.fft import irfft, next_fast_len, rfft
from scipy.ndimage import uniform_filter1d

from imurig.sensors.effects.building_vibration import working_mask
from imurig.sensors.effects.ship_passages import SUPPORT_SIGMAS
from imurig.sensors.noise import _shaping_filter, band_power_gain, child_rng

#: the lab effects with a streamed form: stage "specific_force" (:class:`LabForce`) and "analog" (:class:`LabLines`)
STREAMED_EFFECTS = ("air_conditioning_vibration", "transformer_hum", "ship_passages", "warm_up", "vibration_rectification")
STREAMED_LINE_EFFECTS = ("gyro_scale_instability",)
#: seconds of context on each side of a piece for the rectification's band-pass (module doc)
RECTIFICATION_CONTEXT_S = 32.0
#: pieces whose rectified offset one FFT makes (its margins' share of the work: 2 M / (pieces x piece))
RECT_PIECES = 4


def unsupported_effects(effects) -> list[str]:
    """The names of the lab effects (``ImuLab.effects``) the streamed chain does not model."""
    return [e.name for e in effects if not (e.stage == "specific_force" and e.name in STREAMED_EFFECTS
                                            or e.stage == "analog" and e.name in STREAMED_LINE_EFFECTS)]


def ever_on(hour0: float, hours: float, start_h: float, stop_h: float) -> bool:
    """Whether the local hours [hour0, hour0 + hours] meet a day's working hours [start_h, stop_h)."""
    day = math.floor(hour0 / 24.0)
    return any(s < hour0 + hours and hour0 < e for k in range(day, day + int(hours // 24) + 2)
               for s, e in [(start_h + 24 * k, stop_h + 24 * k)])


def rectification_margin(fs: float, window_s: float) -> int:
    """Rows of context on each side of a piece for the rectification (module doc): at least
    RECTIFICATION_CONTEXT_S, and beyond half the moving-mean window."""
    return int(math.ceil(max(RECTIFICATION_CONTEXT_S, window_s) * fs))


class _AirConditioning:
    def __init__(self, e, rng, t0: float, fs: float, ever_on: bool):
        self.e, self.rng, self.t0, self.ever_on = e, rng, t0, ever_on
        self.u = rng.uniform(0.0, e.cycle_period_s)          # the compressor's phase (AirConditioningVibration.compressor)
        self.tone = None
        if e.blade_pass_hz < fs / 2:
            d = rng.normal(size=3)
            d /= np.linalg.norm(d)
            self.tone = (np.sqrt(2) * e.blade_pass_rms_m_s2, rng.uniform(0, 2 * np.pi), d)
        self.band = None
        if e.broadband_rms_m_s2 > 0 and fs / 2 > e.band_hz[1]:
            band = tuple(e.band_hz)
            sos = _shaping_filter(fs, band)
            gain = np.sqrt(band_power_gain(fs, band)) if sos is not None else 1.0
            zi = None if sos is None else np.zeros((sos.shape[0], 2, 3))
            self.band = [sos, np.asarray(e.broadband_rms_m_s2) / gain if sos is not None else e.broadband_rms_m_s2,
                         zi]

    def rows(self, t: np.ndarray, hour: np.ndarray) -> np.ndarray | None:
        e = self.e
        if not self.ever_on:          # off over the whole record: zero, as the whole record's product gives
            return None
        on = working_mask(hour, e.work_start_h, e.work_stop_h)
        on &= np.mod(t - self.t0 + self.u, e.cycle_period_s) < e.duty * e.cycle_period_s
        out = np.zeros((t.size, 3))
        if self.tone is not None and on.any():
            amp, phase, d = self.tone
            out += (amp * np.sin(2 * np.pi * e.blade_pass_hz * t + phase))[:, None] * d
        if self.band is not None:
            sos, scale, zi = self.band
            y = self.rng.standard_normal((t.size, 3))
            if sos is not None:
                y, self.band[2] = signal.sosfilt(sos, y, axis=0, zi=zi)
            out += y * scale
        return out * on[:, None]


class _Hum:
    def __init__(self, e, rng, fs: float):
        self.e, self.parts = e, []
        for f, a in zip(e.frequencies(), e.amplitudes()):
            d = rng.normal(size=3)
            d /= np.linalg.norm(d)
            phase = rng.uniform(0, 2 * np.pi)
            if f < fs / 2:
                self.parts.append((f, a, phase, d))

    def rows(self, t: np.ndarray, hour: np.ndarray) -> np.ndarray | None:
        on = working_mask(hour, self.e.work_start_h, self.e.work_stop_h)
        if not on.any():              # its draws are made: a piece out of working hours adds zero
            return None
        out = np.zeros((t.size, 3))
        for f, a, phase, d in self.parts:
            out += (a * np.sin(2 * np.pi * f * t + phase))[:, None] * d
        return out * on[:, None]


class _Ships:
    def __init__(self, e, rng, t0: float, t1: float, hour0: float):
        self.e = e
        self.p = e.passages(t0, t1, hour0, rng)
        self.half = SUPPORT_SIGMAS * e.envelope_s

    def rows(self, t: np.ndarray, hour: np.ndarray) -> np.ndarray:
        e, p = self.e, self.p
        out = np.zeros((t.size, 3))
        te = p["time_s"]
        near = np.flatnonzero((te + self.half >= t[0]) & (te - self.half <= t[-1]))
        for i in near.tolist():
            i0, i1 = np.searchsorted(t, [te[i] - self.half, te[i] + self.half])
            u = t[i0:i1] - te[i]
            out[i0:i1] += (e.peak_m_s2 * np.exp(-0.5 * (u / e.envelope_s) ** 2)
                           * np.sin(2 * np.pi * p["frequency_hz"][i] * u + p["phase_rad"][i]))[:, None] \
                * p["direction"][i]
        return out


class _WarmUp:
    def __init__(self, e, t0: float):
        self.e, self.t0 = e, t0

    def rows(self, t: np.ndarray, hour: np.ndarray) -> np.ndarray | None:
        if not np.any(self.e.delta_bias_m_s2):
            return None
        return self.e.bias(t - self.t0 + self.e.start_after_turn_on_s)


class LabForce:
    """The specific force of the base disturbances (``base``: the streamed chain's people transients, an
    object with ``rows(hour)`` giving (m, 3) m/s^2 or None, and ``rng``) and then the lab's effects, row piece
    by row piece (module doc). Called as the base is: ``rows(hour)`` for consecutive pieces [a, a + m) of
    the record ``run``, in order; returns (m, 3) m/s^2."""

    def __init__(self, base, effects, run, seed: np.random.SeedSequence, hours, piece: int):
        self.base, self.run, self.hours, self.piece = base, run, hours, piece
        self.rng = True                                   # the stream calls rows() when rng is set
        self.fs = fs = float(run.meta["sample_rate_hz"])
        t0, t1 = float(run.time_rows(0, 1)[0]), float(run.time_rows(run.n - 1, run.n)[0])
        hour0 = float(hours(run.time_rows(0, 1))[0])
        self.stages, self.rect = [], None
        lab = [e for e in effects if e.stage == "specific_force" and getattr(e, "enabled", True)]
        for i, e in enumerate(lab):
            rng = child_rng(seed, e.stream) if e.stream else None
            if e.name == "vibration_rectification":
                if i != len(lab) - 1:
                    raise ValueError("the streamed chain takes the vibration rectification last among the lab's "
                                     "specific-force effects; use ImuLab.measure")
                if np.any(e.coeff_per_m_s2):
                    self.rect = e
            elif e.name == "air_conditioning_vibration":
                self.stages.append(_AirConditioning(e, rng, t0, fs, ever_on(hour0, (t1 - t0) / 3600.0,
                                                                             e.work_start_h, e.work_stop_h)))
            elif e.name == "transformer_hum":
                self.stages.append(_Hum(e, rng, fs))
            elif e.name == "ship_passages":
                self.stages.append(_Ships(e, rng, t0, t1, hour0))
            elif e.name == "warm_up":
                self.stages.append(_WarmUp(e, t0))
            else:
                raise ValueError(f"the streamed chain does not model the lab effect '{e.name}'; use ImuLab.measure")
        self.margin = rectification_margin(fs, self.rect.window_s) if self.rect is not None else 0
        self.pos = 0                                      # the next row rows() returns
        self.made = deque()                               # (a, f before the rectification) of the pieces made
        self.next_a = 0                                   # the first row not made yet
        self.r_rows, self.r_off = (0, 0), None            # the rows of the rectified offset made, and it

    def _make(self, a: int, b: int) -> np.ndarray:
        t = self.run.time_rows(a, b)
        hour = self.hours(t)
        f = self.base.rows(hour) if self.base.rng is not None else None
        f = np.zeros((b - a, 3)) if f is None else f
        for s in self.stages:
            g = s.rows(t, hour)
            if g is not None:
                f = f + g
        return f

    def _ensure(self, upto: int) -> None:
        while self.next_a < min(upto, self.run.n):
            a, b = self.next_a, min(self.run.n, self.next_a + self.piece)
            self.made.append((a, self._make(a, b)))
            self.next_a = b

    def _take(self, a: int, b: int) -> np.ndarray:
        parts = [f[max(a - s, 0):b - s] for s, f in self.made if s < b and s + f.shape[0] > a]
        return parts[0] if len(parts) == 1 else np.concatenate(parts)

    def _rectified(self, x: np.ndarray, off: int, m: int) -> np.ndarray:
        """:func:`imurig.sensors.effects.vibration_rectification.rectified_offset` of the block ``x`` at its rows
        [off, off + m): one FFT of the block for every band, and each band's moving mean only over the rows
        whose window it reaches (the same values as over the whole block)."""
        e, fs = self.rect, self.fs
        n = x.shape[0]
        W = max(1, int(round(e.window_s * fs)))
        i0, i1 = max(0, off - W), min(n, off + m + W)
        L = next_fast_len(n, real=True)                   # zero-padded to a fast length (the margin absorbs it)
        freqs = np.fft.rfftfreq(L, 1.0 / fs)
        spec = None
        out = np.zeros((m, 3))
        for k, band in zip(e.coeff_per_m_s2.T, e.bands_hz):
            mask = (freqs > band[0]) & (freqs <= band[1])
            if band[0] >= fs / 2 or not np.any(k) or not mask.any():
                continue
            if spec is None:
                spec = rfft(x, n=L, axis=0)
            xb = irfft(spec * mask[:, None], n=L, axis=0)[i0:i1]
            out += k * uniform_filter1d(xb * xb, W, axis=0, mode="nearest")[off - i0:off - i0 + m]
        return out

    def rows(self, hour: np.ndarray) -> np.ndarray:
        a = self.pos
        b = self.pos = a + hour.size
        keep = b
        if self.rect is None:
            self._ensure(b)
            f = self._take(a, b)
        else:       # the offset for RECT_PIECES pieces at a time: one FFT over them and their margins
            ra, rb = self.r_rows
            if not (ra <= a and b <= rb):
                n, M = self.run.n, self.margin
                ra, rb = a, min(n, max(b, a + RECT_PIECES * self.piece))
                lo, hi = max(0, ra - M), min(n, rb + M)
                self._ensure(hi)
                self.r_rows, self.r_off = (ra, rb), self._rectified(self._take(lo, hi), ra - lo, rb - ra)
            f = self._take(a, b) + self.r_off[a - ra:b - ra]
            keep = min(b, rb - self.margin)                # the next batch's context starts there
        while self.made and self.made[0][0] + self.made[0][1].shape[0] <= keep:
            self.made.popleft()
        return f


class _ScaleWander:
    """One line's scale wander s (:class:`imurig.sensors.effects.gyro_scale_instability.GyroScaleInstability`),
    piece by piece: the stationary start s[0] ~ N(0, sigma^2) drawn first, then each piece's drive
    sigma sqrt(1 - phi^2) w[k] through s[k+1] = phi s[k] + drive, the recursion's state carried. (The whole
    record draws its n drives before s[0]: the same process, another order of the draws.)"""

    def __init__(self, e, rng, fs: float):
        self.e, self.rng = e, rng
        self.phi = float(np.exp(-1.0 / (e.tau_s * fs)))
        self.zi = None

    def rows(self, m: int) -> np.ndarray:
        e, phi = self.e, self.phi
        drive = self.rng.standard_normal(m) * e.sigma * np.sqrt(1 - phi**2) if self.zi is not None else None
        if drive is None:
            s0 = self.rng.standard_normal() * e.sigma
            drive = self.rng.standard_normal(m) * e.sigma * np.sqrt(1 - phi**2)
            drive[0] = s0
            self.zi = np.zeros(1)
        s, self.zi = signal.lfilter([1.0], [1.0, -phi], drive, zi=self.zi)
        return s


class LabLines:
    """The lab's own analog-stage effects (:data:`STREAMED_LINE_EFFECTS`) on the analog lines, piece by piece,
    in the chain's order after the slip rings and a loose cable; one random stream per line
    (``child_rng(seed, effect.line_stream(line))``), as the whole-record chain."""

    def __init__(self, effects, names, seed: np.random.SeedSequence, fs: float):
        self.parts = []
        for e in effects:
            if e.stage != "analog":
                continue
            if e.name != "gyro_scale_instability":
                raise ValueError(f"the streamed chain does not model the lab effect '{e.name}'; use ImuLab.measure")
            for line in e.lines(list(names)):
                self.parts.append((line, _ScaleWander(e, child_rng(seed, e.line_stream(line)), fs)))

    def add(self, analog: dict) -> None:
        """V' = V (1 + s) on each line an effect acts on (``analog``: line -> (m,) V, replaced)."""
        for line, w in self.parts:
            v = analog[line]
            analog[line] = v * (1.0 + w.rows(v.size))
