"""The concealed-effect suite as files: ``imurig concealed``.

Every case of :mod:`imurig.concealed.suite` (one library effect present at a chosen size but
left out of the twin) and its null data (nothing left out) can be written as an ordinary
recording, with the injected truth inside it, and diagnosed with ``imurig diagnose`` like a
lab recording. The recording names the twin it must be compared with in
``meta["diagnose_twin"]`` (e.g. ``{"twin_model": "own_axis"}``: a tilt-table twin without
misalignment), so ``imurig diagnose case.h5`` needs no flags; flags given on the command
line override it.

    imurig concealed list
    imurig concealed write tilt_table:adc_crosstalk --out crosstalk.h5 [--size 2e-4] [--seed 1] [--null]
    imurig diagnose crosstalk.h5 --out crosstalk-diagnosis
    imurig concealed all --out suite-run [--seeds 1]     # every case and null, written and diagnosed

``all`` diagnoses each file through the same path as ``imurig diagnose`` and writes
``summary.json`` and ``report.md``: per case, what was found against what was concealed,
the fitted parameter against the injected truth (in standard errors), and per null record
whether anything was reported.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

from imurig.kernel.errors import ConfigError
from imurig.kernel.recording import Recording


def _suite():
    from imurig.concealed import suite

    return suite


def case_names() -> list[str]:
    """``rig:effect`` of every case of the suite."""
    return [f"{c.rig}:{c.effect}" for c in _suite().CASES]


def find_case(spec: str):
    """The suite case named ``rig:effect`` (or just ``effect`` when only one rig has it)."""
    cases = _suite().CASES
    rig, _, effect = spec.rpartition(":")
    hits = [c for c in cases if c.effect == effect and (not rig or c.rig == rig)]
    if len(hits) == 1:
        return hits[0]
    if not hits:
        raise ConfigError(f"no concealed-effect case '{spec}'; `imurig concealed list` shows them: "
                          + ", ".join(case_names()))
    raise ConfigError(f"'{spec}' is ambiguous; name the rig: " + ", ".join(f"{c.rig}:{c.effect}" for c in hits))


def case_recording(case, seed: int, size: float | None = None, null: bool = False) -> Recording:
    """The case's recording (effect at ``size``, default its realistic size) or its null
    recording, with ``meta["concealed_case"]`` (what was concealed) and ``meta["diagnose_twin"]``
    (the twin to compare it with)."""
    suite = _suite()
    size = case.realistic_size if size is None else float(size)
    rec = suite.null_recording(case, seed) if null else case.make(seed, size)
    twin = case.null_twin if null and case.null_twin is not None else case.twin
    from imurig.reports.diagnosis import TWIN_OPTIONS

    unknown = set(twin) - TWIN_OPTIONS[case.rig]
    if unknown:  # a twin that `imurig diagnose` could not rebuild from the file
        raise ConfigError(f"case {case.rig}:{case.effect} uses twin options {sorted(unknown)} that "
                          "`imurig diagnose` does not read; add them to imurig.reports.diagnosis.TWIN_OPTIONS and to the dispatcher")
    # the suite compares slews only where the case says so; the file says it explicitly
    rec.meta["diagnose_twin"] = {"dynamics": False, **twin} if case.rig == "tilt_table" else dict(twin)
    rec.meta["concealed_case"] = {
        "rig": case.rig, "effect": case.effect, "null": bool(null), "seed": int(seed),
        "size": None if null else size, "size_unit": case.size_unit,
        "expected": [] if null else sorted(f"{ch}:{e}" for ch, e in case.expected), "notes": case.notes}
    if not null and case.truth_param is not None:
        rec.meta["concealed_case"]["truth_parameter"] = float(case.truth_param(rec))
    return rec


def score(case, rec: Recording, d: dict) -> dict:
    """What a diagnosis ``d`` of a case recording found against what was concealed."""
    info = rec.meta["concealed_case"]
    found = sorted(f"{ch}:{e}" for ch, e in _suite().found_effects(d))
    out = {"found": found, "expected": info["expected"], "correct": found == info["expected"]}
    # an effect the diagnosis names as indistinguishable (and does not claim) is the right answer
    # when the case says the data cannot identify it at this size (e.g. a wrong local gravity)
    named = {e for n in d.get("indistinguishable", []) for e in n["effects"]}
    expected_effects = {e.split(":")[1] for e in info["expected"]}
    out["indistinguishable_reported"] = bool(expected_effects) and expected_effects <= named
    if not found and out["indistinguishable_reported"] and info["size"] == case.realistic_size:
        out["correct"] = True
    if not info["null"] and case.found_param is not None and "truth_parameter" in info:
        est = case.found_param(d)
        if est is not None:
            out.update(estimate=float(est[0]), std_error=float(est[1]), truth=info["truth_parameter"],
                       z=float((est[0] - info["truth_parameter"]) / est[1]))
    return out


def _write(a):
    from imurig.kernel.recording import save_h5

    case = find_case(a.case)
    rec = case_recording(case, a.seed, a.size, a.null)
    path = save_h5(rec, a.out, overwrite=a.overwrite)
    info = rec.meta["concealed_case"]
    what = "null record (nothing concealed)" if a.null else f"{case.effect} at {info['size']:.4g} {case.size_unit}"
    print(f"{path}: {case.rig}, {what}; twin {rec.meta['diagnose_twin'] or 'nominal'}")
    print(f"diagnose it with: imurig diagnose {path} --out {Path(path).stem}-diagnosis")


def _list(_a):
    from imurig.reports.common import md_table

    rows = [[f"{c.rig}:{c.effect}", f"{c.realistic_size:.4g}", c.size_unit, json.dumps(c.twin) if c.twin else "–",
             ", ".join(sorted(f"{ch}:{e}" for ch, e in c.expected))] for c in _suite().CASES]
    print(md_table(["case", "realistic size", "unit", "twin", "a correct diagnosis reports"], rows))


def run_all(out_dir, seeds: int = 1, overwrite: bool = False, cases: list[str] | None = None) -> dict:
    """Write every case (at its realistic size) and every null record of the suite, diagnose
    each through ``imurig diagnose``'s own path, and report the score (module doc)."""
    from imurig.reports.diagnosis import run as diagnose_run
    from imurig.kernel.progress import progress
    from imurig.kernel.files import load
    from imurig.kernel.recording import save_h5
    from imurig.kernel.outputs import OutputFolder
    from imurig.reports.common import md_table

    suite = _suite()
    chosen = [find_case(s) for s in cases] if cases else list(suite.CASES)
    nulls = {id(c) for c in suite.null_groups().values()}
    jobs = [(c, s, False) for c in chosen for s in range(1, seeds + 1)]
    jobs += [(c, s, True) for c in chosen if id(c) in nulls or cases for s in range(1, seeds + 1)]
    rows, results = [], []
    with OutputFolder(out_dir, overwrite=overwrite) as out, progress(len(jobs), "concealed cases", "record") as bar:
        for sub in ("records", "diagnoses"):
            out.file(sub).mkdir()
        for case, seed, null in jobs:
            name = f"{case.rig}-{case.effect}-{'null-' if null else ''}s{seed}"
            t0 = time.perf_counter()
            rec = case_recording(case, seed, null=null)
            path = save_h5(rec, out.file(f"records/{name}.h5"))
            rec = load(path)   # diagnose the file, as a user would
            # the threshold simulations seeded like the benchmark's (suite.diagnose_case): same findings
            d = diagnose_run(rec, out.file(f"diagnoses/{name}"), seed=seed, twin=rec.meta["diagnose_twin"])
            r = {"record": name, "case": f"{case.rig}:{case.effect}", "null": null, "seed": seed,
                 "wall_s": time.perf_counter() - t0, **score(case, rec, d)}
            results.append(r)
            rows.append([name, ", ".join(r["expected"]) or "nothing", ", ".join(r["found"]) or "nothing",
                         ("yes (named indistinguishable)" if r["correct"] and not r["found"] and r["expected"]
                          else "yes" if r["correct"] else "**no**"),
                         f"{r['z']:+.2f}" if "z" in r else "–", f"{r['wall_s']:.1f}"])
            bar.update(1)
        summary = {"n_records": len(results), "n_correct": sum(r["correct"] for r in results),
                   "cases": [r for r in results if not r["null"]], "nulls": [r for r in results if r["null"]]}
        out.write_json("summary.json", summary)
        out.write_text("report.md", "\n".join([
            "# The concealed-effect suite, written and diagnosed\n",
            (f"{summary['n_correct']} of {summary['n_records']} records diagnosed correctly (the concealed "
            "effect on the right channels and nothing else; nothing on null records). z = (estimate − "
            "injected) / SE of the case's first parameter.\n"),
            md_table(["record", "concealed", "found", "correct", "z", "wall s"], rows),
            ("\nEach record is in `records/` (with its truth); its diagnosis (report.md, diagnosis.json, "
            "figures, .rrd) in `diagnoses/`.\n")]))
    return summary


def _all(a):
    s = run_all(a.out, a.seeds, a.overwrite, a.cases.split(",") if a.cases else None)
    print(f"{s['n_correct']} of {s['n_records']} records diagnosed correctly; report: {Path(a.out) / 'report.md'}")


def add_concealed_parser(sub) -> None:
    """``imurig concealed {list,write,all}`` (module doc)."""
    p = sub.add_parser("concealed", help="the concealed-effect suite as recordings: list, write one, or "
                                         "write and diagnose them all")
    s = p.add_subparsers(dest="concealed_cmd", required=True)
    s.add_parser("list", help="the cases: rig:effect, realistic size, twin").set_defaults(func=_list)
    w = s.add_parser("write", help="write one case (or its null record) as a recording with its truth")
    w.add_argument("case", help="rig:effect, e.g. tilt_table:adc_crosstalk (see `imurig concealed list`)")
    w.add_argument("--out", required=True, help="output recording (.h5)")
    w.add_argument("--size", type=float, default=None, help="effect size in the case's unit (default: realistic)")
    w.add_argument("--seed", type=int, default=1)
    w.add_argument("--null", action="store_true", help="the null record: nothing concealed from this twin")
    w.add_argument("--overwrite", action="store_true")
    w.set_defaults(func=_write)
    al = s.add_parser("all", help="write every case and null record and diagnose each")
    al.add_argument("--out", default="imurig-out/concealed")
    al.add_argument("--seeds", type=int, default=1, help="records per case (seeds 1..N)")
    al.add_argument("--cases", default="", help="comma-separated rig:effect (default: all)")
    al.add_argument("--overwrite", action="store_true")
    al.set_defaults(func=_all)
