"""Diagnosis of a turn-table rate recording in the row format of appendix B (SIMONA).

The simulated twin takes the dial rate as the true rate: table rate = dial, stopwatch round
time = 360 deg / dial, gyro voltage = nominal scale factor x rate. The recording is compared
with it in two observables, and each mismatch is explained by effects of the library:

1. Rate (stopwatch): k_i = rate_measured / dial.
   - A constant factor far from 1 is a *mains-frequency rate factor*. It is named by the
     motor/mains pair it matches: a 60 Hz synchronous motor on 50 Hz mains gives 5/6.
   - The shortfall left against that factor, d_i = k_i / f - 1, goes to the engine with a
     constant shortfall as the nominal model. The library holds rate-dependent *table slip*
     (d = s1 rate^-alpha, alpha scanned) and a linear rate term.
2. Round-time resolution (``timer_quantisation``): the twin takes the round times as exact.
   A timer of resolution q adds to each round time T_i an error of variance sigma_T^2
   (q^2/12 for one rounded reading, q^2/6 for a difference of two quantised edges), so the
   relative rate mismatch d_i = T_true/T_i - 1 gets variance sigma_T^2 / T_i^2, which grows
   with rate^2. The residuals e_i of d after the shortfall model are tested for that
   variance term (:func:`timer_quantisation_test`): a likelihood ratio of
   var(e_i) = (1 - h_i)(a + sigma_T^2 / T_i^2) against sigma_T = 0, its threshold simulated
   under the homoscedastic noise model with the scan over sigma_T^2/a included
   (max-statistic), plus BIC and blocked cross-validation of the held-out log-likelihood.
   The fitted sigma_T (s) comes with its Fisher-information standard error. The grid of the
   printed times (their display resolution) is reported beside it as evidence.
3. Gyro voltage: V_i against the stopwatch rate, with a linear nominal model. The library
   holds an *instrument range change* at an unknown row (gain and offset step from row k
   on, k scanned), *scale-factor nonlinearity* (rate^2) and a *drift* in row order. A range
   change is confirmed when the readings' resolution changes at the same row.
"""
from __future__ import annotations

import numpy as np

from imurig.diagnose.engine import select_effects, wild_bootstrap_noise
from imurig.kernel.errors import RecordingError
from imurig.kernel.recording import Recording
from imurig.sensors.effects import RateRowView, RateShortfallView, VoltmeterRowView, for_view
from imurig.sensors.effects.mains_rate_factor import MOTOR_MAINS

GYROS = ("p", "q", "r")


def reading_resolution(x: np.ndarray, candidates=(1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 1e-1)) -> float:
    """The coarsest decimal step that every value of ``x`` is a multiple of (display resolution).
    A value is on the grid q when |x/q - round(x/q)| < 1e-6 + 1e-12 |x/q| (float rounding of x only:
    a round time of 720.123456 s is on the 1 us grid, not on the 10 us one)."""
    x = np.asarray(x, float)
    best = candidates[0]
    for q in candidates:
        if np.all(np.abs(x / q - np.round(x / q)) < 1e-6 + 1e-12 * np.abs(x / q)):
            best = q
    return best


def resolution_change_row(V: np.ndarray) -> int | None:
    """First index k from which every reading sits on a 10x coarser display grid than the
    record's finest (an autoscaling instrument switched up a range), with reading k-1 off it;
    None if the record ends on the fine grid. A single reading lands on the coarse grid by
    chance one time in ten, so callers combine several channels read by the same instrument."""
    V = np.asarray(V, float)
    q = 10 * reading_resolution(V)
    on = np.abs(V / q - np.round(V / q)) < 1e-6 * np.maximum(1.0, np.abs(V / q))
    if not on[-1]:
        return None
    k = V.size - 1
    while k > 0 and on[k - 1]:
        k -= 1
    return k if 0 < k < V.size - 1 else None


def diagnose_rate_rows(rec: Recording, rng: np.random.Generator, alpha: float = 0.01, n_sim: int = 400) -> dict:
    """Run the three analyses of the module doc on a row recording; returns a diagnosis dict."""
    for c in ("rate_dial", "measured_round"):
        if c not in rec.channels:
            raise RecordingError(f"a rate-table row recording needs '{c}' (see read_simona); it has {sorted(rec.channels)}")
    dial = np.abs(rec.channels["rate_dial"])
    T = rec.channels["measured_round"]
    timed = (T > 0) & (dial > 0)
    if timed.sum() < 6:
        raise RecordingError(f"only {int(timed.sum())} timed rows; the diagnosis needs at least 6")
    rows = np.flatnonzero(timed)
    rate = 2 * np.pi / T[timed]
    k = rate / dial[timed]
    out = {"rows": rows.tolist(), "twin": "table rate = dial; round = 360 deg / dial; V = 6 mV/(deg/s) x rate"}

    # --- 1. rate factor ------------------------------------------------------------
    k_mean = float(np.mean(k))
    k_se = float(np.std(k, ddof=1) / np.sqrt(k.size))
    name, f = min(MOTOR_MAINS.items(), key=lambda it: abs(np.log(k_mean / it[1])))
    out["locate"] = {"round_time_ratio_median": float(np.median(T[timed] * dial[timed] / (2 * np.pi))),
                     "rate_ratio_mean": k_mean, "rate_ratio_se": k_se}
    rate_factor = None
    if abs(k_mean - 1) > 5 * k_se and f != 1.0:
        rate_factor = {"effect": "mains_rate_factor", "physics": f"synchronous table motor: {name} turns at "
                       f"{f:.4f} of the dial", "factor": f, "mean_ratio": k_mean, "mean_ratio_se": k_se}
    out["rate_factor"] = rate_factor
    f_use = f if rate_factor else 1.0
    d = k / f_use - 1.0
    r_dps = np.degrees(rate)
    lib = [c for cls in for_view(RateShortfallView.kind) for c in cls().candidates(RateShortfallView(r_dps))]
    # the scatter of d is the dial's setting error (homoscedastic), far above the stopwatch's
    q = reading_resolution(T[timed])
    # the rows' errors grow with the rate (the timer): threshold from a wild bootstrap of the residuals
    diag = select_effects(d, np.ones((d.size, 1)), ["shortfall"], lib, rng, alpha=alpha, n_sim=n_sim,
                          noise=wild_bootstrap_noise(d, np.ones((d.size, 1))))
    out["shortfall"] = {"mean_shortfall": float(-np.mean(d)), "diagnosis": diag.to_dict(),
                        "note": "d = measured rate / (factor x dial) - 1; negative = slower than set",
                        "residuals": {"rate_dps": r_dps.tolist(), "before": diag.before.residuals_.tolist(),
                                      "after": diag.after.residuals_.tolist()}}
    # --- 2. timer resolution ------------------------------------------------------
    res_rate = np.degrees(rate) * (q / np.sqrt(12)) / T[timed]
    resid = diag.after.residuals_ * np.degrees(rate)  # rate residual, deg/s
    hi = r_dps > np.median(r_dps)
    out["timer_resolution"] = {"effect": "timer_quantisation", "resolution_s": q,
                               "physics": f"round times are known to {q:g} s: at {r_dps.max():.0f} deg/s that is "
                                          f"{res_rate.max():.3f} deg/s (1 sigma) on the rate",
                               "rate_sigma_dps_at_max_rate": float(res_rate.max()),
                               "rate_sigma_dps_at_min_rate": float(res_rate.min()),
                               "rate_residual_rms_dps_high_rates": float(np.sqrt(np.mean(resid[hi] ** 2))),
                               "rate_residual_rms_dps_low_rates": float(np.sqrt(np.mean(resid[~hi] ** 2)))}
    # --- 3. gyro channels ---------------------------------------------------------
    gy = {}
    n = rows.size
    idx = np.arange(n)
    # locate a range change by the readings' display grid (one voltmeter reads all three gyros)
    grid_rows = [resolution_change_row(rec.channels[f"gyro_{g}"][timed]) for g in GYROS if f"gyro_{g}" in rec.channels]
    k_grid = max(grid_rows) if grid_rows and all(k is not None for k in grid_rows) else None
    out["range_change_by_resolution"] = None if k_grid is None else {
        "first_row": int(rows[k_grid]), "rows_after": int(n - k_grid),
        "resolution_before_V": reading_resolution(np.concatenate([rec.channels[f"gyro_{g}"][timed][:k_grid]
                                                                  for g in GYROS if f"gyro_{g}" in rec.channels])),
        "resolution_after_V": reading_resolution(np.concatenate([rec.channels[f"gyro_{g}"][timed][k_grid:]
                                                                 for g in GYROS if f"gyro_{g}" in rec.channels]))}
    scan_k = (k_grid,) if k_grid is not None else tuple(range(3, n - 2))
    for g in GYROS:
        ch = f"gyro_{g}"
        if ch not in rec.channels:
            continue
        V = rec.channels[ch][timed]
        X0 = np.column_stack([np.ones(n), r_dps])
        view = RateRowView(channel=ch, rate_dps=r_dps, first_rows=scan_k)
        lib_v = [c for cls in for_view(RateRowView.kind) for c in cls().candidates(view)]
        # noise model first: reading resolution floor plus a part growing with the rate (the table's
        # rate ripple read at an arbitrary moment), fitted to the nominal model's squared residuals
        w = _variance_weights(V, X0, r_dps, ref_sigma_dps=res_rate)
        dg = select_effects(V, X0, ["bias", "scale"], lib_v, rng, alpha=alpha, n_sim=n_sim, weights=w)
        entry = dg.to_dict()
        entry["residuals"] = {"row": rows.tolist(), "rate_dps": r_dps.tolist(), "before_V": (dg.before.residuals_ / np.sqrt(w)).tolist(),
                              "after_V": (dg.after.residuals_ / np.sqrt(w)).tolist()}  # engine fits whitened
        for fnd in dg.findings:
            if fnd.name == "instrument_range_change":
                kk = int(fnd.theta)
                entry["resolution_before_V"] = reading_resolution(V[:kk])
                entry["resolution_after_V"] = reading_resolution(V[kk:])
                entry["range_change_row"] = int(rows[kk])
                entry["rows_after_change"] = int(n - kk)
        gy[g] = entry
    out["gyros"] = gy
    # the three gyros are read by one voltmeter: test its range change jointly -- one relative gain
    # step and one offset step for all three, against each gyro's own nonlinearity
    chans = [g for g in GYROS if f"gyro_{g}" in rec.channels]
    if len(chans) > 1:
        Vs, parts, scales = [], [], []
        for j, g in enumerate(chans):
            V = rec.channels[f"gyro_{g}"][timed]
            X0g = np.column_stack([np.ones(n), r_dps])
            coef = np.linalg.lstsq(X0g, V, rcond=None)[0]
            Vs.append(V)
            parts.append(_variance_parts(V, X0g, r_dps, ref_sigma_dps=res_rate))
            scales.append(coef[1])
        m = len(chans)
        Y = np.concatenate(Vs)
        X0 = np.zeros((m * n, 2 * m))
        for j in range(m):
            X0[j * n:(j + 1) * n, 2 * j] = 1.0
            X0[j * n:(j + 1) * n, 2 * j + 1] = r_dps
        joint_view = VoltmeterRowView(gyros=tuple(chans), rate_dps=r_dps, first_rows=scan_k,
                                      scale_V_per_dps=tuple(scales))
        lib_j = [c for cls in for_view(VoltmeterRowView.kind) for c in cls().candidates(joint_view)]
        # errors of the three readings of one row are correlated: they share the reference rate
        # (stopwatch resolution) and the table's ripple at the reading moment
        ripple_dps2 = np.mean([p_["ripple_V2_per_dps2"] / sc**2 for p_, sc in zip(parts, scales)])
        shared = res_rate**2 + ripple_dps2 * r_dps**2                        # (deg/s)^2 per row
        C = np.zeros((m * n, m * n))
        for a_ in range(m):
            for b_ in range(m):
                blk = np.diag(scales[a_] * scales[b_] * shared)
                if a_ == b_:  # shared part plus an independent part of at least the display floor
                    indep = np.maximum(parts[a_]["var"] - scales[a_] ** 2 * shared, parts[a_]["floor"])
                    blk = np.diag(scales[a_] ** 2 * shared + indep)
                C[a_ * n:(a_ + 1) * n, b_ * n:(b_ + 1) * n] = blk
        # C is estimated from a few rows and the display resolution changes mid-series: the
        # threshold is simulated with each row's own residuals, one sign per table row for its
        # three readings (cluster wild bootstrap); white draws gave 14 of 60 null records a false
        # range change, this 2 of 60 (benchmarks/bench_diagnose.py --fdr)
        dj = select_effects(Y, X0, [f"{c}_{g}" for g in chans for c in ("bias", "scale")], lib_j, rng,
                            alpha=alpha, n_sim=n_sim, cov=C,
                            noise=wild_bootstrap_noise(Y, X0, cov=C, clusters=np.tile(idx, m)))
        joint = dj.to_dict()
        for fnd in dj.findings:
            if fnd.name == "instrument_range_change":
                joint["range_change_row"] = int(rows[int(fnd.theta)])
        out["voltmeter"] = joint
    # --- 2 (cont.). the timer's round-time error, tested last (so the draws above do not depend on it)
    lookup = {c.name: c for c in lib}
    X_after = np.column_stack([np.ones(d.size)] + [lookup[f.name].design(f.theta) for f in diag.findings])
    test = timer_quantisation_test(diag.after.residuals_, X_after, T[timed], rng, alpha=alpha, n_sim=max(n_sim, 1000))
    out["timer_resolution"]["test"] = test
    if test["accepted"]:
        out["timer_resolution"]["finding"] = {
            "effect": "timer_quantisation",
            "physics": "the round times carry a timer error (resolution of the stopwatch or of the pulse timing) "
                       "that the twin, timing rounds exactly, leaves out: rate scatter growing with the rate",
            "statistic": test["statistic"], "threshold": test["threshold"],
            "parameters": [{"name": "sigma_T_s", "estimate": test["sigma_T_s"], "std_error": test["sigma_T_se_s"]},
                           {"name": "resolution_s_if_rounded", "estimate": test["resolution_s"],
                            "std_error": test["resolution_se_s"]}],
            "variance_share": test["variance_share"], "indistinguishable_from": None}
    return out


def timer_quantisation_test(e: np.ndarray, X: np.ndarray, T_s: np.ndarray, rng: np.random.Generator,
                            alpha: float = 0.01, n_sim: int = 1000, folds: int = 4) -> dict:
    """Is there a round-time error in the rate residuals? (see the module doc, item 2)

    ``e`` (n,): residuals of the relative rate mismatch d (1) after the mean model ``X`` (n, p);
    ``T_s`` (n,): the measured round times (s). Noise models, Gaussian, with h_i the leverage of
    row i in X and z_i = 1 / T_i^2 (1/s^2)::

        H0: var(e_i) = (1 - h_i) a                         (table setting error, relative)
        H1: var(e_i) = (1 - h_i) (a + sigma_T^2 z_i)       (plus the timer's round-time error)

    The statistic is the likelihood ratio LR = 2 (nll0 - min over rho of nll1), rho = sigma_T^2 / a
    scanned on a log grid (a profiled out). Its threshold is the (1 - alpha) quantile of the same
    statistic, scan included, on ``n_sim`` residuals simulated under H0 (LR does not depend on a).
    Accepted when LR beats it, BIC is lower (LR > log n) and blocked cross-validation
    (``folds``) gives a higher held-out log-likelihood. sigma_T (s) and the resolution
    q = sqrt(12) sigma_T of a rounded reading come with standard errors from the expected
    Fisher information of (a, sigma_T^2) (delta method for the square root).
    """
    from scipy.optimize import minimize_scalar

    e = np.asarray(e, float)
    T_s = np.asarray(T_s, float)
    n = e.size
    Q, _ = np.linalg.qr(np.asarray(X, float))
    lev = np.clip(1.0 - np.sum(Q**2, axis=1), 1e-6, None)      # 1 - h_i
    z = 1.0 / T_s**2
    rhos = np.concatenate([[0.0], np.logspace(-3, 4, 141) / z.max()])

    def nll(E2, rh, rows=slice(None)):
        """(s, g) profiled negative log-likelihoods and ML a of squared residuals E2 (s, n)."""
        W = lev[rows][None, :] * (1.0 + rh[:, None] * z[rows][None, :])
        m = W.shape[1]
        a = E2[:, rows] @ (1.0 / W).T / m
        return 0.5 * m * (np.log(a) + 1.0) + 0.5 * np.sum(np.log(W), axis=1)[None, :], a

    def lr(E2):
        L, _ = nll(E2, rhos)
        return 2.0 * (L[:, 0] - L.min(axis=1))

    E2 = (e**2)[None, :]
    stat = float(lr(E2)[0])
    N = rng.standard_normal((n_sim, n))
    Es = N - (N @ Q) @ Q.T
    thr = float(np.quantile(lr(Es**2), 1 - alpha))
    # the estimate: refine the best grid point
    L, _ = nll(E2, rhos)
    j = int(np.argmin(L[0]))
    rho = rhos[j]
    if j > 0:
        lo, hi = np.log(rhos[max(j - 1, 1)]), np.log(rhos[min(j + 1, rhos.size - 1)])
        res = minimize_scalar(lambda lr_: float(nll(E2, np.array([np.exp(lr_)]))[0][0, 0]), bounds=(lo, hi),
                              method="bounded")
        rho = float(np.exp(res.x))
    a = float(nll(E2, np.array([rho]))[1][0, 0])
    s2 = rho * a                                                  # sigma_T^2, s^2
    v = lev * (a + s2 * z)
    G = np.column_stack([lev, lev * z])
    info = 0.5 * (G / v[:, None] ** 2).T @ G
    se_s2 = float(np.sqrt(np.linalg.inv(info)[1, 1]))
    sig = float(np.sqrt(s2))
    se_sig = se_s2 / (2 * sig) if sig > 0 else float(np.sqrt(se_s2))
    # blocked cross-validation of the held-out log-likelihood (rows dealt round-robin in blocks)
    L_blk = max(1, n // (4 * folds))
    fold = (np.arange(n) // L_blk) % folds
    cv0 = cv1 = 0.0
    for f in range(folds):
        tr, te = fold != f, fold == f
        Ltr, Atr = nll(E2, rhos, tr)
        k = int(np.argmin(Ltr[0]))
        for rh, a_, acc in ((0.0, Atr[0, 0], 0), (rhos[k], Atr[0, k], 1)):
            vt = lev[te] * a_ * (1.0 + rh * z[te])
            ll = float(-0.5 * np.sum(np.log(2 * np.pi * vt) + e[te] ** 2 / vt))
            if acc:
                cv1 += ll
            else:
                cv0 += ll
    accepted = bool(stat > thr and stat > np.log(n) and cv1 > cv0)
    share = float(np.sum(lev * s2 * z) / np.sum(lev * (a + s2 * z)))
    return {"statistic": stat, "threshold": thr, "alpha": alpha, "bic_improvement": stat - float(np.log(n)),
            "cv_loglik_without": cv0, "cv_loglik_with": cv1, "accepted": accepted,
            "sigma_T_s": sig, "sigma_T_se_s": float(se_sig), "sigma_T2_s2": s2, "sigma_T2_se_s2": se_s2,
            "resolution_s": float(np.sqrt(12) * sig), "resolution_se_s": float(np.sqrt(12) * se_sig),
            "setting_sigma": float(np.sqrt(a)), "variance_share": share,
            "rate_sigma_rel_at_max_rate": float(sig * np.sqrt(z.max()))}


def _variance_parts(V, X0, r, ref_sigma_dps) -> dict:
    """Noise model of the gyro readings: var_i = max(a + b r_i^2, q_i^2 / 12) + (s sigma_ref,i)^2.

    a is the reading noise, b r^2 the table's rate ripple read at a random moment, q_i the display
    step of reading i, and the last term the known error of the reference rate from the
    stopwatch's resolution (sigma_ref = Omega q_T / (sqrt(12) T), deg/s) times the scale s
    (V per deg/s); a, b >= 0 by non-negative least squares on the rest of the nominal fit's
    squared residuals. Returns var (n,), the ripple coefficient b (V^2 per (deg/s)^2) and the
    display floor q^2/12 (n,)."""
    from scipy.optimize import nnls

    coef = np.linalg.lstsq(X0, V, rcond=None)[0]
    e = V - X0 @ coef
    v_ref = (coef[1] * np.asarray(ref_sigma_dps)) ** 2
    D = np.column_stack([np.ones_like(r), r**2])
    sc = np.linalg.norm(D, axis=0)
    ab, _ = nnls(D / sc, np.clip(e**2 - v_ref, 0, None))
    ab = ab / sc
    q = np.array([reading_resolution([v]) for v in V])
    q = np.minimum(q, 10 * reading_resolution(V))
    return {"var": np.maximum(D @ ab, q**2 / 12) + v_ref, "ripple_V2_per_dps2": float(ab[1]), "floor": q**2 / 12}


def _variance_weights(V, X0, r, ref_sigma_dps) -> np.ndarray:
    """Inverse variances of :func:`_variance_parts`'s noise model."""
    return 1.0 / _variance_parts(V, X0, r, ref_sigma_dps)["var"]


SEED_SAYS = {
    "mains_rate_factor": "4.4.1: the 60 Hz synchronous motor runs on 50 Hz mains: multiply the readings by 5/6",
    "table_slip": "appendix B: measured round times exceed 360/(5/6 dial) by 1-8 % (not explained in the text)",
    "instrument_range_change": "4.4.2: the voltmeter was on autoscale and changed range for the last nine rows",
    "timer_quantisation": "4.4.2-4.4.3: the achievable accuracy depends on the time facility; the round-time "
                          "resolution limits the high rates",
}
