"""A second, independent recording generator: another lab's tilt and turn tables, logged in the
minimal lab CSV (time, set-points or rate dial, channel voltages, ``# rig:`` and ``# site:``),
with one concealed effect per recording or none, and a truth manifest (JSON) beside each CSV.

Numpy and the standard library only: nothing of the project's simulator, rigs, sensors,
calibration or flights is imported (``tests/test_independent_lab.py`` checks this on the
source), so the project's own assumptions cannot leak into the data it is scored on.

    from independent_lab import write_set
    write_set(out_dir, seeds=range(3))            # every effect and the nulls, rates and ADCs cycled
"""
from __future__ import annotations

from pathlib import Path

from . import tilt, turn
from .lab import write_csv, write_manifest

RATES_HZ = (50.0, 100.0, 102.4, 200.0, 1000.0)
CONVERTER_NAMES = ("16bit_5V", "12bit_10V", "24bit_10V", "18bit_2V5")
RIG_EFFECTS = {"tilt_table": tilt.EFFECTS, "turn_table": turn.EFFECTS}
GENERATORS = {"tilt_table": tilt.record, "turn_table": turn.record}


def recording(rig: str, effect: str | None, seed: int, fs_hz: float | None = None, converter: str | None = None):
    """(columns, steps, manifest) of one recording; the rate and converter cycle with the seed
    unless given."""
    k = seed % 1000 + seed // 1000           # the set's seeds are 1000 s + i: cycle over both s and i
    fs_hz = fs_hz or RATES_HZ[k % len(RATES_HZ)]
    converter = converter or CONVERTER_NAMES[(k + k // len(RATES_HZ)) % len(CONVERTER_NAMES)]
    return GENERATORS[rig](seed, effect, fs_hz, converter)


def write_recording(path, rig: str, effect: str | None, seed: int, fs_hz: float | None = None,
                    converter: str | None = None) -> Path:
    """Write ``path`` (.csv) and its manifest (.json beside it); returns the CSV's path."""
    path = Path(path)
    cols, steps, truth = recording(rig, effect, seed, fs_hz, converter)
    site = truth["site"]
    meta = {"rig": rig, "site": site["name"]}
    write_csv(path, meta, cols, steps)
    truth["file"] = path.name
    write_manifest(path.with_suffix(".json"), truth)
    return path


def plan(seeds=range(3), n_null: int | None = None, rigs=("tilt_table", "turn_table")) -> list[tuple]:
    """(rig, effect or None, seed) of a set: every effect at every seed, and as many nulls per rig."""
    out = []
    for rig in rigs:
        for s in seeds:
            out += [(rig, e, 1000 * s + i) for i, e in enumerate(RIG_EFFECTS[rig])]
            out.append((rig, None, 1000 * s + 999))
        for k in range(max(0, (n_null or 0) - len(list(seeds)))):
            out.append((rig, None, 500000 + k))
    return out


def write_set(out_dir, seeds=range(3), n_null: int | None = None, rigs=("tilt_table", "turn_table"),
              fs_hz: float | None = None) -> list[Path]:
    """Write the set of :func:`plan` into ``out_dir``; file names say rig, effect and seed."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for rig, effect, seed in plan(seeds, n_null, rigs):
        name = f"{rig}-{effect or 'null'}-s{seed}.csv"
        paths.append(write_recording(out_dir / name, rig, effect, seed, fs_hz))
    return paths
