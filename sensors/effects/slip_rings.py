"""Slip-ring contact noise of the turn table (seed 4.4.1, Fig. 4.16): every line that leaves the
IMU crosses one of the table's 16 rings, whose brushes are noisier at rough spots.

    v_noise(t) = rms (1 + depth p(theta(t))) n(t),  n ~ N(0, 1) white                  [V]
    p(theta)   = sum over the rough spots s of exp(kappa (cos(theta - theta_s) - 1))

theta: the table angle (rad). The noise is periodic in the table angle; its variance at angle
theta is rms^2 P(theta)^2 with P = 1 + depth p (the profile). Stage "analog": the chain adds it
to every IMU line while the table turns (one random stream per line, "slip_<line>"); the
profile depends on the record's angles only, so it is computed once per record and reused for
every line.

Diagnosis (:class:`TurnSampleView`): the samples' fast residual r (the line less its running
mean over ``window`` samples) binned by table angle into ``n_bins`` bins; the Brown-Forsythe
test (Levene, median-centred; with the acquisition window as a block where the view gives the
windows: :meth:`SlipRingNoise.brown_forsythe_within_windows`) asks whether the spread is the same in every bin (not where the
median bin's robust spread is below the ADC step's q / sqrt(12): the step, not the noise, is then
seen). The refit: the
excess noise variance of each bin over the median bin,

    e_b = mean_b(r^2) - median_b' mean_b'(r^2)                                         [V^2]

with its standard error from the bin's own fourth moment (and the median's), and the excess
noise amplitude sqrt(e_b) (V) per angle, reported with the peak. Truth map: the running mean
leaves (1 - 1/window) of a profile that is smooth over the window, so

    e_b = (1 - 1/window) rms^2 (<P^2>_b - median_b' <P^2>_b')

<.>_b the mean over bin b's angles (uniform within whole rounds).

A deterministic ripple locked to the table angle (a brush's contact resistance, a ring's
eccentricity) is no noise and the running mean would remove it: it is tested on the signal
(``TurnSampleView.signal_V``) by regression on the harmonics of the table angle, each window's
mean and linear trend in time (gyro bias and drift) projected out of the signal and the
harmonics alike (Frisch-Waugh-Lovell),

    s = sum_{k=2..K+1} (a_k cos k theta + b_k sin k theta) + e,   F = (SS_reg / 2K) / (SS_res / dof)

with the residual variance floored at q^2 / 12. Harmonic 1 is a nuisance, projected out too: the
Earth's horizontal rate, the spin axis' tilt and the gyro's misalignment all put a 1/rev signal
on a gyro across the spin axis, physics the whole-round twin holds. The converter's rounding of
that 1/rev signal makes harmonics of its own, damped by the noise before the rounding (the
dither): a ripple must exceed their bound as well (:func:`rounding_harmonic_bound_V`, with the
1/rev amplitude 3 SE high and the dither from the residual variance less q^2 / 12, low).
p < alpha names the effect with the largest harmonic's amplitude A_k = sqrt(a_k^2 + b_k^2) +- its
SE (V) and phase.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from scipy import special, stats

from imurig.sensors.effects.base import ChainContext, Effect, Param
from imurig.sensors.effects.views import TurnSampleView


def rounding_harmonic_bound_V(q_V: float, a1_V: float, sigma_V: float, m: int, k_max: int = 2000) -> float:
    """The largest amplitude (V) at harmonic ``m`` of the table angle that a converter of step q
    can make by rounding a 1/rev signal b + a1 cos(theta) under Gaussian dither sigma (V), any bias b:

        E[round error | u] = sum_k (-1)^k q / (pi k) exp(-2 pi^2 k^2 sigma^2 / q^2) sin(2 pi k u / q)
        sin(2 pi k (b + a1 cos theta) / q)  has harmonic m of amplitude 2 |J_m(2 pi k a1 / q)|

    (Jacobi-Anger), so the bound is sum_k 2 q / (pi k) exp(-2 pi^2 k^2 sigma^2 / q^2) |J_m(2 pi k a1 / q)|, summed to
    ``k_max`` plus the tail with |J_m(x)| <= sqrt(2 / (pi x)). 0 without a step."""
    if q_V <= 0 or a1_V <= 0:
        return 0.0
    k = np.arange(1, k_max + 1, dtype=float)
    damp = np.exp(-2 * np.pi**2 * k**2 * sigma_V**2 / q_V**2)
    head = float(np.sum(2 * q_V / (np.pi * k) * damp * np.abs(special.jv(m, 2 * np.pi * k * a1_V / q_V))))
    tail = 2 * q_V / np.pi * np.sqrt(q_V / (np.pi**2 * a1_V)) * 2.0 / np.sqrt(k_max) * float(damp[-1])
    return head + tail


@dataclass
class SlipRingNoise(Effect):
    """Contact noise ``rms_V`` (V) rising by ``depth`` at the rough spots ``spots_rad`` (width 1/sqrt(kappa) rad)."""

    enabled: bool = True
    rms_V: float = 20e-6
    depth: float = 8.0
    n_spots: int = 3
    kappa: float = 40.0
    spots_rad: tuple = (0.7, 2.9, 4.4)

    name: ClassVar[str] = "slip_ring_noise"
    order: ClassVar[int] = 202
    stage: ClassVar[str] = "analog"
    stream: ClassVar[str] = "slip"
    physics: ClassVar[str] = ("contact noise of the slip rings: the noise of every line that crosses a ring rises "
                              "at fixed table angles where a brush passes a rough spot")
    seed_section: ClassVar[str] = "4.4.1, Fig. 4.16"
    seed_says: ClassVar[str] = ("a periodicity can be seen which can be traced back to the fact that the sliprings "
                                "behave differently in various different positions")
    params: ClassVar[tuple] = (Param("rms_V", "V", seed=20e-6, note="contact noise away from the rough spots"),
                               Param("depth", "1", seed=8.0, note="rise of the noise amplitude at a spot"),
                               Param("peak_excess_noise_rms_V", "V",
                                     note="fitted: sqrt of the excess variance of the noisiest angle bin"))
    views: ClassVar[tuple] = (TurnSampleView.kind,)
    #: the running mean (samples) the diagnosis removes, and the angle bins of its test
    window: ClassVar[int] = 51
    n_bins: ClassVar[int] = 36

    def profile(self, angle_rad: np.ndarray) -> np.ndarray:
        """P(theta) = 1 + depth p(theta) (n,), computed once per angle record (cached on the array)."""
        angle_rad = np.asarray(angle_rad)
        key = (self.depth, self.kappa, tuple(self.spots_rad), angle_rad.shape)
        cache = getattr(self, "_profile_cache", None)
        if cache is not None and cache[0] is angle_rad and cache[1] == key:
            return cache[2]
        P = np.empty(angle_rad.shape)
        tmp = np.empty(min(P.shape[0], 1 << 18))
        for i in range(0, P.shape[0], 1 << 18):  # in row pieces, spot by spot, in place: no (n, spots) temporaries
            p = P[i:i + (1 << 18)]
            t = tmp[:p.shape[0]]
            for j, s in enumerate(self.spots_rad):   # exp(kappa (cos(theta - s) - 1)), summed over the spots in order
                np.subtract(angle_rad[i:i + p.shape[0]], s, out=t)
                np.cos(t, out=t)
                t -= 1
                t *= self.kappa
                np.exp(t, out=t)
                if j:
                    p += t
                else:
                    p[...] = t
            p *= self.depth
            p += 1
        if not len(self.spots_rad):
            P[...] = 1.0
        # kept with a reference to the angle array itself: the chain asks once per line of one record
        self._profile_cache = (angle_rad, key, P)
        return P

    def voltage(self, angle_rad: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """The contact noise (n,) V at the table angles ``angle_rad`` (n,) rad."""
        if not self.enabled:
            return np.zeros_like(angle_rad)
        return self.rms_V * self.profile(angle_rad) * rng.standard_normal(np.shape(angle_rad))

    def lines(self, names, ctx: ChainContext) -> list[str]:
        """The IMU's lines (``ctx.imu_lines``) while the rig turns (a ``spin_angle`` truth signal);
        lines from the table itself do not cross a ring."""
        if not self.enabled or "spin_angle" not in ctx.truth_signals:
            return []
        imu = getattr(ctx, "imu_lines", ())
        return [n for n in names if n in imu]

    def line_stream(self, line: str) -> str:
        return "slip_" + line

    def inject(self, v: np.ndarray, ctx: ChainContext, rng: np.random.Generator) -> np.ndarray:
        if not self.enabled:
            return v
        P = self.profile(ctx.truth_signals["spin_angle"])
        out = np.empty(np.shape(v))
        for a in range(0, out.shape[0], 1 << 18):  # in row pieces: the draws in order, the values of voltage()
            b = min(out.shape[0], a + (1 << 18))
            out[a:b] = v[a:b] + self.rms_V * P[a:b] * rng.standard_normal(b - a)
        return out

    @classmethod
    def from_settings(cls, settings: Mapping) -> "SlipRingNoise":
        """The effect from its recorded settings (the truth's chain["slip_rings"]; lists become tuples)."""
        return cls(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in settings.items()
                      if k in cls.__dataclass_fields__})

    def round_average_variance_V2(self, n_angles: int = 3600) -> float:
        """rms^2 <P^2> over whole rounds (uniform table angle, ``n_angles`` points) (V^2)."""
        if not self.enabled:
            return 0.0
        ang = np.linspace(0, 2 * np.pi, n_angles, endpoint=False)
        return self.rms_V**2 * float(np.mean(self.profile(ang) ** 2))

    def noise_variance(self, ctx: ChainContext) -> float:
        """Per-sample variance on a line that crosses a ring (V^2): rms^2 <P^2> over the record's
        table angles (ctx.truth_signals["spin_angle"]), or over whole rounds without them."""
        if not self.enabled:
            return 0.0
        if "spin_angle" not in ctx.truth_signals:
            return self.round_average_variance_V2()
        return float(self.rms_V**2 * np.mean(self.profile(ctx.truth_signals["spin_angle"]) ** 2))

    # ------------------------------------------------------------------ diagnosis

    def bin_index(self, angle_rad: np.ndarray) -> np.ndarray:
        """The angle bin of each angle in [0, 2 pi]; a sample after the last index pulse of its window
        joins the last bin, one more than a bin before the first pulse gets -1 (in no bin)."""
        a = np.asarray(angle_rad, float)
        return np.minimum((a / (2 * np.pi) * self.n_bins).astype(int), self.n_bins - 1)

    def test(self, view: TurnSampleView) -> dict:
        """Brown-Forsythe test of equal spread over the angle bins, and the refit when it fires
        (see the module doc). Returns the statistics, with the finding under "finding"."""
        if not isinstance(view, TurnSampleView):
            return {}
        ripple = self.ripple(view)
        res = np.asarray(view.residual_V, float)
        idx = self.bin_index(view.angle_rad)
        groups = [res[idx == i] for i in range(self.n_bins)]
        if view.window is not None and np.unique(view.window).size > 1:
            stat, p = self.brown_forsythe_within_windows(res, idx, np.asarray(view.window))
        else:
            stat, p = stats.levene(*groups, center="median")
        spread = np.array([1.4826 * np.median(np.abs(g - np.median(g))) for g in groups])
        return self.verdict(view, res.size, stat, p, spread, lambda: self.refit(groups), ripple)

    def verdict(self, view: TurnSampleView, n: int, stat: float, p: float, spread: np.ndarray, refit, ripple: dict) -> dict:
        """The test's report from its statistics (:meth:`test`; a streamed record's, whose samples are not
        held, :mod:`imurig.diagnose.slip_ring_stream`): ``n`` samples, the spread test's (stat, p), the
        robust noise by angle bin ``spread``, ``refit()`` the refit (called when the spread test fires),
        the ripple's regression."""
        base = float(np.median(spread))
        out = {"samples": int(n), "levene_statistic": float(stat), "p_value": float(p),
               "threshold_p": view.alpha, "noise_V_by_angle_bin": spread.tolist(), "bin_deg": 360.0 / self.n_bins}
        # a step above the noise leaves most bins' MAD at 0 and the code transitions of the slow
        # signal at fixed angles: the spread is then not measured, and not tested
        q_floor = float(view.quantum_V or 0.0) / np.sqrt(12.0)
        if base < q_floor:
            out["spread_tested"] = f"no: the noise ({base:.3g} V, robust) is below the ADC step's q/sqrt(12)"
        elif p < view.alpha:
            high = np.flatnonzero(spread > base * 1.1)
            refit = refit()
            out["finding"] = {"effect": self.name,
                              "physics": f"contact noise of the slip rings on '{view.channel}': the noise rises at "
                                         "fixed table angles where a brush passes a rough spot (seed Fig. 4.16)",
                              "angles_deg": ((high + 0.5) * 360.0 / self.n_bins).tolist(),
                              "peak_to_median_noise": float(spread.max() / base), "p_value": float(p),
                              "parameters": [{"name": "peak_excess_noise_rms_V", "estimate": refit["peak_rms_V"],
                                              "std_error": refit["peak_rms_se_V"]}],
                              "peak_angle_deg": refit["peak_angle_deg"],
                              "excess_noise_rms_V_by_angle_bin": refit["rms_V"],
                              "excess_noise_rms_se_V_by_angle_bin": refit["rms_se_V"],
                              "refit": "excess variance of each angle bin over the median bin, "
                                       "mean(r^2) - median; amplitude sqrt(excess) with delta-method SE"}
        if ripple:
            out["ripple"] = {k: v for k, v in ripple.items() if k != "found"}
            if ripple["found"]:
                f = out.setdefault("finding", {"effect": self.name, "p_value": ripple["p_value"], "parameters": [],
                                               "physics": f"a ripple locked to the table angle on '{view.channel}' "
                                                          "(slip rings, seed Fig. 4.16)"})
                f["parameters"] = f["parameters"] + [
                    {"name": "ripple_amplitude_V", "estimate": ripple["amplitude_V"], "std_error": ripple["amplitude_se_V"]}]
                f["ripple"] = out["ripple"]
        return out

    def brown_forsythe_within_windows(self, res: np.ndarray, idx: np.ndarray, window: np.ndarray) -> tuple[float, float]:
        """Brown-Forsythe across the angle bins with the acquisition window as a block:

            z_i = |r_i - median over i's (window, bin)|,   z'_i = z_i - mean over i's window of z
            F = (SS_bins(z') / (B - 1)) / (SS_within(z') / (N - B - W + 1))

        (B bins, W windows, N samples). Windows differ in noise and, on a coarse ADC, in the shape
        of the rounded residual; their cut ends cover the bins unevenly: pooled, that reads as
        spread by angle (a false finding on clean data), blocked it does not. Returns (F, p)."""
        B = self.n_bins
        _, cell = np.unique(window * B + idx, return_inverse=True)
        med = np.array([np.median(g) for g in np.split(res[np.argsort(cell, kind="stable")],
                                                         np.cumsum(np.bincount(cell))[:-1])])
        z = np.abs(res - med[cell])
        _, iw = np.unique(window, return_inverse=True)
        z = z - (np.bincount(iw, z) / np.bincount(iw))[iw]
        n_b = np.bincount(idx, minlength=B)
        gm = np.bincount(idx, z, minlength=B) / np.maximum(n_b, 1)
        return self.brown_forsythe_from(n_b, gm, float(np.sum((z - gm[idx]) ** 2)), int(iw.max() + 1))

    def brown_forsythe_from(self, n_b: np.ndarray, gm: np.ndarray, ss_within: float, n_windows: int) -> tuple[float, float]:
        """(F, p) of :meth:`brown_forsythe_within_windows` from the bins' counts ``n_b``, their means of z'
        ``gm`` and the within-bin sum of squares of z'."""
        B = self.n_bins
        dof2 = int(np.sum(n_b)) - B - n_windows + 1
        F = float((np.sum(n_b * gm**2) / (B - 1)) / (ss_within / dof2))
        return F, float(stats.f.sf(F, B - 1, dof2))

    def ripple(self, view: TurnSampleView, harmonics: int = 4) -> dict:
        """The harmonic regression of the signal on the table angle (module doc); {} without a signal."""
        if getattr(view, "signal_V", None) is None:
            return {}
        s = np.asarray(view.signal_V, float)
        th = np.asarray(view.angle_rad, float)
        win = np.zeros(s.size, int) if view.window is None else np.asarray(view.window)
        t = np.arange(s.size, dtype=float) if view.time_s is None else np.asarray(view.time_s, float)
        G = np.zeros((3 + 2 * harmonics, 3 + 2 * harmonics))
        for w in np.unique(win):
            i = win == w
            A = self.ripple_columns(s[i], th[i], t[i], harmonics)
            G += A.T @ A
        return self.ripple_from_gram(G, s.size, np.unique(win).size, view.quantum_V, view.alpha, harmonics)

    @staticmethod
    def ripple_columns(signal: np.ndarray, angle_rad: np.ndarray, time_s: np.ndarray, harmonics: int = 4) -> np.ndarray:
        """One window's columns [s, H, H1] (n, 3 + 2 harmonics): the signal, the tested harmonics
        cos, sin k theta (k = 2..harmonics + 1) and harmonic 1 (a nuisance, module doc), each with the
        window's mean and trend removed."""
        th = np.asarray(angle_rad, float)
        k = np.arange(2, harmonics + 2)
        A = np.column_stack([signal, np.cos(np.outer(th, k)), np.sin(np.outer(th, k)), np.cos(th), np.sin(th)])
        T = np.column_stack([np.ones(th.size), time_s - np.mean(time_s)])
        return A - T @ np.linalg.lstsq(T, A, rcond=None)[0]

    def ripple_from_gram(self, G: np.ndarray, n: int, n_windows: int, quantum_V, alpha: float,
                         harmonics: int = 4) -> dict:
        """:meth:`ripple` from the Gram matrix G = sum over windows of A'A (A: :meth:`ripple_columns`) of
        ``n`` samples in ``n_windows`` windows: harmonic 1 projected off the signal and the tested
        harmonics, their least squares, its F test and the amplitude's SE."""
        p = 2 * harmonics
        n_nuis = 2 * n_windows + 2
        if n <= p + n_nuis:
            return {}
        ss, sH, sH1 = G[0, 0], G[0, 1:1 + p], G[0, 1 + p:]
        HH, HH1, H1H1 = G[1:1 + p, 1:1 + p], G[1:1 + p, 1 + p:], G[1 + p:, 1 + p:]
        c1 = np.linalg.solve(H1H1, sH1)            # the 1/rev signal (V), whose rounding makes harmonics
        K = np.linalg.solve(H1H1, HH1.T)           # harmonic 1 off the tested harmonics and the signal
        HHp, sHp = HH - HH1 @ K, sH - K.T @ sH1
        coef = np.linalg.solve(HHp, sHp)
        rr = float(ss - sH1 @ c1 - coef @ sHp)     # the residual sum of squares
        dof = n - p - n_nuis
        var = max(rr / dof, float(quantum_V or 0.0) ** 2 / 12.0)
        ss_reg = float(coef @ HHp @ coef)
        F = (ss_reg / p) / var
        pv = float(stats.f.sf(F, p, dof))
        cov = var * np.linalg.inv(HHp)
        a, b = coef[:harmonics], coef[harmonics:]
        amp = np.hypot(a, b)
        j = int(np.argmax(amp))
        g = np.array([a[j], b[j]]) / max(amp[j], 1e-300)
        idx = [j, j + harmonics]
        se = float(np.sqrt(g @ cov[np.ix_(idx, idx)] @ g))
        # the converter's rounding of the 1/rev signal makes harmonics of its own (module doc): a
        # ripple must exceed that bound, with the 1/rev amplitude taken 3 SE high and the dither
        # (the noise before rounding) low, from the residual variance less the rounding's q^2/12
        q = float(quantum_V or 0.0)
        a1 = float(np.hypot(*c1)) + 3.0 * float(np.sqrt(var / np.min(np.diag(H1H1))))
        dither = float(np.sqrt(max(rr / dof - q * q / 12.0, 0.0)))
        bound = rounding_harmonic_bound_V(q, a1, dither, j + 2)
        return {"found": bool(pv < alpha and amp[j] > bound), "F": float(F), "p_value": pv,
                "harmonic": int(j + 2), "rounding_bound_V": bound, "first_harmonic_V": float(np.hypot(*c1)),
                "dither_V": dither,
                "amplitude_V": float(amp[j]), "amplitude_se_V": se,
                "phase_deg": float(np.degrees(np.arctan2(b[j], a[j]))), "amplitudes_V": amp.tolist(),
                "noise_V": float(np.sqrt(var))}

    def refit(self, groups: list[np.ndarray]) -> dict:
        """The excess noise per angle bin over the median bin (module doc): variances (V^2) and
        amplitudes (V), each with its standard error, and the peak bin's amplitude."""
        v = np.array([np.mean(g**2) for g in groups])
        se = np.array([np.sqrt(np.var(g**2, ddof=1) / g.size) for g in groups])
        return self.refit_from(v, se)

    def refit_from(self, v: np.ndarray, se: np.ndarray) -> dict:
        """:meth:`refit` from each bin's mean square ``v`` (V^2) and its standard error ``se``."""
        v0 = float(np.median(v))
        # the median of n_bins estimates: sqrt(pi/2) x their typical SE / sqrt(n_bins)
        se0 = float(np.sqrt(np.pi / 2) * np.median(se) / np.sqrt(self.n_bins))
        e = v - v0
        e_se = np.sqrt(se**2 + se0**2)
        amp = np.sqrt(np.clip(e, 0.0, None))
        amp_se = np.where(amp > 0, e_se / (2 * np.where(amp > 0, amp, 1.0)), np.sqrt(e_se))
        k = int(np.argmax(e))
        return {"excess_V2": e.tolist(), "excess_se_V2": e_se.tolist(), "rms_V": amp.tolist(),
                "rms_se_V": amp_se.tolist(), "peak_rms_V": float(amp[k]), "peak_rms_se_V": float(amp_se[k]),
                "peak_angle_deg": float((k + 0.5) * 360.0 / self.n_bins)}

    def excess_variance_V2(self, points_per_bin: int = 400) -> np.ndarray:
        """The truth of the refit: e_b = (1 - 1/window) rms^2 (<P^2>_b - median <P^2>) per bin (V^2)."""
        if not self.enabled:
            return np.zeros(self.n_bins)
        edges = np.arange(self.n_bins)[:, None] + (np.arange(points_per_bin) + 0.5)[None, :] / points_per_bin
        P2 = self.profile((edges * 2 * np.pi / self.n_bins).ravel()).reshape(edges.shape) ** 2
        m = P2.mean(axis=1)
        return (1.0 - 1.0 / self.window) * self.rms_V**2 * (m - np.median(m))

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        """{peak_excess_noise_rms_V: sqrt(max_b e_b)} for the recorded rings (truth["chain"]["slip_rings"])."""
        eff = self.from_settings(truth["chain"]["slip_rings"])
        return {"peak_excess_noise_rms_V": float(np.sqrt(max(eff.excess_variance_V2().max(), 0.0)))}
