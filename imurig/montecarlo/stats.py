"""Statistics of a Monte-Carlo study: error distribution, bias, RMS against the Cramér-Rao
bound, honesty of the reported standard errors, and interval coverage with binomial bands.

For parameter j over N runs with estimation error e_i = estimate_i - injected_i:

    bias  = mean(e),  SE(bias) = std(e) / sqrt(N)
    RMS   = sqrt(mean(e^2))
    CRLB  = sqrt(mean(crlb_i^2))       (each run's bound at its own drawn truth)
    SE    = sqrt(mean(se_i^2))         (the estimator's reported standard errors)
    coverage = #{|e_i| <= z_q se_i} / N, z_q = 1.959964 (95 % two-sided normal intervals)

The coverage of a 95 % interval over N independent runs is Binomial(N, 0.95)/N if the
intervals are right: ``band`` is its central 99 % acceptance region (a coverage outside it
says the intervals are wrong, with a 1 % false-alarm rate per parameter); ``ci`` is the
Clopper-Pearson 95 % confidence interval of the true coverage.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import stats as sst

LEVEL = 0.95
BAND = 0.99


def binomial_band(n: int, p: float = LEVEL, level: float = BAND) -> tuple[float, float]:
    """Central acceptance region [lo, hi] (as fractions) of Binomial(n, p)/n with probability >= level."""
    a = (1 - level) / 2
    return float(sst.binom.ppf(a, n, p) / n), float(sst.binom.isf(a, n, p) / n)


def clopper_pearson(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    a = (1 - level) / 2
    lo = 0.0 if k == 0 else float(sst.beta.ppf(a, k, n - k + 1))
    hi = 1.0 if k == n else float(sst.beta.isf(a, k + 1, n - k))
    return lo, hi


def table_arrays(rows_by_run: dict[int, list[dict]]):
    """Columnar arrays (N, P) of estimate, std_error, injected, crlb and the names/units."""
    idx = sorted(rows_by_run)
    names, units = [], {}
    for i in idx:
        for r in rows_by_run[i]:
            if r["name"] not in units:
                names.append(r["name"])
                units[r["name"]] = r.get("unit", "")
    pos = {n: k for k, n in enumerate(names)}
    arr = {k: np.full((len(idx), len(names)), np.nan) for k in ("estimate", "std_error", "injected", "crlb", "z")}
    for a, i in enumerate(idx):
        for r in rows_by_run[i]:
            for k, col in arr.items():
                v = r.get(k)
                if v is not None:
                    col[a, pos[r["name"]]] = v
    return np.array(idx), names, [units[n] for n in names], arr


def parameter_stats(rows_by_run: dict[int, list[dict]]) -> list[dict]:
    """Per-parameter statistics (see module doc), one dict per parameter."""
    if not rows_by_run:
        return []
    _, names, units, A = table_arrays(rows_by_run)
    zq = float(sst.norm.isf((1 - LEVEL) / 2))
    out = []
    for j, (name, unit) in enumerate(zip(names, units)):
        e = A["estimate"][:, j] - A["injected"][:, j]
        ok = np.isfinite(e)
        n = int(ok.sum())
        d = {"name": name, "unit": unit, "runs": n}
        if n == 0:
            out.append(d)
            continue
        e = e[ok]
        se = A["std_error"][ok, j]
        cr = A["crlb"][ok, j]
        d["bias"] = float(np.mean(e))
        d["bias_se"] = float(np.std(e, ddof=1) / math.sqrt(n)) if n > 1 else None
        d["rms"] = float(math.sqrt(np.mean(e**2)))
        d["std"] = float(np.std(e, ddof=1)) if n > 1 else None
        d["injected_spread"] = float(np.std(A["injected"][ok, j])) if n > 1 else None
        d["crlb"] = float(math.sqrt(np.nanmean(cr**2))) if np.any(np.isfinite(cr)) else None
        d["rms_over_crlb"] = d["rms"] / d["crlb"] if d["crlb"] else None
        good = np.isfinite(se) & (se > 0)
        d["mean_se"] = float(math.sqrt(np.mean(se[good] ** 2))) if good.any() else None
        d["rms_over_se"] = d["rms"] / d["mean_se"] if d["mean_se"] else None
        if good.any():
            k = int(np.sum(np.abs(e[good]) <= zq * se[good]))
            m = int(good.sum())
            d["coverage"] = k / m
            d["coverage_ci"] = list(clopper_pearson(k, m))
            d["coverage_band"] = list(binomial_band(m))
            d["coverage_ok"] = bool(d["coverage_band"][0] <= k / m <= d["coverage_band"][1])
        out.append(d)
    return out


def error_matrix(rows_by_run) -> tuple[list[str], np.ndarray]:
    """(names, errors (N, P)) estimate - injected."""
    _, names, _, A = table_arrays(rows_by_run)
    return names, A["estimate"] - A["injected"]
