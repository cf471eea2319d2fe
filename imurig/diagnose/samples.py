"""The tests every recorded channel gets as logged (any rig, any rate): the effects of the library
that offer a test on a :class:`~imurig.sensors.effects.views.RawChannelView` (saturation and
clipping), with the channel's ADC step q (:func:`~imurig.sensors.effects.adc_quantisation.step_of`:
the metadata, else the greatest common step of the values) and the converter's range when the
metadata gives it (``adc.range_V`` or ``inferred.adc_range_V``)."""
from __future__ import annotations

import numpy as np
import scipy.ndimage

from imurig.calibration.preprocess import lowpass_downsample
from imurig.kernel.recording import Recording
from imurig.sensors.effects import RawChannelView, run_tests
from imurig.sensors.effects.adc_quantisation import step_of


def working_record(rec: Recording, rate_hz: float = 100.0, cutoff_hz: float = 50.0) -> Recording:
    """The record at the diagnosis' working rate: the seed's 50 Hz Butterworth low-pass and
    decimation by the whole number k = floor(f_s / ``rate_hz``) when k >= 2 (1 kHz -> 100 Hz,
    250 Hz -> 125 Hz, 1024 Hz -> 102.4 Hz); a record at up to twice the working rate (50 Hz,
    100 Hz, 102.4 Hz, 150 Hz) is used as logged: there is nothing to decimate, and a 50 Hz cut-off
    would sit at or beyond its Nyquist frequency."""
    fs = float(rec.sample_rate_hz)
    k = int(np.floor(fs / rate_hz + 1e-9))
    if k < 2:
        return rec
    return lowpass_downsample(rec, rate_hz=fs / k, cutoff_hz=cutoff_hz)


def scan_order(rec: Recording) -> tuple[list[str], str]:
    """The ADC's scan order and where it comes from: ``meta["adc"]["scan_list"]`` when given, else
    the order of the file's voltage channels (a multiplexed logger writes its channels in the order
    it converts them), said so in the second element."""
    scan = list((rec.meta.get("adc") or {}).get("scan_list", []))
    if scan:
        return scan, "adc.scan_list in the metadata"
    return ([c for c in rec.channels if rec.units.get(c) == "V"],
            "the channel order of the file (no adc.scan_list in the metadata)")


def scan_order_known(rec: Recording) -> bool:
    """Whether the metadata give the ADC's scan order (an ``adc.scan_list`` the import did not infer
    from the file's column order: a logger's columns need not be its conversion order)."""
    return bool((rec.meta.get("adc") or {}).get("scan_list")) and \
        "adc_scan_list" not in (rec.meta.get("inferred") or {})


def leak_sources(rec: Recording, own: tuple[str, ...]) -> tuple[str, ...]:
    """The recorded voltage channels that may leak into the channels ``own`` where the scan order
    is unknown: every V channel but ``own`` (the triad: a leak from its own axes is a column of
    the twin's linear terms, a misalignment), the temperatures (a leak from them has the drift's
    signature) and the set-points."""
    setpoints = set(rec.meta.get("setpoints") or ()) | {"theta", "phi", "rate", "pulse"}
    return tuple(c for c in rec.channels if rec.units.get(c) == "V" and c not in own and c not in setpoints
                 and not c.startswith("temp"))


def at_rail(rec: Recording, ch: str, medians: np.ndarray, min_bits: int = 6) -> np.ndarray:
    """Which positions' medians of channel ``ch`` sit at the converter's rail (bool, per median):
    the channel's lowest (highest) value is a rail when it is -2^n q (2^n q or (2^n - 1) q), n >=
    ``min_bits``, q the channel's ADC step, i.e. a bipolar converter's end code, and a position
    whose median is within q of it was clipped (its voltage is beyond the rail, unknown)."""
    x = np.asarray(rec.channels[ch], float)
    if x.size == 0:
        return np.zeros(np.shape(medians), bool)
    return rail_positions(float(x.min()), float(x.max()), adc_step(rec, ch), medians, min_bits)


def rail_positions(lo: float, hi: float, q: float, medians: np.ndarray, min_bits: int = 6) -> np.ndarray:
    """:func:`at_rail` from the channel's lowest and highest values ``lo``, ``hi`` and its step ``q``."""
    out = np.zeros(np.shape(medians), bool)
    if not q > 0:
        return out
    for v in (lo, hi):
        n = abs(v) / q
        if n >= 2 ** min_bits and min(abs(n - 2 ** round(np.log2(n))), abs(n + 1 - 2 ** round(np.log2(n + 1)))) < 0.01:
            out |= np.abs(np.asarray(medians, float) - v) <= q
    return out


def adc_step(rec: Recording, ch: str) -> float:
    """The ADC step q (V) of channel ``ch`` of ``rec`` (0.0 when neither the metadata nor the values show one)."""
    return step_of(rec.meta, ch, rec.channels[ch], rec.channel_quantum)


def adc_range(rec: Recording) -> float | None:
    """The converter's full scale +-range (V) from the metadata, or None."""
    r = (rec.meta.get("adc") or {}).get("range_V") or (rec.meta.get("inferred") or {}).get("adc_range_V")
    return float(r) if r else None


def raw_channel_tests(rec: Recording, ch: str, alpha: float = 0.01) -> dict:
    """Each raw-sample effect's test on channel ``ch``; a test that fires reports its finding under
    the effect's ``finding_key``; the step used is reported as ``adc_step_V``."""
    q = adc_step(rec, ch)
    view = RawChannelView(channel=ch, samples=rec.channels[ch], time_s=rec.time_s, quantum_V=q,
                          range_V=adc_range(rec), alpha=alpha)
    out = {"adc_step_V": q}
    out.update(run_tests(RawChannelView.kind, view))
    return out


#: a sample whose static residual lies this many robust sigma from its running median is a spike
SPIKE_SIGMAS = 8.0
#: the running median's length (samples): odd, and longer than twice a cable fault's 1-3 samples
SPIKE_WINDOW = 7


def despike(f: np.ndarray, r: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, list[int]]:
    """(f with its spikes replaced, spikes per axis). A loose contact (the library's cable fault
    spikes) adds steps of a few samples far above the noise; in a 0.1-s block mean through a move
    one of them weighs like a delay, and the move-clustered SE cannot tell it from one (a 50-Hz
    record with 0.2-V spikes gave t = 2.8). Per axis, r = f_meas - f_ref(sp) the static residual
    (smooth through a move but for tau df/dt, a box the running median keeps), its running median
    m over ``SPIKE_WINDOW`` samples, the robust sigma s = 1.4826 MAD(r - m) (at least q / sqrt(12),
    q the axis' ADC step in m/s^2); samples with |r - m| > ``SPIKE_SIGMAS`` s are spikes and take
    f_ref + m. Gaussian noise passes 8 sigma once in 1e15 samples, so a record without spikes is
    left as it is."""
    f = np.array(f, float)
    counts = []
    for j in range(f.shape[1]):
        m = scipy.ndimage.median_filter(r[:, j], size=SPIKE_WINDOW, mode="nearest")
        d = r[:, j] - m
        sig = max(1.4826 * float(np.median(np.abs(d - np.median(d)))), float(q[j]) / np.sqrt(12), 1e-300)
        bad = np.abs(d) > SPIKE_SIGMAS * sig
        f[bad, j] -= d[bad]
        counts.append(int(bad.sum()))
    return f, counts
