"""The index pulses' own timing error in a turn-table time series: the timer test from the pulse channel.

Each index pulse is logged as a high level on the pulse voltage channel, so its edge is known only
to the sample grid (step dt = 1/fs). Per pulse k the edge is bracketed by the samples on either
side of the threshold (:func:`edge_times`):

    rising edge  t_k in (t_i, t_i+1],          falling edge t_k + w in (t_j, t_j+1]
    t_k in the intersection I_k of (t_i, t_i+1] and (t_j - w_hi, t_j+1 - w_lo]
    t_k,meas = the middle of I_k,  its grid error var  v_k = |I_k|^2 / 12      (uniform in I_k)

(w_lo, w_hi): the widths every pulse allows, w in (t_j - t_i+1, t_j+1 - t_i) for each. The grid fixes
the width to a whole sample only: pulses of a width that is not a whole number of samples show two
counts of high samples, and the range is then the sample between them, so the falling edge narrows
no bracket and I_k is the rising edge's (the mean count's width is a statistic, and with pulses
locked to the grid's phase a biased one that would misplace every bracket). A width that varies
from pulse to pulse leaves the rising edge alone too. An edge with an intermediate sample, a
sloped edge, is interpolated linearly and keeps v_k = dt^2/12, an upper bound. On a dial plateau the table turns at a constant rate, so the pulses of step s lie
on a line, whatever the mains factor and the slip make of the rate (:func:`pulse_timer_test`):

    t_k,meas = t0_s + T_s n_k + e_k,    var(e_k) = v_k + j^2                    [s]

n_k the round count, j the detector's jitter. The statistic is Q = sum_k r_k^2 / v_k of the
per-step weighted least-squares residuals r_k (H0: j = 0), m = sum_s (n_s - 2) residuals. Under H0
the grid errors are not independent Gaussians: they are uniform, and set by the phase of the pulse
train on the grid, so that when T_s fs is near a whole number they repeat (absorbed by t0_s) and
near a simple fraction they follow a pattern. The null distribution of Q is therefore simulated:
per step the same number of pulses at the fitted period T_s (drawn within its SE: the pattern of
the grid errors depends on T_s fs modulo 1, which the data fix only that far), a uniform phase on the grid, the same
bracketing (pulse width w known to (w_lo, w_hi)), Q summed over steps (:func:`_null_q`); the p-value is the share of
simulated Q at or above the observed one (chi-square on m kept as a reference, and used where an
edge is sloped). The jitter variance is
the moment estimate j^2 = (RSS - tr((I - H) V)) / m over the steps' ordinary least-squares fits,
and the reported timer error is the library's per-edge sigma_T = sqrt(j^2 + dt^2 / 12)
(:class:`imurig.sensors.effects.timer_quantisation.TimerQuantisation`: q^2/12 + jitter^2, q = dt).
The SE of j^2 is sqrt(2 sum_s tr(((I - H) (V + j^2 I))^2)) / m (Gaussian, at the estimate), that of
sigma_T by the delta method. With a few pulses per plateau m is small (three rounds per step give one
residual each), and j^2 scatters as a skewed, scaled chi-square on m: the SE at the estimate is then
small for a low draw and large for a high one (its band still holds the truth about 68 % of the
time, but z = (estimate - truth) / SE has an RMS of about 1.2 on m = 12, with a tail towards low
draws). The exact small-sample interval is reported beside it (:func:`_jitter_interval`): it inverts
Q(j^2) = sum_k r_k^2 / (v_k + j^2) (weighted line fits per plateau, chi-square on m for Gaussian
errors, decreasing in j^2) at its 15.87 % and 84.13 % points, j^2 >= 0, on j^2 and on sigma_T.
"""
from __future__ import annotations

import numpy as np
from scipy import optimize, stats

#: draws of the simulated null of Q
N_SIM = 4000

#: pulses closer than this to the start of a dial plateau are left out: the table still settles
SETTLE_S = 2.0


def edge_times(t_s: np.ndarray, x_V: np.ndarray, threshold_V: float | None = None, levels=None) -> dict:
    """The pulses' rising-edge times (s) bracketed by both edges, with their grid variance (s^2).

    Returns {time_s, var_s2, width_s, width_range_s, sloped, high_samples}: per pulse the middle of
    I_k and |I_k|^2/12 (module doc), the width w, the widths all pulses allow, how many edges had an
    intermediate sample, and per pulse its count of samples at or above the threshold (-1 where an
    edge is sloped), counted from the edge samples' times (so that it holds for a streamed record's
    samples too). ``levels``: the low and high levels (default the channel's 1st and 99.9th
    percentiles), for samples that hold only the threshold crossings (a streamed record's,
    :mod:`imurig.diagnose.turn_record`)."""
    t, x = np.asarray(t_s, float), np.asarray(x_V, float)
    lo, hi = np.percentile(x, [1.0, 99.9]) if levels is None else levels
    thr = 0.5 * (lo + hi) if threshold_V is None else threshold_V
    rise = np.flatnonzero((x[:-1] < thr) & (x[1:] >= thr))
    fall = np.flatnonzero((x[:-1] >= thr) & (x[1:] < thr))
    fall = fall[fall > (rise[0] if rise.size else -1)]
    n = min(rise.size, fall.size)
    rise, fall = rise[:n], fall[:n]
    swing = hi - lo
    binary = ((x[rise] < lo + 0.1 * swing) & (x[rise + 1] > hi - 0.1 * swing)
              & (x[fall] > hi - 0.1 * swing) & (x[fall + 1] < lo + 0.1 * swing))
    dt = np.diff(t)
    a1, b1 = t[rise], t[rise + 1]
    a2, b2 = t[fall], t[fall + 1]
    # the widths every binary pulse allows: w in (a2 - b1, b2 - a1); all of them together fix w to
    # (w_lo, w_hi). Where they do not agree (a width that varies) the rising edge alone brackets.
    w_lo = float(np.max(a2 - b1, where=binary, initial=-np.inf))
    w_hi = float(np.min(b2 - a1, where=binary, initial=np.inf))
    if not w_hi > w_lo or not np.isfinite(w_hi - w_lo):
        w_lo, w_hi = -np.inf, np.inf
    w = 0.5 * (w_lo + w_hi) if np.isfinite(w_hi) else (float(np.mean(0.5 * (a2 + b2 - a1 - b1))) if n else 0.0)
    lo_k, hi_k = np.maximum(a1, a2 - w_hi), np.minimum(b1, b2 - w_lo)
    ok = binary & (hi_k > lo_k)
    lo_k, hi_k = np.where(ok, lo_k, a1), np.where(ok, hi_k, b1)
    mid = 0.5 * (lo_k + hi_k)
    var = (hi_k - lo_k) ** 2 / 12.0
    # a sloped edge: the threshold crossing interpolated between the samples, dt^2/12 kept as its bound
    frac = np.where(binary, 0.5, (thr - x[rise]) / np.where(x[rise + 1] > x[rise], x[rise + 1] - x[rise], 1.0))
    mid = np.where(binary, mid, a1 + frac * dt[rise])
    var = np.where(binary, var, dt[rise] ** 2 / 12.0)
    return {"time_s": mid, "var_s2": var, "width_s": w, "width_range_s": (w_lo, w_hi), "sloped": int(np.sum(~binary)),
            "high_samples": np.where(binary, np.rint((a2 - a1) / np.where(b1 > a1, b1 - a1, 1.0)).astype(int), -1)}


def _bracket(tau: np.ndarray, dt: float, w: float, w_range=None) -> tuple[np.ndarray, np.ndarray]:
    """The middle and the grid variance of true edge times ``tau`` (s) as :func:`edge_times`
    brackets them on a grid n dt with pulses ``w`` long, the width known to ``w_range`` = (w_lo, w_hi)
    (default: exactly; infinite: the rising edge alone) (the simulated null)."""
    w_lo, w_hi = (w, w) if w_range is None else w_range
    a1 = (np.ceil(tau / dt) - 1) * dt
    a2 = (np.ceil((tau + w) / dt) - 1) * dt
    lo, hi = np.maximum(a1, a2 - w_hi), np.minimum(a1 + dt, a2 + dt - w_lo)
    ok = hi > lo
    lo, hi = np.where(ok, lo, a1), np.where(ok, hi, a1 + dt)
    return 0.5 * (lo + hi), (hi - lo) ** 2 / 12.0


def _wls_q(n: np.ndarray, tk: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Q = sum r^2 / v of the weighted line fits t = t0 + T n, over the last axis of ``tk``, ``v``."""
    W = 1.0 / v
    S0, S1, S2 = W.sum(-1), (W * n).sum(-1), (W * n * n).sum(-1)
    Y0, Y1 = (W * tk).sum(-1), (W * n * tk).sum(-1)
    det = S0 * S2 - S1**2
    b0, b1 = (S2 * Y0 - S1 * Y1) / det, (S0 * Y1 - S1 * Y0) / det
    return (W * (tk - b0[..., None] - b1[..., None] * n) ** 2).sum(-1)


def _null_q(steps, dt: float, w: float, rng: np.random.Generator, n_sim: int = N_SIM, w_range=None) -> np.ndarray:
    """``n_sim`` draws of Q under H0 (module doc): each step's pulses at its fitted period (drawn
    within the period's own grid SE, which decides the pattern of the grid errors) with a uniform
    phase on the grid, bracketed as the data are."""
    Q = np.zeros(n_sim)
    for n, tk, v in steps:
        T = float(np.polyfit(n, tk, 1, w=1.0 / np.sqrt(v))[0])
        se_T = float(np.sqrt(np.mean(v) / np.sum((n - n.mean()) ** 2)))
        T = T + se_T * rng.standard_normal(n_sim)[:, None]
        tau = rng.uniform(0, dt, n_sim)[:, None] + T * n[None, :] + 1000.0 * dt
        mid, var = _bracket(tau, dt, w, w_range)
        Q += _wls_q(n[None, :], mid, var)
    return Q


def _step_fits(edges: dict, start_s, stop_s, dial, settle_s: float):
    """Per dial plateau with >= 3 settled pulses: (round counts n, times, grid variances)."""
    t, v = edges["time_s"], edges["var_s2"]
    out = []
    for a, b, d in zip(start_s, stop_s, dial):
        if d == 0:
            continue
        k = (t >= a + settle_s) & (t <= b)
        if k.sum() < 3:
            continue
        tk = t[k]
        T0 = float(np.median(np.diff(tk)))
        n = np.round((tk - tk[0]) / T0)
        out.append((n, tk, v[k]))
    return out


def _jitter_interval(steps, m: int, level: float = 0.6827) -> tuple[float, float]:
    """The ``level`` interval (j2_lo, j2_hi) of the jitter variance (s^2) from
    Q(j^2) = sum over steps of the weighted line fits' sum r_k^2 / (v_k + j^2), chi-square on ``m``
    (module doc): Q(j2_hi) is its lower, Q(j2_lo) its upper quantile; 0 where Q(0) is already below."""
    def q(j2: float) -> float:
        return float(sum(_wls_q(n, tk, v + j2) for n, tk, v in steps))

    ends = []
    for target in stats.chi2.ppf([0.5 + level / 2, 0.5 - level / 2], m):
        if q(0.0) <= target:
            ends.append(0.0)
            continue
        hi = max(float(np.max([np.max(v) for _, _, v in steps])), 1e-12)
        while q(hi) > target:                       # Q falls towards 0 as j^2 grows
            hi *= 4.0
        ends.append(float(optimize.brentq(lambda j2: q(j2) - target, 0.0, hi, xtol=1e-12 * hi, rtol=1e-10)))
    return ends[0], ends[1]


def pulse_timer_test(edges: dict, start_s, stop_s, dial, dt_s: float, rng: np.random.Generator,
                     alpha: float = 0.01, settle_s: float = SETTLE_S) -> dict:
    """Is the index pulses' scatter about each plateau's line larger than the sample grid gives?
    (module doc). ``edges``: :func:`edge_times`; ``start_s``, ``stop_s``, ``dial``: the plateaus;
    ``dt_s`` the sample interval (s); ``rng`` draws the simulated null."""
    steps = _step_fits(edges, start_s, stop_s, dial, settle_s)
    m = sum(n.size - 2 for n, _, _ in steps)
    if m < 3:
        return {"tested": False, "why": f"{m} residual degrees of freedom from the settled index pulses of the "
                                        "dial plateaus; the timer test needs at least 3"}
    Q = rss = trV = 0.0
    parts = []
    for n, tk, v in steps:
        X = np.column_stack([np.ones_like(n), n])
        W = 1.0 / v
        beta = np.linalg.solve(X.T @ (X * W[:, None]), X.T @ (W * tk))
        Q += float(np.sum(W * (tk - X @ beta) ** 2))
        M = np.eye(n.size) - X @ np.linalg.pinv(X)           # I - H of the ordinary fit
        r = M @ tk
        rss += float(r @ r)
        trV += float(np.trace(M * v[None, :]))
        parts.append((M, v))
    p_chi2 = float(stats.chi2.sf(Q, m))
    if edges["sloped"] == 0:
        Qn = _null_q(steps, dt_s, edges["width_s"], rng, w_range=edges.get("width_range_s"))
        p = float((1 + np.sum(Qn >= Q)) / (1 + Qn.size))
        null = f"simulated: {Qn.size} draws of the grid's bracketing at the fitted periods, uniform phases"
    else:
        p, null = p_chi2, "chi-square on the residual count (sloped edges: the grid bracket does not apply)"
    j2 = (rss - trV) / m
    var_rss = sum(2.0 * float(np.sum((M * (v + max(j2, 0.0))[None, :]) * (M * (v + max(j2, 0.0))[None, :]).T))
                  for M, v in parts)
    se_j2 = float(np.sqrt(var_rss)) / m
    s2 = max(j2, 0.0) + dt_s**2 / 12.0
    sig = float(np.sqrt(s2))
    j2_lo, j2_hi = _jitter_interval(steps, m)
    sig_lo, sig_hi = np.sqrt(j2_lo + dt_s**2 / 12.0), np.sqrt(j2_hi + dt_s**2 / 12.0)
    out = {"tested": True, "statistic": Q, "dof": m, "p_value": p, "p_value_chi2": p_chi2, "alpha": alpha,
           "steps": len(steps),
           "pulses": int(sum(n.size for n, _, _ in steps)), "grid_rms_s": float(np.sqrt(trV / m)),
           "scatter_rms_s": float(np.sqrt(rss / m)), "jitter2_s2": j2, "jitter2_se_s2": se_j2,
           "jitter2_interval_s2": [j2_lo, j2_hi], "sigma_T_s": sig, "sigma_T_se_s": se_j2 / (2.0 * sig),
           "sigma_T_interval_s": [float(sig_lo), float(sig_hi)], "interval_level": 0.6827,
           "sample_interval_s": dt_s,
           "pulse_width_s": edges["width_s"], "sloped_edges": edges["sloped"], "null": null}
    out["accepted"] = bool(p < alpha and j2 > 0)
    if out["accepted"]:
        out["finding"] = timer_finding(
            "the index pulse's edge scatters about each plateau's constant-rate line by "
            f"{np.sqrt(rss / m) * 1e3:.2f} ms rms, where the sample grid gives {np.sqrt(trV / m) * 1e3:.2f} ms: "
            "a timer jitter", out, "pulse-time residual rms: observed, and the grid's alone")
    return out


def timer_finding(physics: str, out: dict, note: str) -> dict:
    """The accepted timer's finding from a test's ``out`` (sigma_T_s = sqrt(jitter^2 + dt^2 / 12) and the
    jitter, each +- SE by the delta method from jitter2_s2 +- jitter2_se_s2; the pulse-time residual rms
    before (scatter_rms_s) and after (grid_rms_s, the sample grid's alone))."""
    j = float(np.sqrt(out["jitter2_s2"]))
    return {"effect": "timer_quantisation", "physics": physics,
            "parameters": [{"name": "sigma_T_s", "estimate": out["sigma_T_s"], "std_error": out["sigma_T_se_s"]},
                           {"name": "jitter_s", "estimate": j, "std_error": out["jitter2_se_s2"] / (2.0 * j)}],
            "p_value": out["p_value"],
            "fit": {"before_rms": out["scatter_rms_s"], "after_rms": out["grid_rms_s"], "unit": "s", "note": note}}
