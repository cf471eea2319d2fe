"""Benchmark of mismatch discovery on the concealed-effect suite (not a timed test).

For every effect of the suite: detection rate (correct channels and name, nothing else) at a
realistic size, false discoveries on null records, the fitted parameter's error against truth
(in standard errors), and a power curve -- the smallest size detected in >= 95 % of seeds,
also expressed relative to the noise (see ``relative_size``).

    python benchmarks/bench_diagnose.py --seeds 20                 # the full study
    python benchmarks/bench_diagnose.py --seeds 4 --quick          # a smoke run (no power curves)
    python benchmarks/bench_diagnose.py --fdr 30                   # false-discovery rate of every null group
    python benchmarks/bench_diagnose.py --fdr 30 --groups thermal  # ... of the groups whose name holds a word
    python benchmarks/bench_diagnose.py --power --seeds 10 --effects table_slip,adc_crosstalk
    python benchmarks/bench_diagnose.py --power --seeds 6 --effects lever_arm --sizes 5e-4,1e-3  # own sizes
    python benchmarks/bench_diagnose.py --fdr 40 --effects timer_quantisation   # one case's null records

Detection at the realistic size counts records with exactly the expected findings; the power
curve counts records with at least them. Where a case can give its parameter for every record
(``Case.estimate_param``), z is also reported over all records, not only the detected ones
(those are biased away from zero when the power is below 1).

False-discovery study (``--fdr N``): the null records of every group of ``null_groups()``
over N seeds. A record counts as a false discovery if any channel reports any effect. The
nominal per-record rate is the family-wise bound of the tests the record ran: each call of the
selection engine claims alpha (its max-statistic threshold), a calibrated scatter test its own
p threshold, and the fixed-threshold scatter tests (spikes > 8 robust sigma, spectral peak > 25x,
rate factor > 5 SE) about zero under Gaussian noise; independent tests give
1 - prod(1 - alpha_i). The rate gets a Clopper-Pearson 95 % interval.

Every run prints wall time and peak memory (resident set, MB), and ``--out FILE`` writes JSON.
"""
from __future__ import annotations

import os

# the engine solves thousands of small least-squares problems: one BLAS thread each is ~50x faster
# than a thread pool fighting over a shared 2-core machine (measured: 0.9 ms vs 48 ms for 2304 x 16)
for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse
import inspect
import json
import resource
import time

import numpy as np
from scipy import stats

from imurig.concealed.suite import (
    CASES,
    diagnose_case,
    found_effects,
    null_groups,
    null_recording,
)


def clopper_pearson(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """Exact (Clopper-Pearson) two-sided confidence interval of a binomial rate k/n."""
    a = 1 - level
    lo = 0.0 if k == 0 else float(stats.beta.ppf(a / 2, k, n - k + 1))
    hi = 1.0 if k == n else float(stats.beta.ppf(1 - a / 2, k + 1, n - k))
    return lo, hi


def engine_alpha(rig: str) -> float:
    """The per-call alpha the rig's diagnosis passes to the selection engine (its default)."""
    from imurig.diagnose import rate_table, thermal, tilt_table, turn_table

    fn = {"tilt_table": tilt_table.diagnose_tilt_table, "turn_table": turn_table.diagnose_turn_table,
          "thermal": thermal.diagnose_thermal, "rate_table_rows": rate_table.diagnose_rate_rows}.get(rig)
    if fn is None and rig == "magnetometer":
        from imurig.diagnose.magnetometer import diagnose_magnetometer as fn
    return float(inspect.signature(fn).parameters["alpha"].default)


def record_tests(d: dict, alpha: float) -> list[tuple[str, str, float, bool]]:
    """The tests one diagnosis ran: (channel, kind, nominal false-alarm rate, fired)."""
    out = []

    def engine(ch, e):
        out.append((ch, "engine", alpha, bool(e["findings"])))

    if "axes" in d:
        for a, e in d["axes"].items():
            engine(a, e)
            out.append((a, "spikes (> 8 robust sigma, >= 3)", 0.0, "finding_spikes" in e["scatter"]))
            out.append((a, "spectral peak (> 25x median)", 0.0, "finding_vibration" in e["scatter"]))
        dyn = d.get("dynamic")
        if isinstance(dyn, dict) and "findings" in dyn:  # the slews: one engine call over the stacked axes
            engine("slews", dyn)
    if "channels" in d:
        for ch, e in d["channels"].items():
            engine(ch, e)
    if "gyros" in d and "earth_rate_in_twin" in d:
        for g, e in d["gyros"].items():
            engine(g, e)
            sc = e.get("scatter", {})
            if sc.get("tested"):
                out.append((g, "slip-ring Levene test", float(sc["threshold_p"]), "finding" in sc))
        tt = (d.get("table_rate") or {}).get("timer") or {}
        if tt.get("tested"):
            out.append(("table_rate", "index-pulse timer chi-square", float(tt["alpha"]), bool(tt.get("finding"))))
    elif "gyros" in d:
        out.append(("rate", "rate factor (> 5 SE)", 0.0, bool(d.get("rate_factor"))))
        engine("rate", d["shortfall"]["diagnosis"])
        t = d.get("timer_resolution", {}).get("test")
        if t is not None:
            out.append(("rate", "timer variance LR", float(t["alpha"]), bool(d["timer_resolution"].get("finding"))))
        if "voltmeter" in d:
            engine("voltmeter", d["voltmeter"])
        else:
            for g, e in d["gyros"].items():
                engine(g, e)
    if "magnetometer" in d:
        engine("mag", d["magnetometer"])
        for k, e in d["residual_checks"].items():
            out.append((k, e["kind"], float(e["threshold_p"]), bool(e["finding"])))
    return out


def fdr_study(seeds, groups=None, log=print, cases=None) -> dict:
    """Null records of every null group over ``seeds``; per-record and per-test false discoveries.
    ``cases`` (rig:effect or effect names): instead of the groups, the null records of these cases."""
    res = {}
    if cases:
        todo = [(f"{c.rig}:{c.effect} null", c) for c in CASES if c.effect in cases or f"{c.rig}:{c.effect}" in cases]
    else:
        todo = [(g, c) for i, (g, c) in enumerate(null_groups().items())
                if not groups or any(w == str(i) or (not w.isdigit() and w in g) for w in groups)]
    for group, case in todo:
        alpha = engine_alpha(case.rig)
        t0 = time.perf_counter()
        fd_records, nominal, per_kind, examples = 0, None, {}, []
        for s in seeds:
            d = diagnose_case(case, null_recording(case, s), s, null=True)
            tests = record_tests(d, alpha)
            fired = found_effects(d)
            assert bool(fired) == any(t[3] for t in tests), (group, s, fired, tests)
            fd_records += bool(fired)
            if fired and len(examples) < 5:
                examples.append({"seed": s, "found": sorted(map(list, fired))})
            nominal = 1 - float(np.prod([1 - t[2] for t in tests]))
            for ch, kind, a, hit in tests:
                k = per_kind.setdefault(kind, {"tests": 0, "fired": 0, "nominal_alpha": a})
                k["tests"] += 1
                k["fired"] += hit
            for name in {e for _, e in fired}:  # which effects fired, per record
                k = per_kind.setdefault(f"finding: {name}", {"tests": 0, "fired": 0, "nominal_alpha": None})
                k["fired"] += 1
        for kind, k in per_kind.items():
            if kind.startswith("finding: "):
                k["tests"] = len(seeds)
        n = len(seeds)
        lo, hi = clopper_pearson(fd_records, n)
        for k in per_kind.values():
            k["rate"] = k["fired"] / k["tests"]
            k["ci95"] = clopper_pearson(k["fired"], k["tests"])
        res[group] = {"records": n, "with_false_discovery": fd_records, "rate": fd_records / n, "ci95": [lo, hi],
                      "nominal_per_record": nominal, "engine_alpha_per_call": alpha,
                      "p_value_vs_nominal": float(stats.binomtest(fd_records, n, nominal, "greater").pvalue)
                      if nominal > 0 else (0.0 if fd_records else 1.0),
                      "exceeds_nominal": bool(lo > nominal), "per_test": per_kind, "examples": examples,
                      "wall_s": round(time.perf_counter() - t0, 1)}
        log("null", group, json.dumps(res[group]))
    return res


def fdr_table(res: dict) -> str:
    """Markdown table of an ``fdr_study`` result."""
    rows = [("| null group | records | with a false discovery | rate (95 % CI) | nominal per record | "
             "engine calls: fired / tests (alpha each) | wall s |"), "|---|---|---|---|---|---|---|"]
    for g, r in res.items():
        e = r["per_test"].get("engine", {"fired": 0, "tests": 0})
        rows.append(f"| {g} | {r['records']} | {r['with_false_discovery']} | {r['rate']:.3f} "
                    f"({r['ci95'][0]:.3f}-{r['ci95'][1]:.3f}) | {r['nominal_per_record']:.3f} | "
                    f"{e['fired']}/{e['tests']} ({r['engine_alpha_per_call']:g}) | {r['wall_s']} |")
    return "\n".join(rows)


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--quick", action="store_true", help="skip the power curves")
    ap.add_argument("--fdr", type=int, default=0, metavar="N", help="only the false-discovery study, N seeds per group")
    ap.add_argument("--groups", default="", help="comma-separated null-group indices (see --list) or words "
                    "that the group's name holds")
    ap.add_argument("--list", action="store_true", help="list the null groups and cases, then stop")
    ap.add_argument("--power", action="store_true", help="only detection and power curves (no null study)")
    ap.add_argument("--effects", default="", help="comma-separated effect names or rig:effect (default: all); "
                    "with --fdr: the null records of these cases instead of the null groups")
    ap.add_argument("--sizes", default="", help="comma-separated sizes for the power curve (default: the case's)")
    ap.add_argument("--first-seed", type=int, default=None, help="first seed (default 100; --fdr: 1000)")
    ap.add_argument("--out", default="", help="write the results as JSON to this file")
    a = ap.parse_args(argv)
    t0 = time.perf_counter()
    groups = [w for w in a.groups.split(",") if w]
    if a.list:
        for i, (g, c) in enumerate(null_groups().items()):
            print(f"null group {i}: {g} (case {c.effect})")
        print("cases:", ", ".join(c.effect for c in CASES))
        return {}
    effects = [w for w in a.effects.split(",") if w]
    if a.fdr:
        s0 = 1000 if a.first_seed is None else a.first_seed
        out = {"fdr": fdr_study(list(range(s0, s0 + a.fdr)), groups, cases=effects)}
        print(fdr_table(out["fdr"]))
    else:
        out = {"null": {}, "effects": {}}
        s0 = 100 if a.first_seed is None else a.first_seed
        seeds = list(range(s0, s0 + a.seeds))
        if not a.power:
            out["null"] = fdr_study(seeds, groups)
        sizes = tuple(float(x) for x in a.sizes.split(",") if x) or None
        for case in CASES:
            key = f"{case.rig}:{case.effect}"  # effect names repeat across rigs (time_delay, temperature_drift)
            if effects and case.effect not in effects and key not in effects:
                continue
            out["effects"][key] = effect_study(case, seeds, power=not a.quick, sizes=sizes)
            print(key, json.dumps(out["effects"][key]), flush=True)
    out["wall_s"] = round(time.perf_counter() - t0, 1)
    out["peak_rss_mb"] = round(peak_rss_mb(), 1)
    print(f"wall {out['wall_s']} s, peak memory {out['peak_rss_mb']} MB")
    if a.out:
        with open(a.out, "w", encoding="utf-8") as fh:
            json.dump(out, fh, indent=1, default=float)
    return out


def _acc_noise(rec, d, axis="y"):
    """Within-position sample noise of an accelerometer (m/s^2, 100 Hz): robust sigma / sensitivity."""
    j = "xyz".index(axis)
    return d["axes"][axis]["scatter"]["robust_sigma_V"] / rec.meta["acc_nominal_sensitivity_V_per_m_s2"][j]


def _record_seconds(rec, d):
    """Acquisition time of the record (s): spike rates become expected spikes per record."""
    seg = rec.segments
    return float(np.sum(seg["stop_s"] - seg["start_s"]))


def _mag_noise(rec, d):
    """The fluxgate's sample noise (nT, 100 Hz) from the diagnosis' noise model."""
    return float(np.mean(d["noise"]["sample_sigma_nT"]))


def _mag_noise_per_field(rec, d):
    """Sample noise over the field intensity: a coupling s of the field is s |B| nT."""
    return _mag_noise(rec, d) / float(np.linalg.norm(d["igrf_field_W_nT"]))


def _mag_noise_per_kelvin(rec, d):
    """Sample noise over the temperature swing of the record: a tempco c moves the offset c dT nT."""
    from imurig.diagnose.magnetometer import _temperature_K

    return _mag_noise(rec, d) / float(np.ptp(_temperature_K(rec)))


def _gyro_noise(rec, d, gyro="p"):
    """Gyro p's fast sample noise (V): the median over table-angle bins of its robust spread."""
    return float(np.median(d["gyros"][gyro]["scatter"]["noise_V_by_angle_bin"]))


def _rate_ratio_se(rec, d):
    """The standard error of the mean rate ratio measured / dial (1): a rate factor f is |1 - f| / SE."""
    return float(d["locate"]["rate_ratio_se"])


def _table_setting_seconds(rec, d):
    """The table's relative setting error expressed as round-time error at the fastest row (s):
    sqrt(12) x (setting sigma) x (shortest round time), the stopwatch resolution q whose round-time
    error equals the table's own scatter there."""
    t = d["timer_resolution"]["test"]
    T = rec.channels["measured_round"]
    return float(np.sqrt(12) * t["setting_sigma"] * T[T > 0].min())


#: effect -> (recording, diagnosis) -> the noise (or exposure) the effect's size is compared with
NOISE_REFERENCE = {"building_vibration": _acc_noise, "slip_ring_noise": _gyro_noise,
                   "mains_rate_factor": _rate_ratio_se, "timer_quantisation": _table_setting_seconds, "cable_fault_spikes": lambda rec, d: 1.0 / _record_seconds(rec, d),
                   "hard_iron": _mag_noise, "local_field_anomaly": _mag_noise, "soft_iron": _mag_noise_per_field,
                   "misalignment": _mag_noise_per_field, "magnetometer:temperature_drift": _mag_noise_per_kelvin}


def _noise_reference(case):
    """The case's entry of NOISE_REFERENCE (by rig:effect, else by effect), or None."""
    return NOISE_REFERENCE.get(f"{case.rig}:{case.effect}", NOISE_REFERENCE.get(case.effect))


def effect_study(case, seeds, power=True, sizes=None) -> dict:
    """Detection, parameter z and (``power``) the power curve of one case (``sizes``: instead of the
    case's). At the realistic size a record counts as detected when the diagnosis reports exactly the
    expected (channel, effect) pairs; on the power curve when it reports at least them. A size of the
    curve equal to the realistic size reuses the realistic runs."""
    t0 = time.perf_counter()
    hits, hits_curve, z, z_all, snr, se, noise = 0, 0, [], [], [], [], []
    misses = []
    for s in seeds:
        rec = case.make(s, case.realistic_size)
        d = diagnose_case(case, rec, s)
        f = found_effects(d)
        hits += f == case.expected
        hits_curve += f >= case.expected
        if f != case.expected and len(misses) < 6:
            misses.append({"seed": s, "found": sorted(map(list, f))})
        if case.truth_param and case.found_param and case.found_param(d):
            est, e_se = case.found_param(d)
            z.append((est - case.truth_param(rec)) / e_se)
            snr.append(abs(case.truth_param(rec)) / e_se)
            se.append(e_se)
        if case.truth_param and case.estimate_param:
            est, e_se = case.estimate_param(d)
            z_all.append((est - case.truth_param(rec)) / e_se)
        if _noise_reference(case) is not None:
            noise.append(_noise_reference(case)(rec, d))
    row = {"realistic_size": case.realistic_size, "size_unit": case.size_unit, "seeds": len(seeds),
           "detection_rate": hits / len(seeds), "detected": hits, "misses": misses,
           "parameter_z_rms": float(np.sqrt(np.mean(np.square(z)))) if z else None,
           "parameter_z_mean": float(np.mean(z)) if z else None,
           # the injected parameter in units of its standard error at the realistic size (the fit's SNR)
           "parameter_snr_realistic": float(np.median(snr)) if snr else None,
           "parameter_se_realistic": float(np.median(se)) if se else None,
           "noise_reference": float(np.median(noise)) if noise else None}
    if z_all:  # over every record, detected or not
        row["parameter_z_rms_all_records"] = float(np.sqrt(np.mean(np.square(z_all))))
        row["parameter_z_mean_all_records"] = float(np.mean(z_all))
    sizes = case.sizes if sizes is None else sizes
    if power and sizes:
        curve = {}
        for size in sizes:
            if np.isclose(size, case.realistic_size, rtol=1e-12, atol=0):
                curve[size] = hits_curve / len(seeds)
                continue
            h = sum(found_effects(diagnose_case(case, case.make(s, size), s)) >= case.expected for s in seeds)
            curve[size] = h / len(seeds)
            print(f"  {case.rig}:{case.effect} size {size:g}: {h}/{len(seeds)} "
                  f"({time.perf_counter() - t0:.0f} s)", flush=True)
        row["power_curve"] = curve
        ok = [sz for sz, p in curve.items() if p >= 0.95]
        row["smallest_size_detected_95pct"] = s95 = min(ok) if ok else None
        if s95 is not None and row["parameter_snr_realistic"]:
            # linear effects: the parameter and its SNR scale with the size, the SE does not
            row["snr_at_95pct"] = row["parameter_snr_realistic"] * s95 / case.realistic_size
        if s95 is not None and row["noise_reference"]:
            row["size_over_noise_at_95pct"] = s95 / row["noise_reference"]
    row["wall_s"] = round(time.perf_counter() - t0, 1)
    return row


if __name__ == "__main__":
    main()
