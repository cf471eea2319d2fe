"""Pre-processing of recordings (seed appendix C.1): anti-alias low-pass, downsampling,
per-position statistics.
"""
from __future__ import annotations

import numpy as np
from scipy import signal

from imurig.calibration.window_filter import lowpass_windows
from imurig.kernel.errors import RecordingError
from imurig.kernel.recording import Recording


def lowpass_downsample(rec: Recording, rate_hz: float = 100.0, cutoff_hz: float = 50.0, order: int = 5,
                       zero_phase: bool = True, windows_only: bool = False) -> Recording:
    """Digital low-pass then keep every k-th sample, per contiguous block (seed C.1.1).

    The seed filters 1 kHz data with a 5th-order Butterworth, Wn = 50 / (1000 / 2), then
    downsamples to 100 Hz. Any sample rate goes in: when fs / rate_hz is not a whole number the
    record keeps every k-th sample with k = floor(fs / rate_hz) (>= 1), i.e. the nearest rate at or
    above ``rate_hz`` that the samples give without interpolation (102.4 Hz stays 102.4 Hz, 250 Hz
    becomes 125 Hz); a cut-off at or above the Nyquist frequency is lowered to 0.8 x Nyquist.
    The rate reached is in ``meta['sample_rate_hz']`` and the preprocessing log. ``zero_phase`` runs the filter forwards and backwards
    (scipy ``sosfiltfilt``), which keeps the per-position windows aligned in time.
    Truth signals are filtered the same way so that they stay comparable.
    ``windows_only`` (zero phase only) filters just the segments' acquisition windows, one
    window at a time, and decimates the rest unfiltered (:mod:`imurig.calibration.window_filter`): the
    same values in the windows, in bounded memory.
    """
    fs = rec.sample_rate_hz
    if not (np.isfinite(rate_hz) and rate_hz > 0 and cutoff_hz > 0):
        raise RecordingError(f"rate_hz ({rate_hz}) and cutoff_hz ({cutoff_hz}) must be positive")
    ratio = fs / rate_hz
    if abs(ratio - round(ratio)) <= 1e-6 and round(ratio) >= 1:
        k = int(round(ratio))
    else:
        k = max(int(np.floor(ratio)), 1)
        rate_hz = fs / k
    cutoff_hz = min(cutoff_hz, 0.8 * fs / 2)
    sos = signal.butter(order, cutoff_hz / (fs / 2), output="sos")
    keep_idx, blocks = [], rec.blocks()
    names = list(rec.channels)
    # truth signals: filter the measured quantities the same way; decimate the rest unfiltered
    tnames = [n for n in rec.truth_signals if rec.truth_units.get(n) in ("m/s^2", "rad/s", "T")]
    others = [n for n in rec.truth_signals if n not in tnames]
    setpoints = set(rec.meta.get("setpoints", []))
    log = {"step": "lowpass_downsample", "filter": f"butterworth order {order}", "cutoff_hz": cutoff_hz,
           "zero_phase": zero_phase, "from_hz": fs, "to_hz": rate_hz}
    if windows_only and zero_phase and rec.n_segments:
        idx, channels, tsig = lowpass_windows(rec, sos, k, [n for n in names if n not in setpoints], tnames)
        return _decimated(rec, idx, channels, tsig, rate_hz, {**log, "where": "segment windows"})
    x = rec.stack(names) if names else np.zeros((rec.n, 0))
    xt = np.stack([rec.truth_signals[n] for n in tnames], 1) if tnames else np.zeros((rec.n, 0))
    out_x, out_t = [], []
    for b in blocks:
        seg = x[b]
        segt = xt[b]
        padlen = min(3 * (2 * len(sos) + 1), seg.shape[0] - 1)
        if zero_phase:
            fx = signal.sosfiltfilt(sos, seg, axis=0, padlen=padlen) if seg.shape[1] else seg
            ft = signal.sosfiltfilt(sos, segt, axis=0, padlen=padlen) if segt.shape[1] else segt
        else:
            fx = signal.sosfilt(sos, seg, axis=0)
            ft = signal.sosfilt(sos, segt, axis=0)
        idx = np.arange(b.start, b.stop, k)
        keep_idx.append(idx)
        out_x.append(fx[::k])
        out_t.append(ft[::k])
    idx = np.concatenate(keep_idx)
    fx = np.concatenate(out_x)
    ft = np.concatenate(out_t)
    # set-point channels are step functions: decimate them without filtering
    channels = {n: (rec.channels[n][idx] if n in setpoints else fx[:, i]) for i, n in enumerate(names)}
    return _decimated(rec, idx, channels, {**{n: ft[:, i] for i, n in enumerate(tnames)},
                                           **{n: rec.truth_signals[n][idx] for n in others}}, rate_hz, log)


def _decimated(rec: Recording, idx, channels: dict, truth_signals: dict, rate_hz: float, log: dict) -> Recording:
    """The downsampled Recording (samples ``idx`` of ``rec``) with its preprocessing log entry."""
    meta = dict(rec.meta)
    meta["sample_rate_hz"] = rate_hz
    meta["preprocessing"] = list(meta.get("preprocessing", [])) + [log]
    return Recording(time_s=rec.time_s[idx], channels=channels, units=dict(rec.units),
                     segments=dict(rec.segments), segment_units=dict(rec.segment_units), meta=meta,
                     truth=rec.truth, truth_signals=truth_signals,
                     truth_units=dict(rec.truth_units))


def clipped_mean(x: np.ndarray, axis: int = 0, k: float = 6.0) -> np.ndarray:
    """The mean of the values within k * max(s_MAD, q) + q of the median along ``axis``:

        m = median(x),  s_MAD = 1.4826 median|x - m|,  q = the smallest step between distinct values,
        clipped mean = mean{x_i : |x_i - m| <= k max(s_MAD, q) + q}.

    Robust to spikes like the median, but for values on an ADC's grid (q larger than or near the
    noise) it averages the codes where the median stays on the grid (error up to q/2 that no
    number of samples reduces)."""
    x = np.asarray(x, float)
    med = np.median(x, axis=axis, keepdims=True)
    mad = 1.4826 * np.median(np.abs(x - med), axis=axis, keepdims=True)
    d = np.diff(np.sort(x, axis=axis), axis=axis)
    q = np.min(np.where(d > 0, d, np.inf), axis=axis, keepdims=True) if d.shape[axis] else np.zeros_like(med)
    q = np.where(np.isfinite(q), q, 0.0)
    keep = np.abs(x - med) <= k * np.maximum(mad, q) + q
    return np.sum(np.where(keep, x, 0.0), axis=axis) / np.sum(keep, axis=axis)


def segment_statistic(rec: Recording, names, statistic: str = "median", source: str = "channels") -> np.ndarray:
    """Per-segment statistic (n_seg, len(names)) of channels (or truth signals).

    statistic: 'median' (seed C.1.1, robust to spikes), 'mean', 'clipped_mean' (:func:`clipped_mean`,
    robust and not held to an ADC's grid) or 'std'.
    """
    if not rec.n_segments:
        raise RecordingError("the recording has no segments (set-point windows); add a 'segment' column "
                             "or name the set-point columns in the '# setpoints:' metadata")
    data = rec.channels if source == "channels" else rec.truth_signals
    fn = {"median": np.median, "mean": np.mean, "clipped_mean": clipped_mean, "std": np.std}.get(statistic)
    if fn is None:
        raise ValueError(f"statistic must be median, mean, clipped_mean or std; got {statistic!r}")
    x = np.stack([data[n] for n in names], axis=1)
    out = np.empty((rec.n_segments, len(names)))
    for i, s in enumerate(rec.segment_slices()):
        if s.stop - s.start < 1:
            raise RecordingError(f"segment {i} ({rec.segments['start_s'][i]:.3f}-{rec.segments['stop_s'][i]:.3f} s)"
                                 " holds no samples; check the segment times against time_s")
        out[i] = fn(x[s], axis=0)
    return out


def segment_statistic_variance(rec: Recording, names, statistic: str = "median", batches: int = 10) -> np.ndarray:
    """Variance (n_seg, len(names)) of each segment's statistic from its own samples, by batch means.

    Each window is cut into ``batches`` consecutive batches; the statistic of the whole window
    has variance ~ var(batch statistics) / batches (exact for the mean of noise that decorrelates
    within a batch; for the median both scale as 1/N). Noise slower than a batch is not seen.
    """
    data = np.stack([rec.channels[n] for n in names], axis=1)
    fn = {"median": np.median, "mean": np.mean, "clipped_mean": clipped_mean}.get(statistic)
    if fn is None:
        raise ValueError(f"statistic must be median, mean or clipped_mean; got {statistic!r}")
    out = np.full((rec.n_segments, len(names)), np.nan)
    for i, sl in enumerate(rec.segment_slices()):
        n = (sl.stop - sl.start) // batches
        if n >= 2:
            x = data[sl.start:sl.start + n * batches].reshape(batches, n, -1)
            out[i] = np.var(fn(x, axis=1), axis=0, ddof=1) / batches
    return out


def segment_samples(rec: Recording, names) -> tuple[np.ndarray, np.ndarray]:
    """All samples inside segments: (values (m, len(names)), segment index (m,))."""
    sl = rec.segment_slices()
    idx = np.concatenate([np.arange(s.start, s.stop) for s in sl])
    seg = np.concatenate([np.full(s.stop - s.start, i) for i, s in enumerate(sl)])
    return rec.stack(names)[idx], seg
