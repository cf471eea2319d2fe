"""The diagnosis on data the project did not simulate (issue 16, "What must hold").

The independent lab (tests/independent_lab, numpy only) writes minimal lab CSVs with one concealed
effect each, at its realistic (seed-level) size, or none; every file goes through the user's path
(load, then dispatch.diagnose) in a capped child process (benchmarks/bench_diagnosis_independent.py).
A refused or crashed file is a miss. Asserted, per effect and per rig's nulls:

- named right (every expected channel and effect, nothing else) in >= 90 % of the recordings where
  the effect is detectable at all: a mean-level tilt effect (drift, nonlinearity, misalignment,
  crosstalk) is scored only where its expected non-centrality, computed from the lab's manifest
  (effect size, noise, ADC step, positions and samples: benchmarks/independent_detectability.py),
  reaches the 90 % power point of its test, and likewise a turn-table slip-ring ripple (per gyro,
  against the converter's step and noise) and a timer jitter (the pulse test's simulated power:
  benchmarks/independent_detectability_turn.py); the others are listed in the report with their figures,
  and at least half of each effect's recordings must be detectable (so the criterion cannot empty);
- false discoveries on nulls at or below the nominal family-wise rate per record (the rate's
  95 % Clopper-Pearson lower bound must not exceed it, the project's convention in
  benchmarks/bench_diagnose.py);
- the scored parameter's z = (estimate - truth) / SE with RMS <= 1.5 over the recordings.

IMURIG_INDEPENDENT_SEEDS (default 10) sets the recordings per effect and the nulls per rig.
"""
from __future__ import annotations

import importlib.util
import os
from pathlib import Path

import pytest
from scipy import stats

BENCH = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_diagnosis_independent.py"


def _bench():
    spec = importlib.util.spec_from_file_location("bench_diagnosis_independent", BENCH)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _ci_low(k: int, n: int) -> float:
    return 0.0 if k == 0 else float(stats.beta.ppf(0.025, k, n - k + 1))


@pytest.mark.slow
def test_diagnosis_holds_on_the_independent_lab(tmp_path):
    b = _bench()
    n = int(os.environ.get("IMURIG_INDEPENDENT_SEEDS", "10"))
    res = b.independent_study(tmp_path, range(n), n, timeout_s=600.0, mem_gb=6.0, log=lambda *a: None)
    report = b.table(res, None) + "\nerrors: " + "; ".join(f"{len(v)} x {k}" for k, v in res["errors"].items())
    bad = []
    for effect, v in res["effects"].items():
        if v["n_detectable"] < v["n"] / 2:
            bad.append(f"{effect}: only {v['n_detectable']} of {v['n']} recordings detectable")
        elif v["named_right"] < 0.9:
            bad.append(f"{effect}: named right {v['named_right']:.0%} of {v['n_detectable']} detectable < 90 %")
        if v["z_rms"] is None or v["z_rms"] > 1.5:
            bad.append(f"{effect}: parameter z RMS {v['z_rms']} (over {v['n_z']} records) > 1.5")
    for rig, v in res["nulls"].items():
        ok = v["n"] - v["refused"]
        if v["refused"]:
            bad.append(f"{rig} nulls: {v['refused']} of {v['n']} refused")
        if ok and _ci_low(v["false_discoveries"], ok) > v["nominal_fwer"]:
            bad.append(f"{rig} nulls: {v['false_discoveries']}/{ok} false discoveries, above the nominal "
                       f"{v['nominal_fwer']:.3f}")
    assert not bad, "\n".join(bad) + "\n" + report
