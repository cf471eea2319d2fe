"""The concealed-effect suite written to files: one case as a recording, or every case and
null record written, diagnosed through ``imurig diagnose``'s own path and scored
(summary.json, report.md). The cases and their score: :mod:`imurig.concealed.cases`."""
from __future__ import annotations

import json
import time
from pathlib import Path

from imurig.concealed import suite
from imurig.concealed.cases import case_recording, case_twin, find_case, score
from imurig.kernel.errors import ConfigError
from imurig.kernel.files import load
from imurig.kernel.outputs import OutputFolder
from imurig.kernel.progress import progress
from imurig.kernel.recording import Recording, save_h5
from imurig.reports.common import md_table
from imurig.reports.diagnosis import TWIN_OPTIONS
from imurig.reports.diagnosis import run as diagnose_run


def check_twin(case, null: bool = False) -> None:
    """Refuse a case whose twin `imurig diagnose` could not rebuild from the file."""
    unknown = set(case_twin(case, null)) - TWIN_OPTIONS[case.rig]
    if unknown:
        raise ConfigError(f"case {case.rig}:{case.effect} uses twin options {sorted(unknown)} that "
                          "`imurig diagnose` does not read; add them to imurig.reports.diagnosis.TWIN_OPTIONS and to "
                          "the dispatcher")


def case_table() -> str:
    """The cases as a Markdown table: rig:effect, realistic size, twin, what a correct diagnosis reports."""
    rows = [[f"{c.rig}:{c.effect}", f"{c.realistic_size:.4g}", c.size_unit, json.dumps(c.twin) if c.twin else "–",
             ", ".join(sorted(f"{ch}:{e}" for ch, e in c.expected))] for c in suite.CASES]
    return md_table(["case", "realistic size", "unit", "twin", "a correct diagnosis reports"], rows)


def write_case(spec: str, out, seed: int, size: float | None = None, null: bool = False,
               overwrite: bool = False) -> tuple[Path, Recording]:
    """Write the case ``spec`` (rig:effect) or its null record as a recording with its truth."""
    case = find_case(spec)
    check_twin(case, null)
    rec = case_recording(case, seed, size, null)
    return save_h5(rec, out, overwrite=overwrite), rec


def run_all(out_dir, seeds: int = 1, overwrite: bool = False, cases: list[str] | None = None) -> dict:
    """Write every case (at its realistic size) and every null record of the suite, diagnose
    each through ``imurig diagnose``'s own path, and report the score
    (:mod:`imurig.concealed.cases`)."""
    chosen = [find_case(s) for s in cases] if cases else list(suite.CASES)
    nulls = {id(c) for c in suite.null_groups().values()}
    jobs = [(c, s, False) for c in chosen for s in range(1, seeds + 1)]
    jobs += [(c, s, True) for c in chosen if id(c) in nulls or cases for s in range(1, seeds + 1)]
    for case, _, null in jobs:
        check_twin(case, null)
    rows, results = [], []
    with OutputFolder(out_dir, overwrite=overwrite) as out, progress(len(jobs), "concealed cases", "record") as bar:
        for sub in ("records", "diagnoses"):
            out.file(sub).mkdir()
        for case, seed, null in jobs:
            r = _diagnose_one(out, case, seed, null)
            results.append(r)
            rows.append([r["record"], ", ".join(r["expected"]) or "nothing", ", ".join(r["found"]) or "nothing",
                         ("yes (named indistinguishable)" if r["correct"] and not r["found"] and r["expected"]
                          else "yes" if r["correct"] else "**no**"),
                         f"{r['z']:+.2f}" if "z" in r else "–", f"{r['wall_s']:.1f}"])
            bar.update(1)
        summary = {"n_records": len(results), "n_correct": sum(r["correct"] for r in results),
                   "cases": [r for r in results if not r["null"]], "nulls": [r for r in results if r["null"]]}
        out.write_json("summary.json", summary)
        out.write_text("report.md", _report_md(summary, rows))
    return summary


def _diagnose_one(out: OutputFolder, case, seed: int, null: bool) -> dict:
    """Write one record into ``out/records``, diagnose the file into ``out/diagnoses`` and score it."""
    name = f"{case.rig}-{case.effect}-{'null-' if null else ''}s{seed}"
    t0 = time.perf_counter()
    rec = case_recording(case, seed, null=null)
    path = save_h5(rec, out.file(f"records/{name}.h5"))
    rec = load(path)   # diagnose the file, as a user would
    # the threshold simulations seeded like the benchmark's (suite.diagnose_case): same findings
    d = diagnose_run(rec, out.file(f"diagnoses/{name}"), seed=seed, twin=rec.meta["diagnose_twin"])
    return {"record": name, "case": f"{case.rig}:{case.effect}", "null": null, "seed": seed,
            "wall_s": time.perf_counter() - t0, **score(case, rec, d)}


def _report_md(summary: dict, rows: list[list]) -> str:
    return "\n".join([
        "# The concealed-effect suite, written and diagnosed\n",
        (f"{summary['n_correct']} of {summary['n_records']} records diagnosed correctly (the concealed "
         "effect on the right channels and nothing else; nothing on null records). z = (estimate − "
         "injected) / SE of the case's first parameter.\n"),
        md_table(["record", "concealed", "found", "correct", "z", "wall s"], rows),
        ("\nEach record is in `records/` (with its truth); its diagnosis (report.md, diagnosis.json, "
         "figures, .rrd) in `diagnoses/`.\n")])
