"""The concealed-effect suite as recordings: the cases by name, their recordings and their score.

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
``summary.json`` and ``report.md``: per case, what was found against what was concealed
(:func:`score`), the fitted parameter against the injected truth (in standard errors), and
per null record whether anything was reported. The files are written by
:mod:`imurig.reports.concealed`, the command by :mod:`imurig.cli.concealed`.
"""
from __future__ import annotations

from imurig.concealed import suite
from imurig.kernel.errors import ConfigError
from imurig.kernel.recording import Recording


def case_names() -> list[str]:
    """``rig:effect`` of every case of the suite."""
    return [f"{c.rig}:{c.effect}" for c in suite.CASES]


def find_case(spec: str):
    """The suite case named ``rig:effect`` (or just ``effect`` when only one rig has it)."""
    cases = suite.CASES
    rig, _, effect = spec.rpartition(":")
    hits = [c for c in cases if c.effect == effect and (not rig or c.rig == rig)]
    if len(hits) == 1:
        return hits[0]
    if not hits:
        raise ConfigError(f"no concealed-effect case '{spec}'; `imurig concealed list` shows them: "
                          + ", ".join(case_names()))
    raise ConfigError(f"'{spec}' is ambiguous; name the rig: " + ", ".join(f"{c.rig}:{c.effect}" for c in hits))


def case_twin(case, null: bool = False) -> dict:
    """The twin the case's recording (or its null recording) must be compared with, as written
    in its ``meta["diagnose_twin"]``."""
    twin = case.null_twin if null and case.null_twin is not None else case.twin
    # the suite compares slews only where the case says so; the file says it explicitly
    return {"dynamics": False, **twin} if case.rig == "tilt_table" else dict(twin)


def case_recording(case, seed: int, size: float | None = None, null: bool = False) -> Recording:
    """The case's recording (effect at ``size``, default its realistic size) or its null
    recording, with ``meta["concealed_case"]`` (what was concealed) and ``meta["diagnose_twin"]``
    (the twin to compare it with)."""
    size = case.realistic_size if size is None else float(size)
    rec = suite.null_recording(case, seed) if null else case.make(seed, size)
    rec.meta["diagnose_twin"] = case_twin(case, null)
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
    found = sorted(f"{ch}:{e}" for ch, e in suite.found_effects(d))
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
