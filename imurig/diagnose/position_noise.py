"""The noise of the tilt positions' statistics where the converter's step is coarse: errors shared
by the positions that sit at one level.

A position's median of the logged codes is a code (or a half-code): its error against the true
reading x is the rounding error e(x), a sawtooth of period q (the ADC step), which the samples'
noise does not average away. Positions whose true reading is the same (the six phi positions of
one theta on the z axis, every theta = 0 / 180 position on x and y) therefore share one e(x):
their residuals in the position regression are not independent, and a column that moves slowly
over the positions (the temperature, which rises with time, and time runs theta by theta) can fit
the few independent level errors. A white-noise threshold then gives false discoveries.

The model used for the engine's simulated threshold (:func:`imurig.diagnose.engine.select_effects`,
its ``noise``) is, by default, the **rounding phase** model (:func:`_phase_noise`): the covariance of
two positions' rounding errors follows from the difference of their readings modulo q, each
harmonic h of the smoothed sawtooth contributing a_h cos(2 pi h (v_i - v_k) / q), with the
independent part each position's own sampling variance from its samples. It needs no groups, and
an effect the twin lacks that moves the readings of one reference level apart (a misalignment
moves them by a fifth of a 12-bit step) no longer counts as one shared error; nor does an accepted
effect inflate the independent part (the group model below took it from the residuals' within-group
variance, which holds the effect: on a 12-bit misalignment record the noise then looked white once
the misalignment was accepted, and the shared errors passed as a temperature drift on z).

The earlier **level-group** model (``phase=False``): per position i in level group G(i),

    e_i = sigma_r z_i + sigma_g w_G(i),        z, w ~ N(0, 1) independent

- groups: positions with the same reference level on the axis (to 1e-3 of its span) whose
  medians fall on the same code (true readings more than a step apart do not share e(x));
- sigma_g^2 = sum_k q^2 / (2 pi^2 k^2) exp(-4 pi^2 k^2 s_d^2 / q^2) / K^2: the part of the rounding
  error's variance (q^2 / 12 in all, Fourier series of the sawtooth) that a Gaussian smearing of
  sd s_d leaves common to the group (K: the nominal sensitivity, V per m/s^2). s_d is the sampling
  sd of the position's median, sqrt(pi / 2) s / sqrt(N) (s the samples' sd, N their number) where
  the medians are of the codes as logged; of a low-passed and decimated record, the converter's
  own dither sqrt(s^2 - q^2 / 12) of the raw samples (the filter averages codes);
- sigma_r^2: the pooled within-group variance of the nominal fit's residuals (whatever is
  independent from position to position), at least s_d^2 / K^2.

Where sigma_g^2 < 1 % of sigma_r^2 (a fine converter) the default white noise is kept.

The model is returned as a :class:`SharedNoise`, which carries its covariance beside the draws: the
engine simulates its threshold with the draws and gives the refitted parameters standard errors from
the covariance (:func:`imurig.diagnose.engine._model_std_errors`), so positions that share one
rounding error are not counted as independent observations of it.
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np

#: the shared part is ignored below this fraction of the independent variance
MIN_SHARED_FRACTION = 0.01


class SharedNoise:
    """The engine's ``noise`` (:func:`imurig.diagnose.engine.select_effects`) for positions that share
    rounding errors: ``noise(rng, m)`` draws one vector of the errors (unit variance on average),
    ``covariance`` (m, m) is their covariance in the same relative units, so that the engine can
    give the refitted parameters standard errors that count the shared errors once (an OLS standard
    error takes the positions of one level as independent observations of their common rounding
    error, and was ~1.6 times too small for a nonlinearity on a 16-bit, 102.4 Hz record)."""

    def __init__(self, draw: Callable[[np.random.Generator, int], np.ndarray], covariance: np.ndarray):
        self._draw = draw
        self.covariance = np.asarray(covariance, float)

    def __call__(self, rng: np.random.Generator, m: int) -> np.ndarray:
        return self._draw(rng, m)


def shared_rounding_variance(q: float, s_d: float, terms: int = 50) -> float:
    """sum_k q^2 / (2 pi^2 k^2) exp(-4 pi^2 k^2 s_d^2 / q^2) (V^2): the rounding error's variance
    common to positions at one level, after a Gaussian smearing of sd ``s_d`` (module doc)."""
    k = np.arange(1, terms + 1)
    return float(np.sum(q * q / (2 * np.pi ** 2 * k ** 2) * np.exp(-4 * np.pi ** 2 * k ** 2 * s_d ** 2 / q ** 2)))


def level_groups(ref: np.ndarray, median_V: np.ndarray, q: float) -> np.ndarray:
    """Group label per position: same reference level (1e-3 of the span) and same median code."""
    ref = np.asarray(ref, float)
    lev = np.rint(ref / (1e-3 * max(float(np.ptp(ref)), 1e-12))).astype(np.int64)
    code = np.rint(np.asarray(median_V, float) / q).astype(np.int64)
    _, inv = np.unique(np.column_stack([lev, code]), axis=0, return_inverse=True)
    return inv.ravel()


def dither_sd(samples_V: np.ndarray, slices, q: float, grid: int = 48) -> float | None:
    """The converter's noise before the rounding, sigma (V), by maximum likelihood from the codes of
    every position: the codes c of position k are round(x_k + e) / q, e ~ N(0, sigma^2), one sigma
    for all, x_k profiled per position:

        log L(sigma) = sum_k max_x sum_c n_kc log(Phi((c + 1/2 - x) q / sigma) - Phi((c - 1/2 - x) q / sigma)).

    sigma on a log grid (0.05 q to 3 q), refined by a parabola in log sigma; x by bounded Newton steps
    from each position's mean code. Where the noise is near the step, the shared rounding variance
    depends on sigma as exp(-4 pi^2 sigma^2 / q^2); the moment estimate sqrt(mean(s^2) - q^2 / 12)
    (Sheppard) is exact only averaged over uniform phases of the positions on the grid, which a few
    dozen positions sharing a few levels are not (0.23 q to 0.33 q for a true 0.3 q on 12-bit
    records, i.e. a shared variance wrong by a factor of 0.4 to 2.3). None without two positions of
    at least 10 samples or when the maximum is at the grid's end (noise far below or above q)."""
    x = np.asarray(samples_V, float) / q
    return dither_sd_from([code_histogram(x[sl]) for sl in slices], q, grid)


def code_histogram(codes: np.ndarray):
    """One position's codes (samples / q) as :func:`dither_sd_from` takes them: (codes about the
    rounded mean, their counts, the mean's offset from it), or None below 10 samples."""
    c = np.rint(codes)
    if c.size < 10:
        return None
    k, n = np.unique(c, return_counts=True)
    return k - np.rint(c.mean()), n, float(c.mean() - np.rint(c.mean()))


def dither_sd_from(hists, q: float, grid: int = 48) -> float | None:
    """:func:`dither_sd` from the positions' :func:`code_histogram` (None entries skipped)."""
    from scipy.special import ndtr   # lazy: only records on a coarse converter need it (norm.cdf's own kernel,
    #                                   without scipy.stats' argument handling: 10x faster, the same bits)
    hist = [h for h in hists if h is not None]
    if len(hist) < 2:
        return None
    sig = np.exp(np.linspace(np.log(0.05), np.log(3.0), grid))
    total = np.zeros(sig.size)
    for k, n, m in hist:
        def ll(xv):
            z_hi = (k[None, :] + 0.5 - xv[:, None]) / sig[:, None]
            p = ndtr(z_hi) - ndtr(z_hi - 1.0 / sig[:, None])
            return np.log(np.maximum(p, 1e-300)) @ n.astype(float)
        # x profiled per sigma by bounded Newton steps from the mean code (the likelihood of an
        # interval is log-concave in the location, so the maximum is unique)
        xv, h = np.full(sig.size, m), 1e-4
        for _ in range(15):
            f0, fp, fm = ll(xv), ll(xv + h), ll(xv - h)
            g, H = (fp - fm) / (2 * h), (fp - 2 * f0 + fm) / h ** 2
            step = np.clip(np.where(H < 0, -g / np.where(H < 0, H, -1.0), np.sign(g) * 0.1), -0.1, 0.1)
            xv = np.clip(xv + step, m - 1.0, m + 1.0)
            if np.max(np.abs(step)) < 1e-6:
                break
        total += ll(xv)
    i = int(np.argmax(total))
    if i == 0 or i == sig.size - 1:
        return None
    a, b, c = total[i - 1:i + 2]
    h = np.log(sig[1] / sig[0])
    shift = 0.5 * (a - c) / (a - 2 * b + c) if a - 2 * b + c < 0 else 0.0
    return float(q * np.exp(np.log(sig[i]) + h * shift))


def position_noise(y: np.ndarray, X0: np.ndarray, ref: np.ndarray, median_V: np.ndarray, quantum_V: float,
                   sensitivity: float, sd_V: np.ndarray, n_samples: np.ndarray,
                   decimated: bool = False, phase: bool = True,
                   dither_V: float | None = None) -> tuple[Callable | None, dict]:
    """(noise generator for the engine or None for white noise, the model's figures) of one axis
    (module doc). ``sd_V``, ``n_samples``: the samples' sd (V) and number per position, of the
    record the medians were taken from (``decimated``: of the raw record, the medians' being
    low-passed). ``phase``: the rounding errors' covariance from the positions' readings
    (:func:`_phase_noise`), else the level groups (the module doc's first model). ``dither_V``:
    the converter's noise before the rounding (:func:`dither_sd`) for a decimated or averaged
    statistic, in place of the moment estimate sqrt(mean(sd^2) - q^2 / 12)."""
    q = float(quantum_V or 0.0)
    if q <= 0 or not sensitivity:
        return None, {"shared_level_errors": False, "why": "the ADC step is unknown"}
    sd = np.asarray(sd_V, float)
    if decimated and dither_V is not None:
        s_d = float(dither_V)
    elif decimated:
        s_d = float(np.sqrt(max(np.mean(sd ** 2) - q * q / 12, 0.0)))
    else:
        s_d = float(np.sqrt(np.pi / 2 * np.mean(sd ** 2 / np.maximum(np.asarray(n_samples, float), 1))))
    sg2 = shared_rounding_variance(q, s_d) / sensitivity ** 2
    if phase:
        return _phase_noise(median_V, q, s_d, sensitivity, sd, n_samples, decimated)
    groups = level_groups(ref, median_V, q)
    r = y - X0 @ np.linalg.lstsq(X0, y, rcond=None)[0]
    G = groups.max() + 1
    size = np.bincount(groups, minlength=G)
    gm = np.bincount(groups, weights=r, minlength=G) / np.maximum(size, 1)
    dof = int(np.sum(size[size > 1] - 1))
    within = float(np.sum((r - gm[groups]) ** 2) / dof) if dof > 0 else np.inf
    sr2 = max(within, s_d ** 2 / sensitivity ** 2 if not decimated else 0.0, 1e-300)
    info = {"shared_level_errors": bool(np.isfinite(sr2) and sg2 >= MIN_SHARED_FRACTION * sr2 and dof > 0),
            "groups": int(G), "sigma_shared_m_s2": float(np.sqrt(sg2)),
            "sigma_independent_m_s2": float(np.sqrt(sr2)) if np.isfinite(sr2) else None, "adc_step_V": q}
    if not info["shared_level_errors"]:
        return None, info
    scale = np.sqrt(sr2 + sg2)

    def draw(rng: np.random.Generator, m: int) -> np.ndarray:
        return (np.sqrt(sr2) * rng.standard_normal(m) + np.sqrt(sg2) * rng.standard_normal(G)[groups]) / scale
    same = (groups[:, None] == groups[None, :]).astype(float)
    return SharedNoise(draw, (sr2 * np.eye(groups.size) + sg2 * same) / scale ** 2), info


def true_reading(v_V: np.ndarray, q: float, s_d: float, iterations: int = 30) -> np.ndarray:
    """The readings x (V) whose smoothed rounding gives the statistics v: v = x + E r(x), the mean
    rounding error of x + e (e ~ N(0, s_d^2)) on a grid of step q,

        E r(x) = q sum_h (-1)^h / (pi h) exp(-2 pi^2 h^2 s_d^2 / q^2) sin(2 pi h x / q),

    solved by the fixed point x <- v - E r(x) (a contraction: |d E r / dx| <= 2 exp(-2 pi^2 s_d^2 / q^2),
    0.34 at s_d = 0.3 q; no correction where s_d < 0.2 q, where it would not converge). The rounding
    phase of a position is that of x, not of v: at s_d = 0.3 q they differ by up to 0.34 rad, and
    the shared errors' covariance from v's phases left a part of them outside the model's span."""
    v = np.asarray(v_V, float)
    if s_d < 0.2 * q:
        return v
    h = np.arange(1, 21)
    c = q * (-1.0) ** h / (np.pi * h) * np.exp(-2 * np.pi ** 2 * h ** 2 * s_d ** 2 / q ** 2)
    x = v.copy()
    for _ in range(iterations):
        x = v - np.sin(2 * np.pi * np.outer(x, h) / q) @ c
    return x


def _phase_noise(v_V: np.ndarray, q: float, s_d: float, sensitivity: float, sd_V: np.ndarray,
                 n_samples: np.ndarray, decimated: bool) -> tuple[Callable | None, dict]:
    """The rounding errors' covariance from the positions' own readings v (V), the offset of the
    converter's grid taken as uniform: the smoothed sawtooth's harmonics give

        cov(e_i, e_k) = sum_h a_h cos(2 pi h (v_i - v_k) / q) / K^2,
        a_h = q^2 / (2 pi^2 h^2) exp(-4 pi^2 h^2 s_d^2 / q^2),

    so positions whose readings differ by a whole number of steps share their error, and positions
    half a step apart have opposite ones, whatever the reference says (an effect the twin lacks
    moves the readings of one reference level apart: a 1 mrad misalignment on a 12-bit converter
    moves them by up to 0.2 q, which the level groups counted as one shared error). The
    independent part is each position statistic's own sampling variance, from its samples
    (mean of s^2 / N for averaged codes, the median's s_d^2), not the residuals (which hold every
    effect the twin lacks). Draws: e_i = sigma_r z_i + sum_h sqrt(a_h) (cos(2 pi h v_i / q) w_h
    + sin(2 pi h v_i / q) w'_h) / K, scaled to unit variance."""
    v = np.asarray(v_V, float)
    h = np.arange(1, 51)
    a = q * q / (2 * np.pi ** 2 * h ** 2) * np.exp(-4 * np.pi ** 2 * h ** 2 * s_d ** 2 / q ** 2)
    keep = a > 1e-6 * a[0]
    h, a = h[keep], a[keep]
    sg2 = float(a.sum()) / sensitivity ** 2
    sd, n = np.asarray(sd_V, float), np.maximum(np.asarray(n_samples, float), 1)
    sr2 = max(float(np.mean(sd ** 2 / n)) if decimated else s_d ** 2, 1e-300) / sensitivity ** 2
    info = {"shared_level_errors": bool(sg2 >= MIN_SHARED_FRACTION * sr2), "model": "rounding phase",
            "dither_sd_V": s_d,
            "harmonics": int(h.size), "sigma_shared_m_s2": float(np.sqrt(sg2)),
            "sigma_independent_m_s2": float(np.sqrt(sr2)), "adc_step_V": q}
    if not info["shared_level_errors"]:
        return None, info
    ph = 2 * np.pi * np.outer(true_reading(v, q, s_d), h) / q
    B = np.hstack([np.cos(ph), np.sin(ph)]) * np.sqrt(np.concatenate([a, a]))[None, :] / sensitivity
    scale = np.sqrt(sr2 + sg2)

    def draw(rng: np.random.Generator, m: int) -> np.ndarray:
        return (np.sqrt(sr2) * rng.standard_normal(m) + B @ rng.standard_normal(B.shape[1])) / scale
    return SharedNoise(draw, (sr2 * np.eye(v.size) + B @ B.T) / scale ** 2), info
