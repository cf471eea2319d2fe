"""Pre-processing of recordings (seed appendix C.1): anti-alias low-pass, downsampling,
per-position statistics.
"""
from __future__ import annotations

from contextlib import contextmanager

import numpy as np
from scipy import signal, special

from imurig.calibration.window_filter import lowpass_windows
from imurig.kernel.errors import RecordingError
from imurig.kernel.recording import Recording


def lowpass_downsample(rec: Recording, rate_hz: float = 100.0, cutoff_hz: float = 50.0, order: int = 5,
                       zero_phase: bool = True, windows_only: bool = False, filtered=None) -> Recording:
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
    same values in the windows, in bounded memory. ``filtered`` (with ``windows_only``): the channels and
    truth signals low-passed in the windows, e.g. just those an analysis reads (default: every channel
    but the set-points, and the truth signals above); the others are decimated as sampled, as outside
    the windows.
    """
    fs = rec.sample_rate_hz
    k, sos, log = filter_design(fs, rate_hz, cutoff_hz, order, zero_phase)
    rate_hz = log["to_hz"]
    keep_idx, blocks = [], rec.blocks()
    names = list(rec.channels)
    # truth signals: filter the measured quantities the same way; decimate the rest unfiltered
    tnames = [n for n in rec.truth_signals if rec.truth_units.get(n) in ("m/s^2", "rad/s", "T")]
    others = [n for n in rec.truth_signals if n not in tnames]
    setpoints = set(rec.meta.get("setpoints", []))
    if windows_only and zero_phase and rec.n_segments:
        low = [n for n in names if n not in setpoints and (filtered is None or n in filtered)]
        tlow = [n for n in tnames if filtered is None or n in filtered]
        idx, channels, tsig = lowpass_windows(rec, sos, k, low, tlow)
        return _decimated(rec, idx, channels, tsig, rate_hz, window_log(log, low, tlow))
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


def window_log(log: dict, channels, truth_signals) -> dict:
    """The preprocessing log entry of a low-pass in the segment windows of ``channels`` and ``truth_signals``."""
    return {**log, "where": "segment windows", "channels": list(channels), "truth_signals": list(truth_signals)}


def filter_design(fs: float, rate_hz: float = 100.0, cutoff_hz: float = 50.0, order: int = 5,
                  zero_phase: bool = True) -> tuple[int, np.ndarray, dict]:
    """(k, sos, log) of :func:`lowpass_downsample` at the sample rate ``fs``: keep every k-th sample, the
    Butterworth's sections, and the preprocessing log entry (its ``to_hz``: the rate reached)."""
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
    log = {"step": "lowpass_downsample", "filter": f"butterworth order {order}", "cutoff_hz": cutoff_hz,
           "zero_phase": zero_phase, "from_hz": fs, "to_hz": rate_hz}
    return k, sos, log


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
    q = grid_step(x, axis)
    keep = np.abs(x - med) <= k * np.maximum(mad, q) + q
    return np.sum(np.where(keep, x, 0.0), axis=axis) / np.sum(keep, axis=axis)


#: Huber's tuning constant: 95 % asymptotic efficiency at the Gaussian (Huber 1964)
HUBER_K = 1.345
#: the consistency factor of the MAD at the Gaussian, 1 / Phi^-1(3/4)
MAD_SIGMA = 1.482602218505602


def grid_step(x: np.ndarray, axis: int = 0) -> np.ndarray:
    """The smallest step between distinct values along ``axis`` (keepdims; 0 where all are equal):
    an ADC's step q for values logged on its grid, ~0 for continuous (filtered, averaged) values."""
    d = np.diff(np.sort(x, axis=axis), axis=axis)
    if not d.shape[axis]:
        return np.zeros_like(np.take(x, [0], axis=axis))
    q = np.min(np.where(d > 0, d, np.inf), axis=axis, keepdims=True)
    return np.where(np.isfinite(q), q, 0.0)


def huber_scale(x: np.ndarray, axis: int = 0, median: np.ndarray | None = None) -> np.ndarray:
    """The quantisation-aware noise level of :func:`huber_location` (keepdims):

        s = max(1.4826 median|x - median(x)|, q),   q = :func:`grid_step`

    The MAD is the Gaussian sd for continuous values; on an ADC's grid it moves in half-steps and
    is 0 when most values sit on one code, so it is floored at one step: codes within k q of the
    centre are then averaged (sub-step resolution from the dither, as :func:`clipped_mean`).
    ``median``: median(x) along ``axis`` (keepdims) when already known."""
    med = np.median(x, axis=axis, keepdims=True) if median is None else median
    mad = MAD_SIGMA * np.median(np.abs(x - med), axis=axis, keepdims=True)
    return np.maximum(mad, grid_step(x, axis))


def huber_location(x: np.ndarray, axis: int = 0, k: float = HUBER_K, tol: float = 1e-10,
                   max_iter: int = 50) -> np.ndarray:
    """Huber M-estimate of location along ``axis``: the m that solves

        sum_i psi_k((x_i - m) / s) = 0,     psi_k(r) = max(-k, min(k, r)),

    s = :func:`huber_scale` (fixed, from the median and MAD). Samples within k s of m count
    fully (the mean), those beyond with bounded influence k s (a spike moves m by at most
    k s / (N (2 Phi(k) - 1)), where it moves the mean by spike / N). At the Gaussian the
    asymptotic variance is s^2 E[psi_k^2] / E[psi_k']^2 / N, efficiency :func:`huber_efficiency`
    (0.950 at k = 1.345, against 2/pi = 0.637 for the median); breakdown point 1/2 (MAD scale).

    Solved by Newton steps from the median, m <- m + s sum psi / #{|r| < k}: the sum is
    piecewise linear and decreasing in m, so a step is exact once the samples inside +-k s stay
    the same (2-4 steps); stops when a step is below ``tol`` s. Where s = 0 (all values equal)
    the median is returned."""
    x = np.moveaxis(np.asarray(x, float), axis, 0)
    m = np.median(x, axis=0)
    s = huber_scale(x, 0, m[None])[0]
    s = np.where(s > 0, s, 1.0)
    for _ in range(max_iter):
        r = (x - m) / s
        inside = np.count_nonzero(np.abs(r) < k, axis=0)
        step = s * np.sum(np.clip(r, -k, k), axis=0) / np.maximum(inside, 1)
        m = m + step
        if np.all(np.abs(step) <= tol * s + 8 * np.finfo(float).eps * np.abs(m)):
            break
    return m


def huber_efficiency(k: float = HUBER_K) -> float:
    """Asymptotic efficiency of :func:`huber_location` against the mean at the Gaussian (known scale):

        eff = (2 Phi(k) - 1)^2 / E[psi_k^2],  E[psi_k^2] = 2 Phi(k) - 1 - 2 k phi(k) + 2 k^2 (1 - Phi(k))."""
    p = 2 * special.ndtr(k) - 1
    phi = np.exp(-0.5 * k * k) / np.sqrt(2 * np.pi)
    e_psi2 = p - 2 * k * phi + 2 * k**2 * special.ndtr(-k)
    return float(p**2 / e_psi2)


#: per-position statistics by name: 'huber' (default of the tilt calibration), 'median' (the seed's,
#: C.1.1), 'mean', 'clipped_mean'
STATISTICS = {"huber": huber_location, "median": np.median, "mean": np.mean, "clipped_mean": clipped_mean}


def statistic_efficiency(statistic: str) -> float:
    """Asymptotic efficiency of a per-position statistic at Gaussian white noise (variance of the
    mean / variance of the statistic): mean 1, huber :func:`huber_efficiency`, median 2 / pi."""
    eff = {"mean": 1.0, "huber": huber_efficiency(), "median": 2 / np.pi}.get(statistic)
    if eff is None:
        raise ValueError(f"no Gaussian efficiency for statistic {statistic!r}; known: huber, median, mean")
    return eff


def _statistic_fn(statistic: str, extra: dict | None = None):
    fns = {**STATISTICS, **(extra or {})}
    fn = fns.get(statistic)
    if fn is None:
        raise ValueError(f"statistic must be one of {', '.join(fns)}; got {statistic!r}")
    return fn


#: statistics evaluated on all windows of one length at once (for these a loop over the windows
#: costs more than the statistic); the others keep the per-window loop of earlier releases
STACKED = ("huber",)


def _windows(fn, x: np.ndarray, starts, length: int, stacked: bool, axis: int = 0) -> np.ndarray:
    """fn over the windows x[start:start + length] (reshaped by the caller's ``axis`` convention)."""
    if stacked:
        idx = np.asarray(starts)[:, None] + np.arange(length)
        return fn(x[idx], axis=axis + 1)
    return np.stack([fn(x[s0:s0 + length], axis=axis) for s0 in starts])


#: results of segment_statistic / segment_statistic_covariance kept inside :func:`reuse_statistics`
_MEMO: dict | None = None


@contextmanager
def reuse_statistics():
    """Inside the block, :func:`segment_statistic` and :func:`segment_statistic_covariance` compute each
    result once per recording arrays and arguments and give copies of it again (e.g. the seven fits of
    one report on one record). The recording's arrays must not change inside the block."""
    global _MEMO
    outer = _MEMO
    _MEMO = {} if outer is None else outer
    try:
        yield
    finally:
        _MEMO = outer


def _memo(kind: tuple, rec: Recording, data, names, compute) -> np.ndarray:
    """compute(), or inside :func:`reuse_statistics` its earlier result for the same arrays (by identity:
    time, segment bounds and the named signals, kept alive beside the result) and ``kind``."""
    if _MEMO is None:
        return compute()
    names = tuple(names)
    arrays = (rec.time_s, rec.segments.get("start_s"), rec.segments.get("stop_s"), *(data[n] for n in names))
    key = (kind, names, tuple(id(a) for a in arrays))
    if key not in _MEMO:
        _MEMO[key] = (compute(), arrays)
    return _MEMO[key][0].copy()


def segment_statistic(rec: Recording, names, statistic: str = "median", source: str = "channels") -> np.ndarray:
    """Per-segment statistic (n_seg, len(names)) of channels (or truth signals).

    statistic: 'median' (seed C.1.1, robust to spikes), 'huber' (:func:`huber_location`, robust at 95 %
    Gaussian efficiency; the tilt calibration's default), 'mean', 'clipped_mean' (:func:`clipped_mean`,
    robust and not held to an ADC's grid) or 'std'.
    """
    if not rec.n_segments:
        raise RecordingError("the recording has no segments (set-point windows); add a 'segment' column "
                             "or name the set-point columns in the '# setpoints:' metadata")
    if not hasattr(rec, "channels"):            # a FileRecord (imurig.kernel.filerecord): one segment at a time
        if source != "channels":
            raise ValueError("a file record's segment statistics are of its channels (source='channels')")
        return _segment_statistic_rows(rec, names, statistic)
    data = rec.channels if source == "channels" else rec.truth_signals
    return _memo(("statistic", statistic, source), rec, data, names,
                 lambda: _segment_statistic(rec, data, names, statistic))


def _segment_statistic_rows(rec, names, statistic: str) -> np.ndarray:
    """:func:`_segment_statistic` of a record read in row ranges (``rec.read(name, a, b)``): each
    segment's window is read alone, so the memory is one window's, not the recording's."""
    fn = _statistic_fn(statistic, {"std": np.std})
    out = np.empty((rec.n_segments, len(names)))
    for i, s in enumerate(rec.segment_slices()):
        if s.stop - s.start < 1:
            raise RecordingError(f"segment {i} ({rec.segments['start_s'][i]:.3f}-{rec.segments['stop_s'][i]:.3f} s)"
                                 " holds no samples; check the segment times against time_s")
        x = np.stack([rec.read(n, s.start, s.stop) for n in names], axis=1)
        out[i] = fn(x[None], axis=1)[0] if statistic in STACKED else fn(x, axis=0)
    return out


def _segment_statistic(rec: Recording, data, names, statistic: str) -> np.ndarray:
    fn = _statistic_fn(statistic, {"std": np.std})
    x = np.stack([data[n] for n in names], axis=1)
    out = np.empty((rec.n_segments, len(names)))
    slices = rec.segment_slices()
    for i, s in enumerate(slices):
        if s.stop - s.start < 1:
            raise RecordingError(f"segment {i} ({rec.segments['start_s'][i]:.3f}-{rec.segments['stop_s'][i]:.3f} s)"
                                 " holds no samples; check the segment times against time_s")
    lengths = np.array([s.stop - s.start for s in slices])
    for n in np.unique(lengths):
        which = np.flatnonzero(lengths == n)
        out[which] = _windows(fn, x, [slices[i].start for i in which], int(n), statistic in STACKED)
    return out


def segment_statistic_covariance(rec: Recording, names, statistic: str = "median", batches: int = 10) -> np.ndarray:
    """Covariance (n_seg, k, k) of each segment's statistic of the k channels ``names`` from its own
    samples, by batch means: the window is cut into ``batches`` consecutive batches of n samples,
    b_j the statistic of batch j (k,), and

        cov = sum_j (b_j - b_bar)(b_j - b_bar)' / ((batches - 1) batches)

    (exact for the mean of noise that decorrelates within a batch; for the median and the Huber
    M-estimate both scale as 1/N). Off the diagonal: noise the channels share (the converter's
    common mode). Noise slower than a batch is not seen. NaN where a batch holds < 2 samples."""
    return _memo(("covariance", statistic, batches), rec, rec.channels, names,
                 lambda: _segment_statistic_covariance(rec, names, statistic, batches))


def _segment_statistic_covariance(rec: Recording, names, statistic: str, batches: int) -> np.ndarray:
    data = np.stack([rec.channels[n] for n in names], axis=1)
    fn = _statistic_fn(statistic)
    k = len(names)
    out = np.full((rec.n_segments, k, k), np.nan)
    slices = rec.segment_slices()
    per_batch = np.array([(s.stop - s.start) // batches for s in slices])
    for n in np.unique(per_batch[per_batch >= 2]):
        which = np.flatnonzero(per_batch == n)
        starts = np.array([slices[i].start for i in which])
        b = _windows(lambda w, axis: fn(w.reshape(*w.shape[:axis], batches, int(n), k), axis=axis + 1),
                     data, starts, int(n) * batches, statistic in STACKED)            # (g, batches, k)
        d = b - b.mean(axis=1, keepdims=True)
        out[which] = np.einsum("gbi,gbj->gij", d, d) / ((batches - 1) * batches)
    return out


def segment_statistic_variance(rec: Recording, names, statistic: str = "median", batches: int = 10) -> np.ndarray:
    """Variance (n_seg, len(names)) of each segment's statistic from its own samples, by batch means.

    Each window is cut into ``batches`` consecutive batches; the statistic of the whole window
    has variance ~ var(batch statistics) / batches (exact for the mean of noise that decorrelates
    within a batch; for the median and the Huber M-estimate both scale as 1/N). Noise slower than
    a batch is not seen. (The diagonal of :func:`segment_statistic_covariance`.)
    """
    data = np.stack([rec.channels[n] for n in names], axis=1)
    fn = _statistic_fn(statistic)
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
