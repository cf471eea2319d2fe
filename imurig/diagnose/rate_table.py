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
   variance term (:func:`imurig.diagnose.rate_timer.timer_quantisation_test`): a likelihood ratio of
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
from scipy.optimize import nnls

from imurig.diagnose.engine import select_effects, wild_bootstrap_noise
from imurig.diagnose.rate_timer import timer_quantisation_test
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
    out["locate"], out["rate_factor"] = _rate_factor(k, T[timed], dial[timed])
    f_use = out["rate_factor"]["factor"] if out["rate_factor"] else 1.0
    d = k / f_use - 1.0
    r_dps = np.degrees(rate)
    lib, diag = _shortfall(d, r_dps, rng, alpha, n_sim)
    out["shortfall"] = {"mean_shortfall": float(-np.mean(d)), "diagnosis": diag.to_dict(),
                        "note": "d = measured rate / (factor x dial) - 1; negative = slower than set",
                        "residuals": {"rate_dps": r_dps.tolist(), "before": diag.before.residuals_.tolist(),
                                      "after": diag.after.residuals_.tolist()}}
    # --- 2. timer resolution ------------------------------------------------------
    # the scatter of d is the dial's setting error (homoscedastic), far above the stopwatch's
    q = reading_resolution(T[timed])
    res_rate = np.degrees(rate) * (q / np.sqrt(12)) / T[timed]
    out["timer_resolution"] = _timer_resolution(q, res_rate, diag.after.residuals_ * np.degrees(rate), r_dps)
    # --- 3. gyro channels ---------------------------------------------------------
    # locate a range change by the readings' display grid (one voltmeter reads all three gyros)
    out["range_change_by_resolution"], k_grid = _range_change_by_resolution(rec, timed, rows)
    scan_k = (k_grid,) if k_grid is not None else tuple(range(3, rows.size - 2))
    out["gyros"] = _gyro_entries(rec, timed, rows, r_dps, res_rate, scan_k, rng, alpha, n_sim)
    # the three gyros are read by one voltmeter: test its range change jointly -- one relative gain
    # step and one offset step for all three, against each gyro's own nonlinearity
    joint = _voltmeter(rec, timed, rows, r_dps, res_rate, scan_k, rng, alpha, n_sim)
    if joint is not None:
        out["voltmeter"] = joint
    # --- 2 (cont.). the timer's round-time error, tested last (so the draws above do not depend on it)
    test, finding = _timer_test(lib, diag, T[timed], rng, alpha, n_sim)
    out["timer_resolution"]["test"] = test
    if finding is not None:
        out["timer_resolution"]["finding"] = finding
    return out


def _rate_factor(k: np.ndarray, T: np.ndarray, dial: np.ndarray) -> tuple[dict, dict | None]:
    """Where the rate mismatch sits, and the mains-frequency factor it matches (None: none far from 1).
    ``k`` = measured rate / dial, ``T`` round times [s], ``dial`` [rad/s] of the timed rows."""
    k_mean = float(np.mean(k))
    k_se = float(np.std(k, ddof=1) / np.sqrt(k.size))
    name, f = min(MOTOR_MAINS.items(), key=lambda it: abs(np.log(k_mean / it[1])))
    locate = {"round_time_ratio_median": float(np.median(T * dial / (2 * np.pi))),
              "rate_ratio_mean": k_mean, "rate_ratio_se": k_se}
    rate_factor = None
    if abs(k_mean - 1) > 5 * k_se and f != 1.0:
        rate_factor = {"effect": "mains_rate_factor", "physics": f"synchronous table motor: {name} turns at "
                       f"{f:.4f} of the dial", "factor": f, "mean_ratio": k_mean, "mean_ratio_se": k_se}
    return locate, rate_factor


def _shortfall(d: np.ndarray, r_dps: np.ndarray, rng: np.random.Generator, alpha: float, n_sim: int,
               weights: np.ndarray | None = None):
    """The shortfall d against a constant, with slip and a proportional rate error as candidates:
    (library, diagnosis). Without ``weights`` (stopwatch rows, whose errors grow with the rate in a way
    no model gives): the threshold from a wild bootstrap of the residuals. With ``weights`` (relative
    inverse variances: a pulse-timed window's relative rate error is sqrt(2) sigma_e / T_w, so weights
    T_w^2): Gaussian noise of those variances. The wild bootstrap's signs then cost the power that a
    few windows cannot spare: its residuals hold the effect under test, so one sign pattern in 2^n
    redraws the data itself (10 windows: the threshold swung between 0.5x and 2x the statistic of a
    30 % slip with the seed of its 300 draws)."""
    lib = [c for cls in for_view(RateShortfallView.kind) for c in cls().candidates(RateShortfallView(r_dps))]
    if weights is not None:
        diag = select_effects(d, np.ones((d.size, 1)), ["shortfall"], lib, rng, alpha=alpha, n_sim=n_sim,
                              weights=np.asarray(weights, float) / np.mean(weights))
        return lib, diag
    # the rows' errors grow with the rate (the timer): threshold from a wild bootstrap of the residuals
    diag = select_effects(d, np.ones((d.size, 1)), ["shortfall"], lib, rng, alpha=alpha, n_sim=n_sim,
                          noise=wild_bootstrap_noise(d, np.ones((d.size, 1))))
    return lib, diag


def _timer_resolution(q: float, res_rate: np.ndarray, resid: np.ndarray, r_dps: np.ndarray) -> dict:
    """The round times' grid q [s] as evidence: the rate sigma it gives [deg/s] and the rate
    residual ``resid`` [deg/s] at high against low rates."""
    hi = r_dps > np.median(r_dps)
    return {"effect": "timer_quantisation", "resolution_s": q,
            "physics": f"round times are known to {q:g} s: at {r_dps.max():.0f} deg/s that is "
                       f"{res_rate.max():.3f} deg/s (1 sigma) on the rate",
            "rate_sigma_dps_at_max_rate": float(res_rate.max()),
            "rate_sigma_dps_at_min_rate": float(res_rate.min()),
            "rate_residual_rms_dps_high_rates": float(np.sqrt(np.mean(resid[hi] ** 2))),
            "rate_residual_rms_dps_low_rates": float(np.sqrt(np.mean(resid[~hi] ** 2)))}


def _range_change_by_resolution(rec: Recording, timed: np.ndarray, rows: np.ndarray) -> tuple[dict | None, int | None]:
    """The row from which every gyro reading sits on a coarser display grid (None: none), and its index."""
    n = rows.size
    grid_rows = [resolution_change_row(rec.channels[f"gyro_{g}"][timed]) for g in GYROS if f"gyro_{g}" in rec.channels]
    k_grid = max(grid_rows) if grid_rows and all(k is not None for k in grid_rows) else None
    entry = None if k_grid is None else {
        "first_row": int(rows[k_grid]), "rows_after": int(n - k_grid),
        "resolution_before_V": reading_resolution(np.concatenate([rec.channels[f"gyro_{g}"][timed][:k_grid]
                                                                  for g in GYROS if f"gyro_{g}" in rec.channels])),
        "resolution_after_V": reading_resolution(np.concatenate([rec.channels[f"gyro_{g}"][timed][k_grid:]
                                                                 for g in GYROS if f"gyro_{g}" in rec.channels]))}
    return entry, k_grid


def _gyro_entries(rec: Recording, timed: np.ndarray, rows: np.ndarray, r_dps: np.ndarray, res_rate: np.ndarray,
                  scan_k: tuple, rng: np.random.Generator, alpha: float, n_sim: int) -> dict:
    """Each gyro's voltage against the stopwatch rate (linear nominal model) and its own effects."""
    gy = {}
    n = rows.size
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
    return gy


def _voltmeter(rec: Recording, timed: np.ndarray, rows: np.ndarray, r_dps: np.ndarray, res_rate: np.ndarray,
               scan_k: tuple, rng: np.random.Generator, alpha: float, n_sim: int) -> dict | None:
    """The gyros' voltages jointly (one voltmeter reads them all): its range change as one relative
    gain step and one offset step for all, against each gyro's own nonlinearity; None for one gyro."""
    n = rows.size
    idx = np.arange(n)
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
        return joint
    return None


def _timer_test(lib: list, diag, T_s: np.ndarray, rng: np.random.Generator, alpha: float, n_sim: int):
    """The timer's round-time error in the shortfall's residual (:func:`timer_quantisation_test`):
    (test, finding or None)."""
    lookup = {c.name: c for c in lib}
    X_after = np.column_stack([np.ones(T_s.size)] + [lookup[f.name].design(f.theta) for f in diag.findings])
    test = timer_quantisation_test(diag.after.residuals_, X_after, T_s, rng, alpha=alpha, n_sim=max(n_sim, 1000))
    if not test["accepted"]:
        return test, None
    return test, {
        "effect": "timer_quantisation",
        "physics": "the round times carry a timer error (resolution of the stopwatch or of the pulse timing) "
                   "that the twin, timing rounds exactly, leaves out: rate scatter growing with the rate",
        "statistic": test["statistic"], "threshold": test["threshold"],
        "parameters": [{"name": "sigma_T_s", "estimate": test["sigma_T_s"], "std_error": test["sigma_T_se_s"]},
                       {"name": "resolution_s_if_rounded", "estimate": test["resolution_s"],
                        "std_error": test["resolution_se_s"]}],
        "variance_share": test["variance_share"], "indistinguishable_from": None}


def _variance_parts(V, X0, r, ref_sigma_dps) -> dict:
    """Noise model of the gyro readings: var_i = max(a + b r_i^2, q_i^2 / 12) + (s sigma_ref,i)^2.

    a is the reading noise, b r^2 the table's rate ripple read at a random moment, q_i the display
    step of reading i, and the last term the known error of the reference rate from the
    stopwatch's resolution (sigma_ref = Omega q_T / (sqrt(12) T), deg/s) times the scale s
    (V per deg/s); a, b >= 0 by non-negative least squares on the rest of the nominal fit's
    squared residuals. Returns var (n,), the ripple coefficient b (V^2 per (deg/s)^2) and the
    display floor q^2/12 (n,)."""
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
