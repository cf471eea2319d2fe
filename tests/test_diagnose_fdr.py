"""False discoveries of the mismatch engine at its nominal alpha.

Default: the selection engine on synthetic white-noise data with a scanned library (a step at
an unknown row, a square, a sinusoid): the share of null runs that accept any effect must be
consistent with the claimed family-wise alpha (one-sided binomial test at the 1 % level).

Slow: the null records of every null group of the concealed-effect suite over many seeds
(``benchmarks/bench_diagnose.py --fdr N`` runs the same study): the per-record false-discovery
rate must not lie significantly above the family-wise bound of the tests the record ran.
"""
from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from imurig.diagnose.engine import Candidate, select_effects


def _bench():
    path = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_diagnose.py"
    spec = importlib.util.spec_from_file_location("bench_diagnose", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_engine_family_wise_rate_on_white_noise():
    alpha, reps, m = 0.1, 150, 40
    x = np.linspace(-1, 1, m)
    X0 = np.column_stack([np.ones(m), x])
    idx = np.arange(m)
    lib = [Candidate("step", "a step at an unknown row", ("h",), lambda k: (idx >= k).astype(float),
                     scan=tuple(range(8, 33, 4)), scan_name="row"),
           Candidate("square", "a square term", ("c",), lambda _: x**2),
           Candidate("ripple", "a sinusoid", ("a", "b"), lambda _: np.column_stack([np.sin(7 * x), np.cos(7 * x)]))]
    rng = np.random.default_rng(2024)
    fired = 0
    for _ in range(reps):
        y = 0.3 + 2.0 * x + rng.standard_normal(m)
        d = select_effects(y, X0, ["c0", "c1"], lib, rng, alpha=alpha, n_sim=100)
        fired += bool(d.findings)
    p = stats.binomtest(fired, reps, alpha, alternative="greater").pvalue
    assert p > 0.01, (fired, reps, alpha)
    # and the threshold is not so conservative that it never fires (it is a level-alpha test)
    assert stats.binomtest(fired, reps, alpha, alternative="less").pvalue > 0.01, (fired, reps, alpha)


def test_clopper_pearson_interval():
    b = _bench()
    lo, hi = b.clopper_pearson(0, 30)
    assert lo == 0.0 and hi == pytest.approx(1 - 0.025 ** (1 / 30))
    lo, hi = b.clopper_pearson(3, 60)
    # the exact interval covers 3/60 and matches the beta quantiles
    assert lo == pytest.approx(stats.beta.ppf(0.025, 3, 58)) and hi == pytest.approx(stats.beta.ppf(0.975, 4, 57))
    assert lo < 0.05 < hi


@pytest.mark.slow
def test_null_groups_false_discovery_rate_at_nominal():
    """Every null group over 30 seeds: the per-record false-discovery count must not be
    significantly (one-sided binomial p < 0.01) above the record's nominal family-wise rate."""
    b = _bench()
    res = b.fdr_study(list(range(3000, 3030)), log=lambda *a: None)
    bad = {g: (r["with_false_discovery"], r["records"], round(r["nominal_per_record"], 3))
           for g, r in res.items() if r["p_value_vs_nominal"] < 0.01}
    assert not bad, bad
