"""Saturation and clipping: the converter (or the sensor's output stage) cannot go beyond its range.

    v'(t) = min(max(v(t), -range_V), +range_V)                       [V],  on ``channel``

Stage "analog" (applied per line before the converter; the simulator's DAQ clips its codes too).

Diagnosis (:class:`~imurig.sensors.effects.views.RawChannelView`, the channel as logged): a clip
is a flat top, a run of samples held at the record's extreme level L (max or min) within
q / 2 (q: the ADC step; 1e-9 |L| for unquantised values). Without clipping, a sample x + e (e white,
sd sigma before the rounding) repeats the code L of the one before with probability
p_L = Phi((L + q/2 - x) / sigma) - Phi((L - q/2 - x) / sigma), at most P = 2 Phi(q / (2 sigma)) - 1
(x at the code's centre, the worst phase), so k equal samples in a row at L have probability at
most P^(k-1); runs of at least k_min = max(3, 1 + log(alpha / n) / log P) samples are flat tops (up to P = ``MAX_REPEAT``).
sigma is the noise before the rounding, bounded from below by the noise as logged, s: a position's
codes x + e + r (r the rounding error, |r| <= q / 2) have sd at most sigma + q / 2 whatever the
phase of x on the grid, so sigma >= s - q / 2 (an underestimated sigma only raises P: the bound
keeps the level; Sheppard's sigma^2 = s^2 - q^2 / 12 holds only averaged over uniform phases,
which a few dozen positions are not: on 12-bit records with sigma = 0.3 q it gave 0.35 q).
s^2 = var(diff2) / 6 from the second differences (free of a slow signal's slope), their mean
square within 5 robust sigma of the median (a slew's corners and spikes cut). (The
earlier P = q / (2 sqrt(pi) s), the chance that a first difference rounds to zero averaged over
the phase, with s from the MAD of the differences, which is a whole number of steps where the
noise is near q, gave runs of 22 where codes repeat with probability 0.9: a 12-bit record whose
converter noise is 0.3 q named a flat top at an unclipped position.) Where the step exceeds the noise (P near 1: every sample repeats its code)
a run proves nothing, and only the converter's known range can: the level must lie within 1.5 q
of +-range_V. The finding reports the level (V), the clipped fraction of the record, the number
of runs and the first clipped time.

Diagnosis (:class:`~imurig.sensors.effects.base.PositionView`, the static positions' regression):
a clip before the converter is not a run of equal codes (the converter's own noise dithers it),
but the reading no longer follows the input. In the inverse model (the twin's reference
y = X0 beta + e from the indicated readings) positions whose input passes the limit read the
limit instead, so the twin misses y by the reference's excess over the limit:

    C(L) = max(y - L, 0)        (upper limit; min(y - L, 0) for a lower one)    [m/s^2]

with coefficient ~1 (the nominal scale). L is scanned over the gaps between the reference's
distinct levels (8 values per gap), and a value is offered only where the clipped set S = {y > L}
holds at least two distinct reference levels whose indicated readings are flat: the slope of the
reading against the reference over S is below 1/2 (0 when clipped, 1 when not). The engine's
max-statistic threshold, simulated over the whole library and every offered (side, L), pays
for the scan. The limit in volts is refitted from the clipped positions' mean readings
(:func:`limit_from_samples`).
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from scipy.optimize import minimize
from scipy.stats import norm

from imurig.sensors.effects.base import Candidate, ChainContext, Effect, Param, PositionView
from imurig.sensors.effects.views import RawChannelView


#: above this chance that a sample repeats the code before it, a run of equal codes proves nothing
#: (k_min would exceed ~1000 samples at alpha / n = 1e-7) and only the converter's range can
MAX_REPEAT = 0.985


def _runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(starts, lengths) of the runs of True in ``mask``."""
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    starts, stops = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
    return starts, stops - starts


@dataclass
class Saturation(Effect):
    """Clipping of ``channel`` at +-``range_V`` (V)."""

    enabled: bool = False
    channel: str = "acc_x"
    range_V: float = 5.0

    name: ClassVar[str] = "saturation"
    stage: ClassVar[str] = "analog"
    physics: ClassVar[str] = "the channel is clipped at the end of its range (flat tops at a constant level)"
    seed_section: ClassVar[str] = "2 (the DAQ's +-5 V range)"
    seed_says: ClassVar[str] = "– (the seed's signals stay inside the converter's range)"
    params: ClassVar[tuple] = (Param("level_V", "V"), Param("fraction", "1"),
                               Param("upper_limit_V", "V", note="the refitted clip limit (positions' means)"),
                               Param("lower_limit_V", "V", note="the refitted clip limit (positions' means)"),
                               Param("excess", "1", note="coefficient of max(y - L, 0) in the inverse model (~1)"))
    views: ClassVar[tuple] = (RawChannelView.kind, PositionView.kind)
    finding_key: ClassVar[str] = "finding_saturation"

    def lines(self, names, ctx: ChainContext | None = None) -> list[str]:
        if not self.enabled:
            return []
        if self.channel not in names:
            raise ValueError(f"saturation on '{self.channel}', which is not an analog line; choose one of {sorted(names)}")
        return [self.channel]

    def inject(self, v: np.ndarray, ctx: ChainContext | None = None, rng: np.random.Generator | None = None) -> np.ndarray:
        """v clipped to [-range_V, +range_V] (module doc)."""
        return np.clip(v, -self.range_V, self.range_V) if self.enabled else v

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        """{level_V}: the clip level on ``channel`` (0 where nothing is clipped)."""
        c = (truth.get("chain") or {}).get("saturation") or {}
        on = bool(c.get("enabled")) and (channel is None or channel == c.get("channel"))
        return {"level_V": float(c["range_V"]) if on else 0.0}

    #: values of L scanned in each gap between distinct reference levels
    scan_per_gap: ClassVar[int] = 8
    #: the largest slope of the indicated reading against the reference over a clipped set (0 clipped, 1 not)
    max_flat_slope: ClassVar[float] = 0.5

    def candidates(self, view: PositionView) -> list[Candidate]:
        """The clipping hinge C(L) = max(y - L, 0) (upper) or min(y - L, 0) (lower) of the module doc,
        scanned over (side, L) with L in the gaps of the reference where the clipped readings are flat."""
        ref = getattr(view, "reference", None)
        u = (view.readings or {}).get(f"a{view.axis}")
        if ref is None or u is None or len(ref) < 8:
            return []
        ref, u = np.asarray(ref, float), np.asarray(u, float)
        scan = [(side, L) for side in (1.0, -1.0) for L in clip_grid(ref, u, side, self.scan_per_gap,
                                                                       self.max_flat_slope)]
        if not scan:
            return []
        return [Candidate(self.name, "the channel's output saturates: beyond a limit L the reading stays at L",
                          ("excess",), lambda th, y=ref: hinge(y, *th), scan=tuple(scan), scan_name="side, limit_m_s2")]

    def test(self, view: RawChannelView) -> dict:
        """The flat-top test at both extremes (module doc); 'finding' when one holds."""
        x = np.asarray(view.samples, float)
        if x.size < 10:
            return {}
        q = float(view.quantum_V or 0.0)
        s, sigma = _noise_before_rounding(x, q)
        extremes = (float(np.max(x)), float(np.min(x)))
        runs = {L: _runs(np.abs(x - L) <= flat_tolerance(L, q)) for L in extremes}
        return flat_top_result(view, x.size, s, sigma, extremes, runs,
                               lambda i: float(np.asarray(view.time_s)[i]))


def flat_tolerance(L: float, q: float) -> float:
    """A sample is at the level L when within this of it: q / 2 (1e-9 |L| for unquantised values)."""
    return max(0.5 * q, 1e-9 * abs(L))


def flat_top_result(view, n: int, s: float, sigma: float, extremes, runs: dict, time_at) -> dict:
    """The flat-top test's output from the record's statistics: ``n`` samples, the noise ``s`` and
    ``sigma`` (:func:`_noise_before_rounding`), ``extremes`` (max, min), ``runs`` {L: (starts,
    lengths)} of the samples within :func:`flat_tolerance` of L, ``time_at(i)`` the time of sample i.
    ``view``: channel, quantum_V, range_V, alpha (a :class:`RawChannelView`, its samples unused)."""
    q = float(view.quantum_V or 0.0)
    P = (1.0 if sigma <= 0 else float(2 * norm.cdf(q / (2 * sigma)) - 1)) if q > 0 else 0.0
    k_min = 3 if P <= 0 else (np.inf if P >= MAX_REPEAT else max(3, int(np.ceil(1 + np.log(view.alpha / n) / np.log(P)))))
    out = {"saturation_noise_V": s, "saturation_min_run": None if not np.isfinite(k_min) else int(k_min)}
    best = None
    for L in extremes:
        starts, lengths = runs[L]
        at_range = view.range_V is not None and abs(L) >= float(view.range_V) - 1.5 * q
        keep = lengths >= (2 if at_range else k_min)
        if not keep.any():
            continue
        m = int(lengths[keep].sum())
        if best is None or m > best["samples"]:
            best = {"effect": Saturation.name, "physics": f"'{view.channel}' is clipped at {L:.6g} V (flat tops)",
                    "level_V": L, "fraction": m / n, "samples": m, "runs": int(keep.sum()),
                    "first_time_s": time_at(int(starts[keep][0])),
                    "evidence": "at the converter's range" if at_range else
                                f"runs of >= {int(k_min)} equal samples where the noise ({s:.3g} V) resolves the step"}
    if best is not None:
        out["finding"] = best
    elif not np.isfinite(k_min) and view.range_V is None:
        out["saturation_tested"] = "no: the ADC step exceeds the noise and the converter's range is unknown"
    return out


def _noise_before_rounding(x: np.ndarray, q: float) -> tuple[float, float]:
    """(s, sigma) (V) of samples x on a grid of step q (0: unquantised): s the noise as logged, from
    the second differences (var 6 s^2 for white noise), their mean square within 5 robust sigma of
    the median (a slew's corners and spikes cut; the robust sigma at least q, as a MAD of whole
    steps can be 0); sigma = max(s - q / 2, 0), a lower bound of the noise before the rounding
    (module doc)."""
    d2 = np.diff(x, 2)
    c = np.median(d2)
    cut = noise_cut(float(np.median(np.abs(d2 - c))), q)
    inner = d2[np.abs(d2 - c) <= cut] if cut > 0 else d2
    return noise_from_moments(float(np.sum((inner - c) ** 2)) if inner.size else 0.0, inner.size, q)


def noise_cut(mad: float, q: float) -> float:
    """The cut of :func:`_noise_before_rounding`: 5 max(1.4826 MAD, q)."""
    return 5 * max(1.4826 * mad, q)


def noise_from_moments(sum_sq: float, count: int, q: float) -> tuple[float, float]:
    """(s, sigma) of :func:`_noise_before_rounding` from the sum of squares of the kept second
    differences about their median and their count."""
    s2 = sum_sq / count / 6 if count else 0.0
    s = float(np.sqrt(max(s2, q * q / 12)))
    return s, max(s - q / 2, 0.0)


def hinge(y: np.ndarray, side: float, limit: float) -> np.ndarray:
    """max(y - L, 0) for side +1 (an upper limit), min(y - L, 0) for side -1 (a lower one)."""
    return np.maximum(side * (np.asarray(y, float) - limit), 0.0) * side


def _levels(y: np.ndarray) -> np.ndarray:
    """The distinct levels of ``y`` (values closer than 1e-3 of its span are one level), sorted."""
    v = np.sort(np.asarray(y, float))
    tol = 1e-3 * max(float(np.ptp(v)), 1e-12)
    return v[np.concatenate([[True], np.diff(v) > tol])]


def clip_grid(ref: np.ndarray, u: np.ndarray, side: float, per_gap: int = 8, max_slope: float = 0.5) -> list[float]:
    """Limits L (m/s^2) to scan on one side: ``per_gap`` values inside each gap between the reference's
    distinct levels such that the clipped set S = {side (y - L) > 0} holds >= 2 levels and the
    reading u against y over S has a slope below ``max_slope`` (flat: the reading ignores the input)."""
    lv = _levels(ref)[::-1] if side > 0 else _levels(ref)      # from the clipped end inwards
    out = []
    for k in range(2, lv.size - 2):           # S = the first k levels; keep >= 2 levels outside S
        S = side * (ref - 0.5 * (lv[k - 1] + lv[k])) > 0
        dy = ref[S] - ref[S].mean()
        slope = float(dy @ (u[S] - u[S].mean()) / (dy @ dy))
        if abs(slope) < max_slope:
            out += [float(lv[k] + (lv[k - 1] - lv[k]) * (i + 0.5) / per_gap) for i in range(per_gap)]
    return out


def _rounded_gaussian_nll(x: float, log_s: float, k: np.ndarray, n: np.ndarray) -> float:
    """-log likelihood of code counts n at codes k (units of q) for round(x + N(0, s^2))."""
    s = np.exp(log_s)
    p = norm.cdf((k + 0.5 - x) / s) - norm.cdf((k - 0.5 - x) / s)
    return -float(n @ np.log(np.maximum(p, 1e-300)))


def _mle_limit(codes: np.ndarray) -> tuple[float, float] | None:
    """(x, SE) in units of q: the maximum-likelihood level of integer codes round(x + N(0, s^2)),
    SE from the observed information (numerical Hessian in (x, log s)); None below two codes."""
    k, n = np.unique(codes, return_counts=True)
    if k.size < 2:
        return None
    m = float(n @ k) / n.sum()
    s0 = max(float(np.sqrt(n @ (k - m) ** 2 / n.sum())), 0.05)
    res = minimize(lambda t: _rounded_gaussian_nll(t[0], t[1], k, n), [m, np.log(s0)], method="Nelder-Mead",
                   options={"xatol": 1e-7, "fatol": 1e-9, "maxiter": 2000})
    t, h = res.x, 1e-3
    H = np.empty((2, 2))
    f = lambda a, b: _rounded_gaussian_nll(t[0] + a, t[1] + b, k, n)
    for i, j in ((0, 0), (0, 1), (1, 1)):
        e_i, e_j = np.eye(2)[i] * h, np.eye(2)[j] * h
        H[i, j] = H[j, i] = (f(*(e_i + e_j)) - f(*(e_i - e_j)) - f(*(e_j - e_i)) + f(*(-e_i - e_j))) / (4 * h * h)
    try:
        cov = np.linalg.inv(H)
    except np.linalg.LinAlgError:
        return None
    return (float(t[0]), float(np.sqrt(cov[0, 0]))) if cov[0, 0] > 0 else None


def limit_from_samples(x_V: list[np.ndarray], quantum_V: float = 0.0) -> tuple[float, float]:
    """The clip limit L (V) and its standard error from the logged samples of the clipped positions.

    A clip before the converter leaves L + n_adc, rounded to the step q: the samples' mean is
    biased by the rounding where the converter's own noise s_n is not >> q (by up to
    q exp(-2 pi^2 s_n^2 / q^2) / pi), so where q > 0 and the spread is below 2 q, L is the
    maximum-likelihood level of the pooled codes under code = round((L + N(0, s_n^2)) / q)
    (SE from the observed information; one code only: that code +- q / sqrt(12)). Otherwise L is
    the mean of the positions' means. Either SE is at least the positions' means' scatter
    sd / sqrt(|S|) (a limit that moves from position to position).
    """
    means = np.array([np.mean(v) for v in x_V])
    se_pos = float(np.std(means, ddof=1) / np.sqrt(means.size)) if means.size > 1 else 0.0
    allx = np.concatenate(x_V)
    q = float(quantum_V or 0.0)
    if q > 0 and np.std(allx) < 2 * q:
        codes = np.rint(allx / q).astype(np.int64)
        fit = _mle_limit(codes)
        L, se = (q * fit[0], q * fit[1]) if fit is not None else (q * float(codes[0]), q / np.sqrt(12))
        return float(L), float(max(se, se_pos))
    return float(means.mean()), se_pos
