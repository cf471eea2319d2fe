"""The diagnosis scored on data the project did not simulate, beside its own concealed suite.

(a) The independent lab (``tests/independent_lab``, numpy only) writes minimal lab CSVs (time,
set-points or rate dial, channel voltages, ``# rig:`` and ``# site:``) with one concealed effect
each or none, and a truth manifest beside each file. Every file goes through what a user runs:
``imurig.kernel.files.load`` then ``imurig.diagnose.dispatch.diagnose``, in a child process with
a memory cap and a time limit, so a refused, crashed, killed or timed-out file counts as a miss
with its error recorded. (b) The project's own suite (``imurig.concealed``) at realistic size,
scored by ``imurig.concealed.cases.score``.

Per effect: named right (every expected (channel, effect) found and no other effect named),
false discoveries on nulls against the nominal family-wise rate per record, and the parameter z
= (estimate - truth) / SE of the manifest's scored parameter (RMS over records that gave one);
plus wall time, CPU time and peak memory per file.

    python benchmarks/bench_diagnosis_independent.py --seeds 1                  # one of each + nulls
    python benchmarks/bench_diagnosis_independent.py --seeds 10 --nulls 20 --suite-seeds 2 --out res.json
    python benchmarks/bench_diagnosis_independent.py --seeds 1 --suite-cases none   # the independent side only
"""
from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):   # see bench_diagnose.py
    os.environ.setdefault(_v, "1")

import argparse
import importlib.util
import json
import math
import resource
import subprocess
import sys
import tempfile
import time
import traceback
from collections import defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
#: the per-record false-alarm rate of one engine call when a diagnosis gives none (the rigs' default alpha)
DEFAULT_ALPHA = 0.01
#: names a diagnosis may give an effect the lab calls otherwise (lab name -> accepted names)
ALIASES = {"time_delay": {"time_delay", "channel_skew", "setpoint_delay", "slew_lag"},
           "saturation": {"saturation", "clipping"},
           "slip_ring_noise": {"slip_ring_noise", "slip_ring_ripple"}}
JOINT = {"", "acc", "gyro", "gyros", "rate", "table_rate", "all", "table", "slews", "mag"}
GYRO_AXES = {"p": "gyro_x", "q": "gyro_y", "r": "gyro_z"}


def _bench_diagnose():
    """The concealed suite's own benchmark module (its per-record family-wise bound)."""
    spec = importlib.util.spec_from_file_location("bench_diagnose", ROOT / "benchmarks" / "bench_diagnose.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def detectability(truth: dict, csv: Path) -> dict | None:
    """The expected non-centrality of a recording's mean-level tilt effect, slip-ring ripple or timer
    jitter against the one a test needs (``benchmarks/independent_detectability.py``,
    ``benchmarks/independent_detectability_turn.py``), or None where it does not apply."""
    spec = importlib.util.spec_from_file_location("independent_detectability",
                                                  ROOT / "benchmarks" / "independent_detectability.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.detectability(truth, csv, independent_lab().tilt)


def independent_lab():
    """The independent generator (a package of the tests tree)."""
    sys.path.insert(0, str(ROOT / "tests"))
    import independent_lab as lab   # lazy: it lives in the tests tree, not in the installed package
    return lab


# ---------------------------------------------------------------------------------------------- reading findings
def channel_name(ch: str, rig: str) -> str:
    """A diagnosis' channel label in the lab's names: 'y' -> acc_y (tilt), 'p' -> gyro_x, 'gyro_p' -> gyro_x."""
    ch = str(ch or "")
    if ch in GYRO_AXES or (ch.startswith("gyro_") and ch[-1] in GYRO_AXES):
        return GYRO_AXES[ch[-1]]
    if ch in ("x", "y", "z"):
        return ("acc_" if rig == "tilt_table" else "gyro_") + ch
    return ch


def _params(f: dict) -> dict:
    """{name: (estimate, std_error)} of a finding (a list of parameter dicts or a mapping)."""
    out = {}
    ps = f.get("parameters") or []
    items = ps.items() if isinstance(ps, dict) else ((p.get("name"), p) for p in ps if isinstance(p, dict))
    for name, p in items:
        if isinstance(p, dict) and "estimate" in p:
            se = p.get("std_error", p.get("se"))
            out[str(name).split(":")[-1]] = (float(p["estimate"]), float(se) if se is not None else float("nan"))
    return out


def findings_of(d: dict, rig: str) -> list[dict]:
    """[{effect, channel, params}] of a diagnosis: its top-level ``findings`` list where it has one
    (the documented diagnosis.json), else the per-rig results read as the concealed suite reads them."""
    out = []
    if not isinstance(d.get("findings"), list):
        from imurig.diagnose.summary import findings   # lazy: only the child imports imurig
        d = {"findings": findings(d)}   # the documented diagnosis.json's list, as a user reads it
    if isinstance(d.get("findings"), list):
        for f in d["findings"]:
            out.append({"effect": f.get("effect"), "channel": channel_name(f.get("channel"), rig), "params": _params(f)})
        return out
    from imurig.concealed.suite import found_effects   # lazy: only the child and the suite side import imurig
    params = {}

    def walk(x, ch=""):
        if isinstance(x, dict):
            if "effect" in x and "parameters" in x:
                params.setdefault((channel_name(ch, rig), x["effect"]), _params(x))
            for k, v in x.items():
                walk(v, k if k in ("x", "y", "z", "p", "q", "r") or str(k).startswith(("acc_", "gyro_")) else ch)
        elif isinstance(x, list):
            for v in x:
                walk(v, ch)
    walk(d)
    for ch, eff in sorted(found_effects(d)):
        c = channel_name(ch, rig)
        out.append({"effect": eff, "channel": c, "params": params.get((c, eff), {})})
    return out


def _matches(found: dict, expected: str) -> bool:
    ch, eff = expected.split(":")
    if found["effect"] not in ALIASES.get(eff, {eff}):
        return False
    fc = found["channel"]
    return fc == ch or fc in JOINT or ch in JOINT and fc.startswith(ch)


def score_record(truth: dict, res: dict) -> dict:
    """Named right, false discovery and z of one independent recording's result."""
    found = res.get("findings") or []
    expected = truth["expected"]
    names = {n for e in truth["effects"] for n in ALIASES.get(e["effect"], {e["effect"]})}
    extra = sorted({f"{f['channel']}:{f['effect']}" for f in found if f["effect"] not in names})
    out = {"ok": res.get("ok", False), "error": res.get("error"), "found": sorted(f"{f['channel']}:{f['effect']}"
                                                                              for f in found),
           "unexplained": res.get("unexplained", []), "extra": extra}
    out["right"] = bool(res.get("ok")) and all(any(_matches(f, x) for f in found) for x in expected) and not extra \
        and bool(expected)
    out["false_discovery"] = bool(res.get("ok")) and not expected and bool(found)
    for e in truth["effects"]:
        sc = dict(e["score"])
        if "per_nominal_V_per_m_s2" in sc:
            # the lab states the parameter for a reader whose nominal sensitivity is its own (1 V per g);
            # in the reader's units it scales with (the nominal the reader used / the lab's) ** power
            used = (res.get("nominal_sensitivity") or {}).get("acc_nominal_sensitivity_V_per_m_s2")
            if used is not None:
                ch = "xyz".index(str(sc.get("channel", "acc_x"))[-1])
                s_used = float(np.broadcast_to(np.asarray(used, float), (3,))[ch])
                sc["value"] = sc["value"] * (s_used / sc["per_nominal_V_per_m_s2"]) ** sc.get("nominal_power", 1)
        for f in found:
            if f["effect"] in ALIASES.get(e["effect"], {e["effect"]}) and sc["name"] in f["params"] and \
                    (sc.get("channel") is None or f["channel"] in (sc["channel"], *JOINT)):
                est, se = f["params"][sc["name"]]
                if se > 0:
                    out.update(estimate=est, std_error=se, truth=sc["value"], z=(est - sc["value"]) / se)
                break
    return out


# ---------------------------------------------------------------------------------------------- the child process
def worker(csv_path: str, out_path: str, mem_gb: float) -> None:
    """Load and diagnose one file under an address-space cap; write the result (JSON)."""
    cap = int(mem_gb * 2 ** 30)
    resource.setrlimit(resource.RLIMIT_AS, (cap, cap))
    t0, c0 = time.perf_counter(), time.process_time()
    truth = json.loads(Path(csv_path).with_suffix(".json").read_text())
    res = {"ok": False, "stage": "import"}
    try:
        from imurig.kernel.files import load
        from imurig.diagnose.dispatch import diagnose
        rec = load(csv_path)
        res["stage"] = "diagnose"
        res["nominal_sensitivity"] = {k: v for k, v in rec.meta.items() if k.endswith("_nominal_sensitivity_V_per_m_s2")}
        # the manifest's twin is what `imurig diagnose --twin-model` would be given (none: the default)
        d = diagnose(rec, seed=int(truth["seed"]), twin=truth.get("diagnose_twin") or None)
        res["findings"] = findings_of(d, truth["rig"])
        res["unexplained"] = d.get("unexplained", [])
        try:
            bd = _bench_diagnose()
            tests = bd.record_tests(d, float(d.get("alpha", DEFAULT_ALPHA)))
            res["nominal_fwer"] = 1 - float(np.prod([1 - t[2] for t in tests])) if tests else None
        except Exception as e:   # the bound is a side figure; its failure must not hide the findings
            res["nominal_fwer_error"] = f"{type(e).__name__}: {e}"
        res["ok"] = True
    except MemoryError:
        res["error"] = f"MemoryError (address space capped at {mem_gb} GB)"
    except Exception as e:
        res["error"] = f"{type(e).__name__}: {str(e)[:400]}"
        res["where"] = traceback.format_exc().strip().splitlines()[-3][:300]
    res.update(wall_s=time.perf_counter() - t0, cpu_s=time.process_time() - c0,
               peak_rss_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0)
    Path(out_path).write_text(json.dumps(res, default=float))


def run_file(csv: Path, timeout_s: float, mem_gb: float) -> dict:
    """The child's result, or a miss naming the timeout or the signal that ended it."""
    with tempfile.NamedTemporaryFile(suffix=".json", delete=False) as f:
        out = Path(f.name)
    t0 = time.perf_counter()
    try:
        p = subprocess.run([sys.executable, __file__, "--worker", str(csv), str(out), str(mem_gb)],
                           capture_output=True, text=True, timeout=timeout_s)
        if out.stat().st_size:
            return json.loads(out.read_text())
        return {"ok": False, "error": f"child ended with code {p.returncode}: {p.stderr.strip()[-300:]}",
                "wall_s": time.perf_counter() - t0}
    except subprocess.TimeoutExpired:
        return {"ok": False, "error": f"timeout after {timeout_s:.0f} s", "wall_s": timeout_s}
    finally:
        out.unlink(missing_ok=True)


def independent_study(out_dir: Path, seeds, n_null: int, timeout_s: float, mem_gb: float, log=print,
                      rigs=("tilt_table", "turn_table"), effects=None) -> dict:
    """Write the independent set into ``out_dir`` and score every file (only the files whose name
    holds one of the words ``effects``, e.g. ('saturation', 'null'), when given)."""
    lab = independent_lab()
    records = []
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    for rig, effect, seed in lab.plan(seeds, n_null, rigs):
        name = f"{rig}-{effect or 'null'}-s{seed}.csv"   # the names of lab.write_set
        if effects and not any(w in name for w in effects):
            continue
        csv = lab.write_recording(out_dir / name, rig, effect, seed)
        truth = json.loads(csv.with_suffix(".json").read_text())
        res = run_file(csv, timeout_s, mem_gb)
        s = score_record(truth, res)
        s["detectability"] = detectability(truth, csv)
        s.update(file=csv.name, rig=truth["rig"], effect=truth["effects"][0]["effect"] if truth["effects"] else None,
                 fs_hz=truth["fs_hz"], adc=truth["adc_name"], nominal_fwer=res.get("nominal_fwer"),
                 wall_s=res.get("wall_s"), cpu_s=res.get("cpu_s"), peak_rss_mb=res.get("peak_rss_mb"))
        dt = s["detectability"]
        log(f"  {csv.name:48s} {'right' if s['right'] else ('FD' if s['false_discovery'] else '-'):5s} "
            f"found={s['found']} {('error: ' + s['error']) if s['error'] else ''}"
            + ("" if dt is None else f" (non-centrality {min(dt['lambda'].values()):.3g}, needs "
                                     f"{dt['lambda_90']:.3g})"))
        records.append(s)
    return summarise(records)


# ---------------------------------------------------------------------------------------------- the project's suite
def suite_study(seeds, case_filter=None, log=print) -> dict:
    """The project's concealed suite at realistic size: the same figures from ``cases.score``."""
    from imurig.concealed import cases, suite   # lazy: the child processes need not import the suite
    bd = _bench_diagnose()
    records = []
    for case in suite.CASES:
        name = f"{case.rig}:{case.effect}"
        if case_filter is not None and not any(w in name for w in case_filter):
            continue
        for seed in seeds:
            for null in (False, True):
                t0, c0 = time.perf_counter(), time.process_time()
                try:
                    rec = cases.case_recording(case, seed, null=null)
                    d = suite.diagnose_case(case, rec, seed, null=null)
                    s = cases.score(case, rec, d)
                    tests = bd.record_tests(d, bd.engine_alpha(case.rig))
                    s.update(ok=True, error=None, nominal_fwer=1 - float(np.prod([1 - t[2] for t in tests])))
                except Exception as e:
                    s = {"ok": False, "error": f"{type(e).__name__}: {str(e)[:300]}", "found": [], "correct": False}
                r = {"rig": case.rig, "effect": None if null else case.effect, "ok": s["ok"], "error": s["error"],
                     "found": s["found"], "right": bool(s.get("correct")) and not null,
                     "false_discovery": null and bool(s["found"]), "z": s.get("z"),
                     "nominal_fwer": s.get("nominal_fwer"),
                     "wall_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0,
                     "file": f"{name}{'-null' if null else ''}-s{seed}"}
                log(f"  {r['file']:48s} {'right' if r['right'] else ('FD' if r['false_discovery'] else '-'):5s} "
                    f"found={r['found']}")
                records.append(r)
    return summarise(records)


# ---------------------------------------------------------------------------------------------- figures
def summarise(records: list[dict]) -> dict:
    """Per effect: n, named-right fraction, z RMS; per rig's nulls: false-discovery rate and nominal."""
    eff, nul = defaultdict(list), defaultdict(list)
    for r in records:
        (eff[f"{r['rig']}:{r['effect']}"] if r["effect"] else nul[r["rig"]]).append(r)
    effects = {}
    for k, rs in sorted(eff.items()):
        zs = [r["z"] for r in rs if r.get("z") is not None and math.isfinite(r["z"])]
        # named right is scored over the recordings where the effect is detectable at all (its
        # expected non-centrality from the manifest reaches the test's 90 % power point); the others
        # are listed with their figures
        det = [r for r in rs if (r.get("detectability") or {}).get("detectable", True)]
        und = [r for r in rs if r not in det]
        effects[k] = {"n": len(rs), "n_detectable": len(det),
                      "named_right": sum(r["right"] for r in det) / len(det) if det else None,
                      "named_right_all": sum(r["right"] for r in rs) / len(rs),
                      "refused": sum(not r["ok"] for r in rs), "z_rms": math.sqrt(np.mean(np.square(zs))) if zs else None,
                      "n_z": len(zs),
                      "undetectable": [{"file": r["file"], "fs_hz": r["fs_hz"], "adc": r["adc"], "right": r["right"],
                                        "found": r["found"], "lambda": r["detectability"]["lambda"],
                                        "lambda_90": r["detectability"]["lambda_90"]} for r in und]}
    nulls = {}
    for k, rs in sorted(nul.items()):
        ok = [r for r in rs if r["ok"]]
        fd = sum(r["false_discovery"] for r in rs)
        nom = [r["nominal_fwer"] for r in ok if r.get("nominal_fwer") is not None]
        nulls[k] = {"n": len(rs), "refused": len(rs) - len(ok), "false_discoveries": fd,
                    "fd_rate": fd / len(ok) if ok else None,
                    "nominal_fwer": float(np.mean(nom)) if nom else DEFAULT_ALPHA}
    errors = defaultdict(list)
    for r in records:
        if r.get("error"):
            errors[_error_kind(r["error"])].append(r["file"])
    return {"records": records, "effects": effects, "nulls": nulls, "errors": dict(errors),
            "wall_s": sum(r.get("wall_s") or 0 for r in records), "cpu_s": sum(r.get("cpu_s") or 0 for r in records),
            "peak_rss_mb": max([r.get("peak_rss_mb") or 0 for r in records] or [0])}


def _error_kind(msg: str) -> str:
    """An error message without its file names and numbers (to group alike failures)."""
    words = [w for w in msg.replace(",", " ").split() if not any(c.isdigit() for c in w) and "/" not in w]
    return " ".join(words)[:160]


def table(indep: dict, own: dict | None) -> str:
    """The side-by-side table (markdown)."""
    rows = ["| effect | independent: n (detectable) | named right (of detectable) | z RMS (n) | refused | own suite: n | "
            "named right | z RMS (n) |", "|---|---|---|---|---|---|---|---|"]
    own_e = {k.split(":")[1]: v for k, v in (own or {}).get("effects", {}).items()}

    def zf(v):
        return f"{v['z_rms']:.2f} ({v['n_z']})" if v and v.get("z_rms") is not None else f"- ({v['n_z'] if v else 0})"
    for k, v in indep["effects"].items():
        o = own_e.get(k.split(":")[1])
        nr = "-" if v["named_right"] is None else f"{v['named_right']:.0%}"
        rows.append(f"| {k} | {v['n']} ({v.get('n_detectable', v['n'])}) | {nr} | {zf(v)} | {v['refused']} | "
                    + (f"{o['n']} | {o['named_right']:.0%} | {zf(o)} |" if o else "- | - | - |"))
    rows += ["", "| nulls | n | refused | false discoveries | rate | nominal family-wise rate |", "|---|---|---|---|---|---|"]
    for src, res in (("independent", indep), ("own suite", own or {})):
        for k, v in res.get("nulls", {}).items():
            rate = "-" if v["fd_rate"] is None else f"{v['fd_rate']:.0%}"
            rows.append(f"| {src} {k} | {v['n']} | {v['refused']} | {v['false_discoveries']} | {rate} | "
                        f"{v['nominal_fwer']:.3f} |")
    und = [(k, u) for k, v in indep["effects"].items() for u in v.get("undetectable", [])]
    if und:
        rows += ["", "| below detectability | f_s (Hz) | converter | non-centrality per axis (needed) | named right |"
                     " found |", "|---|---|---|---|---|---|"]
        for k, u in und:
            lam = ", ".join(f"{c[-1]} {x:.3g}" for c, x in u["lambda"].items())
            rows.append(f"| {u['file']} | {u['fs_hz']:g} | {u['adc']} | {lam} ({u['lambda_90']:.3g}) | "
                        f"{'yes' if u['right'] else 'no'} | {', '.join(u['found']) or '-'} |")
    return "\n".join(rows)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--worker", nargs=3, help=argparse.SUPPRESS)
    ap.add_argument("--seeds", type=int, default=1, help="independent recordings per effect")
    ap.add_argument("--first-seed", type=int, default=0,
                    help="first seed of the set (seeds first-seed .. first-seed + seeds - 1), to extend a study")
    ap.add_argument("--nulls", type=int, default=None, help="null recordings per rig (default: --seeds)")
    ap.add_argument("--suite-seeds", type=int, default=1)
    ap.add_argument("--suite-cases", default="", help="words picking suite cases ('none': skip the suite)")
    ap.add_argument("--timeout", type=float, default=300.0, help="seconds per independent file")
    ap.add_argument("--mem-gb", type=float, default=4.0, help="address-space cap per file")
    ap.add_argument("--dir", default=None, help="where the independent files go (default: a temporary folder)")
    ap.add_argument("--out", default=None, help="write the full results (JSON)")
    ap.add_argument("--effects", default="", help="words picking independent files, e.g. 'saturation,null' "
                                                  "(default: all)")
    ap.add_argument("--rigs", default="tilt_table,turn_table", help="rigs of the independent set")
    a = ap.parse_args(argv)
    if a.worker:
        worker(a.worker[0], a.worker[1], float(a.worker[2]))
        return 0
    t0, c0 = time.perf_counter(), time.process_time()
    with tempfile.TemporaryDirectory() as tmp:
        print("independent lab:")
        seeds = range(a.first_seed, a.first_seed + a.seeds)
        indep = independent_study(Path(a.dir or tmp), seeds, a.nulls or a.seeds, a.timeout, a.mem_gb,
                                  rigs=tuple(a.rigs.split(",")),
                                  effects=[w for w in a.effects.split(",") if w] or None)
    own = None
    if a.suite_cases != "none":
        print("project's concealed suite:")
        own = suite_study(range(1, a.suite_seeds + 1), [w for w in a.suite_cases.split(",") if w] or None)
    print(table(indep, own))
    print("\nerrors (grouped):")
    for k, files in sorted(indep["errors"].items(), key=lambda kv: -len(kv[1])):
        print(f"  {len(files):3d} x {k}")
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    print(f"\nwall {wall:.1f} s; CPU {cpu + indep['cpu_s']:.1f} s (children {indep['cpu_s']:.1f} s); peak memory "
          f"{max(indep['peak_rss_mb'], resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024):.0f} MB")
    if a.out:
        Path(a.out).write_text(json.dumps({"independent": indep, "own_suite": own}, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
