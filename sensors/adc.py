"""The DAQ-6036E analog-to-digital chain (seed sections 2, 3 and 4.3.4).

One multiplexed 16-bit converter scans the channels of ``scan_list`` in order at the
multiplexing frequency f_mux, once per sample period. Per sample n and scan slot j:

    t_j   = t_n + j / f_mux                                    [s]   channel skew
    u_j   = x_j(t_j) + g(t_n) + c_mode(t_n)                    [V]   ground loop, common mode
    u_j  += c_x (u_{j-1} - u_j),  c_x = exp(-1 / (f_mux tau))  [V]   settling crosstalk from the
                                                                       previously scanned channel
    code  = clip(round((u_j + e_adc) / q), -2^15, 2^15 - 1)   [-]   q = 2 range / 2^16
    V     = code * q                                           [V]

With averaged logging (``averaging`` = conversions per logged sample, e.g. 100 for 10 Hz
records of a 1 kHz converter) the logged value is the mean of dithered conversions:
V = u_j + e, e ~ N(0, (q^2/12 + e_adc^2) / averaging), no longer on the LSB grid.

g: 50 Hz ground-loop pickup, present only with ground-referenced single-ended wiring
(GRSE) of grounded sources (seed 3.4). c_mode: common-mode noise, rejected by the
differential configuration (DIFF). e_adc: converter input noise. The crosstalk grows
with f_mux because the amplifier has less time to settle (seed Table 4.3).

Options of seed 4.3.4: ``ground_between`` converts a slot wired to the card's ground before every
data slot (u_{j-1} = 0 V, so the leak is a pure scale factor c on u_j); ``channel_settling_tau_s``
gives a channel its own tau (a higher source impedance, e.g. a faulty connector in its line);
``channel_slow_settling`` gives a channel a slow settling tail (alpha, tau_s) that remembers the slots
before the previous one, through a grounded slot too (:mod:`imurig.sensors.effects.adc_slow_settling`).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from imurig.kernel.errors import ConfigError
from imurig.sensors.effects.adc_crosstalk import AdcCrosstalk
from imurig.sensors.effects.adc_quantisation import variance_V2
from imurig.sensors.effects.adc_slow_settling import AdcSlowSettling
from imurig.sensors.effects.base import ScanSlot
from imurig.sensors.effects.common_mode_noise import CommonModeNoise
from imurig.sensors.effects.channel_skew import ChannelSkew

GROUNDINGS = ("GRSE", "NRSE", "DIFF")


@dataclass
class DAQ6036E:
    scan_list: tuple[str, ...]
    range_V: float = 5.0
    bits: int = 16
    sample_rate_hz: float = 1000.0
    mux_frequency_hz: float = 20e3
    settling_tau_s: float = 0.59e-6
    crosstalk_enabled: bool = True
    skew_enabled: bool = True
    grounding: str = "NRSE"
    ground_loop_V: float = 2e-3
    mains_hz: float = 50.0
    common_mode_noise_V_rms: float = 30e-6
    input_noise_lsb_rms: float = 0.6
    averaging: int = 1  # conversions averaged into one logged sample (slow averaged logging)
    #: seed Table 4.3's "grounded channel between": a slot wired to the card's ground (0 V) is
    #: converted before every data slot, so each data slot settles from 0 V (2 slots per channel)
    ground_between: bool = False
    #: per-channel settling time constants (s) where a channel's source impedance differs from the
    #: card's (e.g. a faulty connector's series resistance); the others settle with settling_tau_s
    channel_settling_tau_s: dict | None = None
    #: per-channel slow settling tails {channel: (alpha, tau_s)} (module doc)
    channel_slow_settling: dict | None = None

    def validate(self):
        if self.grounding not in GROUNDINGS:
            raise ConfigError(f"grounding must be one of {GROUNDINGS}, got {self.grounding!r}")
        if self.range_V not in (10.0, 5.0, 0.5, 0.05):
            raise ConfigError(f"DAQ-6036E input ranges are +-10, 5, 0.5, 0.05 V; got {self.range_V}")
        slots = self.slots_per_scan
        if slots > 16 or (self.grounding == "DIFF" and slots > 8):
            raise ConfigError(f"{slots} scan slots do not fit: 16 single-ended or 8 differential"
                              + (" (a grounded slot before each channel doubles the slots)" if self.ground_between
                                 else ""))
        for opt in ("channel_settling_tau_s", "channel_slow_settling"):
            unknown = set(getattr(self, opt) or {}) - set(self.scan_list)
            if unknown:
                raise ConfigError(f"{opt} names {sorted(unknown)}, which are not in the scan list "
                                  f"{list(self.scan_list)}")
        if slots / self.mux_frequency_hz > 1 / self.sample_rate_hz:
            raise ConfigError(f"scanning {slots} slots at {self.mux_frequency_hz:g} Hz takes "
                             f"longer than one sample period at {self.sample_rate_hz:g} Hz; raise f_mux or "
                             "lower the sample rate")
        return self

    @property
    def slots_per_scan(self) -> int:
        """Converted slots per scan: the channels, plus a grounded slot before each with ``ground_between``."""
        return len(self.scan_list) * (2 if self.ground_between else 1)

    def channel_crosstalk(self, name: str) -> AdcCrosstalk:
        """The settling crosstalk into channel ``name`` (its own time constant where one is given)."""
        tau = (self.channel_settling_tau_s or {}).get(name, self.settling_tau_s)
        return AdcCrosstalk(settling_tau_s=tau, enabled=self.crosstalk_enabled)

    def slow_tails(self, analog: dict, common: np.ndarray, idle_first: float | None = None) -> dict:
        """{channel: (its AdcSlowSettling, r (n,) V)} for the channels with a slow tail: r from the inputs of the
        slots before it in the scan (grounded slots 0 V) and the previous scan's last slot as the idle input.
        Row 0's previous scan: ``idle_first`` (V, the last slot's input, common mode included; a piece of a
        streamed record), else row 0's own (the record's first scan)."""
        out = {}
        for name, (alpha, tau_s) in (self.channel_slow_settling or {}).items():
            tail = AdcSlowSettling(alpha=float(alpha), tau_s=float(tau_s))
            j = self.scan_list.index(name)
            before = []
            for k in range(j - 1, -1, -1):   # nearest first; with grounded slots: G_(k+1), then channel k
                before += [None, analog[self.scan_list[k]] + common] if self.ground_between else \
                    [analog[self.scan_list[k]] + common]
            if self.ground_between:
                before.append(None)   # the grounded slot before the scan's first channel
            last = analog[self.scan_list[-1]] + common
            idle = np.concatenate((last[:1] if idle_first is None else [idle_first], last[:-1]))
            out[name] = (tail, tail.reservoir(before, idle, self.mux_frequency_hz))
        return out

    @property
    def lsb_V(self) -> float:
        return 2 * self.range_V / 2**self.bits

    @property
    def common_mode(self) -> CommonModeNoise:
        """The common-mode noise and ground loop of this wiring (:mod:`imurig.sensors.effects.common_mode_noise`)."""
        return CommonModeNoise(self.common_mode_noise_V_rms, self.ground_loop_V, self.mains_hz, self.grounding)

    @property
    def crosstalk(self) -> AdcCrosstalk:
        """The settling crosstalk effect of this converter (:mod:`imurig.sensors.effects.adc_crosstalk`)."""
        return AdcCrosstalk(settling_tau_s=self.settling_tau_s, enabled=self.crosstalk_enabled)

    @property
    def skew(self) -> ChannelSkew:
        """The channel skew of this converter (:mod:`imurig.sensors.effects.channel_skew`)."""
        return ChannelSkew(enabled=self.skew_enabled)

    def crosstalk_coefficient(self) -> float:
        """Fraction of the previous channel's difference left when this one is sampled."""
        return self.crosstalk.coefficient(self.mux_frequency_hz)

    def sample_variance_V2(self) -> float:
        """Per-logged-sample variance of rounding and input noise (V^2), :func:`variance_V2`."""
        return variance_V2(self.lsb_V, self.input_noise_lsb_rms, self.averaging)

    def convert(self, analog: dict[str, np.ndarray], time_s: np.ndarray, rng: np.random.Generator,
                slope: dict[str, np.ndarray] | None = None, consume: bool = False) -> tuple[dict[str, np.ndarray], dict]:
        """Digitise ``analog`` (name -> (n,) volts). Returns (volts per channel, report dict).

        ``slope`` (name -> (n,) V/s, the noise-free signal's time derivative) enables the
        channel skew; channels without a slope are taken as constant over one scan. ``consume``
        drops each scanned line from ``analog`` and ``slope`` once converted (the caller's dicts),
        so that memory holds the lines or their conversions, not both.
        """
        self.validate()
        missing = [c for c in self.scan_list if c not in analog]
        if missing:
            raise ConfigError(f"scan list names {missing} but no such analog signals exist")
        common = self.common_mode.common(time_s, rng)
        n = common.size
        out, saturated = {}, {}
        held = None  # the previous slot's input u_{j-1} (n,), where the next slot's crosstalk needs it
        tails = self.slow_tails(analog, common) if self.channel_slow_settling else {}
        # one channel at a time, in row chunks (bounded temporaries; the draws in the same order as
        # one whole-channel draw, so the result does not depend on the chunk size)
        for j, name in enumerate(self.scan_list):
            nxt = self.scan_list[j + 1] if j + 1 < len(self.scan_list) else None
            keep = nxt is not None and not self.ground_between and \
                self.channel_crosstalk(nxt).coefficient(self.mux_frequency_hz) > 0
            held_next = np.empty(n) if keep else None
            out[name] = np.empty(n)
            for a, b in _row_chunks(n):
                out[name][a:b] = self._convert_rows(j, name, a, b, analog, common, slope, held, held_next, rng,
                                                    saturated, tails.get(name))
            held = held_next
            if consume:
                analog.pop(name, None)
                if slope:
                    slope.pop(name, None)
        c = self.crosstalk.coefficient(self.mux_frequency_hz)
        report = {"lsb_V": self.lsb_V, "crosstalk_coefficient": c, "saturated_samples": saturated,
                  "crosstalk_coefficients": {k: self.channel_crosstalk(k).coefficient(self.mux_frequency_hz)
                                             for k in self.scan_list}}
        return out, report

    def _convert_rows(self, j: int, name: str, a: int, b: int, analog: dict, common: np.ndarray, slope, held,
                      held_next, rng, saturated: dict, tail=None, codes: bool = False) -> np.ndarray:
        """Rows a:b of scan slot j (channel ``name``): u = x + c_mode, the skew, the crosstalk from the
        previous slot (``held``: its input; the last channel's for j = 0), the slow tail (``tail``: its effect
        and r, :meth:`slow_tails`), the noise and the rounding (module doc). Stores this slot's input into
        ``held_next`` (when given). Volts, or with ``codes`` the integer codes (int16 up to 16 bits;
        volts = code * lsb_V)."""
        slot = 2 * j + 1 if self.ground_between else j
        u = analog[name][a:b] + common[a:b]
        if slope and name in slope:  # slot j is sampled j / f_mux after the scan starts
            u = self.skew.inject(u, ScanSlot(slot, self.mux_frequency_hz, slope_V_s=slope[name][a:b]))
        if held_next is not None:
            held_next[a:b] = u
        xtalk = self.channel_crosstalk(name)
        if xtalk.coefficient(self.mux_frequency_hz) > 0:
            if self.ground_between:  # the grounded slot before it: settles from 0 V
                prev = np.zeros_like(u)
            elif j == 0:  # the first slot follows the last slot of the previous scan
                last = self.scan_list[-1]
                lo = max(a - 1, 0)
                prev = analog[last][lo:b - 1] + common[lo:b - 1]
                if a == 0:
                    prev = np.concatenate((u[:1], prev))
            else:
                prev = held[a:b]
            u = xtalk.inject(u, ScanSlot(slot, self.mux_frequency_hz, prev))
        if tail is not None:
            u = tail[0].inject(u, ScanSlot(slot, self.mux_frequency_hz, tail[1][a:b]))
        return self._quantise(u, rng, name, saturated, codes)

    def _quantise(self, u: np.ndarray, rng: np.random.Generator, name: str, saturated: dict,
                  codes: bool = False) -> np.ndarray:
        """Add the converter noise to ``u`` (a scratch array, overwritten) and quantise: volts (n,), or
        with ``codes`` the codes (int16 up to 16 bits, else int32; not with averaging)."""
        q = self.lsb_V
        lo, hi = -(2 ** (self.bits - 1)), 2 ** (self.bits - 1) - 1
        if self.averaging > 1:
            # the mean of `averaging` dithered conversions: quantisation and input noise
            # average down and the result is no longer on the grid
            e = rng.standard_normal(u.size)
            e *= np.sqrt(self.sample_variance_V2())
            u += e
            u /= q
        else:
            e = rng.standard_normal(u.size)
            e *= self.input_noise_lsb_rms * q
            u += e
            u /= q
            np.round(u, out=u)
        del e
        np.clip(u, lo, hi, out=u)
        nsat = int(np.count_nonzero(u == lo) + np.count_nonzero(u == hi))
        if nsat:
            saturated[name] = saturated.get(name, 0) + nsat
        if codes and self.averaging == 1:
            return u.astype(np.int16 if self.bits <= 16 else np.int32)
        u *= q
        return u

    def settings(self) -> dict:
        d = asdict(self)
        d["scan_list"] = list(self.scan_list)
        d["lsb_V"] = self.lsb_V
        d["crosstalk_coefficient"] = self.crosstalk_coefficient()
        d["crosstalk_coefficients"] = {k: self.channel_crosstalk(k).coefficient(self.mux_frequency_hz)
                                       for k in self.scan_list}
        return d


#: rows per piece of the converter's work (bounded temporaries; the result does not depend on it)
ROW_CHUNK = 1 << 18


def _row_chunks(n: int, chunk: int = ROW_CHUNK):
    """(start, stop) row ranges covering n rows."""
    return [(a, min(n, a + chunk)) for a in range(0, n, chunk)]
