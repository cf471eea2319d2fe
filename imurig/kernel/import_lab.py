"""The import of a minimal lab file (CSV or MATLAB): columns to channels, then the inferences.

Shared by :mod:`imurig.kernel.labcsv` and :mod:`imurig.kernel.matfile`:

- :func:`check_memory`: rows x columns x 8 bytes x a working factor against the available memory
  (``/proc/meminfo`` MemAvailable, else ``os.sysconf``), a RecordingError before allocating;
- :func:`columns_to_channels`: named columns (``name_unit``) to SI channels; ``_counts`` columns via
  the ADC's ``adc.scale_V_per_count`` or ``adc.range_V`` and ``adc.bits`` (V = code * 2 range / 2^bits,
  offset binary when every code is >= 0 and some exceed 2^(bits-1)), refused otherwise;
  ``_g`` columns in standard g; event columns ``event_<name>_s`` (``event_hp6700_s`` and
  ``event_pulse_hp6700_s`` are the same timer);
- :func:`infer_structure`: the inferences of :mod:`imurig.kernel.infer` for a file that declares no
  structure (no ``segment`` column, no ``setpoints`` metadata).
"""
from __future__ import annotations

import os

import numpy as np

from imurig.kernel import gravity_check, infer
from imurig.kernel.errors import RecordingError
from imurig.kernel.plateaus import MIN_PLATEAU_S, plateau_segments
from imurig.kernel.recording import Recording
from imurig.kernel.units import G_STANDARD, UnitSpec, split_column, to_si

#: bytes per value while importing: the parsed table, its columns in SI, the inference's copies
WORK_FACTOR = 4
KNOWN_TIMERS = ("hp6700", "gps_mark", "adc", "channel")
#: the maker's scaled channels: g is standard gravity
EXTRA_UNITS = {"g": UnitSpec("g", "m/s^2", G_STANDARD)}


def available_memory_bytes() -> int:
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return 1 << 62


def check_memory(rows: int, cols: int, where: str, limit_bytes: int | None = None) -> int:
    """Refuse before allocating when rows x cols x 8 x WORK_FACTOR exceeds the available memory."""
    need = int(rows) * int(cols) * 8 * WORK_FACTOR
    have = available_memory_bytes() if limit_bytes is None else int(limit_bytes)
    if need > have:
        raise RecordingError(f"{where}: {rows} rows x {cols} columns need about {need / 1e9:.3g} GB to import, "
                             f"but {have / 1e9:.3g} GB are available; split the file (e.g. per run) or "
                             "drop unused columns")
    return need


def count_rows(path) -> int:
    """Lines in the file (a bound on the data rows), counted in 1 MiB blocks."""
    n = 0
    with open(path, "rb") as fh:
        while True:
            b = fh.read(1 << 20)
            if not b:
                return n + 1
            n += b.count(b"\n")


def event_name(header: str) -> str | None:
    """``event_<name>_s`` -> the event name; a bare timer name gets its ``pulse_`` prefix."""
    if header.startswith("event_") and header.endswith("_s") and len(header) > 8:
        name = header[len("event_"):-2]
        return f"pulse_{name}" if name in KNOWN_TIMERS else name
    return None


def counts_to_volts(x: np.ndarray, name: str, meta: dict, where: str) -> tuple[np.ndarray, str]:
    adc = meta.get("adc") if isinstance(meta.get("adc"), dict) else {}
    if "scale_V_per_count" in adc:
        return x * float(adc["scale_V_per_count"]) + float(adc.get("offset_V", 0.0)), "adc.scale_V_per_count"
    if "range_V" in adc and "bits" in adc:
        bits, rng = int(adc["bits"]), float(adc["range_V"])
        lsb = 2 * rng / 2 ** bits
        offset = 2 ** (bits - 1) if (np.min(x) >= 0 and np.max(x) >= 2 ** (bits - 1)) else 0
        how = f"+-{rng} V over {bits} bits ({lsb:.4g} V per count" + (", offset binary)" if offset else ")")
        return (x - offset) * lsb, how
    raise RecordingError(f"{where}: column '{name}_counts' is in ADC counts but the file does not say how to turn "
                         "counts into volts; add '# adc.range_V: 5' and '# adc.bits: 16' (a bipolar +-range) or "
                         "'# adc.scale_V_per_count: ...'")


def columns_to_channels(cols: dict, meta: dict, where: str):
    """Named columns (with unit suffixes) to (time_s, channels, units, events, notes)."""
    events, channels, units, notes = {}, {}, {}, {}
    for h, x in cols.items():
        ev = event_name(h)
        if ev:
            events[ev] = np.sort(x[np.isfinite(x)])
            if h[6:-2] in KNOWN_TIMERS:
                notes[h] = f"event column read as '{ev}'"
            continue
        if h in ("time_s", "segment", "run"):
            continue
        if h.endswith("_counts") and len(h) > 7:
            name = h[:-7]
            channels[name], how = counts_to_volts(np.asarray(x, float), name, meta, where)
            units[name] = "V"
            notes[h] = f"ADC counts to volts: {how}"
        else:
            base, _, suf = h.rpartition("_")
            name, spec = (base, EXTRA_UNITS[suf]) if suf in EXTRA_UNITS and base else split_column(h)
            if name in channels:
                raise RecordingError(f"{where}: channel '{name}' appears twice with different units")
            channels[name] = to_si(np.asarray(x, float), spec)
            units[name] = spec.si
            check_angle_range(h, name, channels[name], spec.si, where)
            check_unit_range(h, channels[name], spec.si, where)
    return channels, units, events, notes


#: set-point angles: a column whose values leave one turn is in another unit than its name says
ANGLE_NAMES = ("theta", "phi", "psi")


def check_angle_range(column: str, name: str, x_si: np.ndarray, unit_si: str, where: str) -> None:
    """Refuse a set-point angle column whose values contradict its unit (|angle| beyond one turn,
    e.g. degrees in a column named ``theta_rad``)."""
    if unit_si != "rad" or name not in ANGLE_NAMES:
        return
    fin = np.abs(x_si[np.isfinite(x_si)])
    if fin.size and fin.max() > 2 * np.pi + 1e-9:
        raise RecordingError(f"{where}: column '{column}' reaches {np.degrees(fin.max()) if column.endswith('_deg') else fin.max():.6g} "
                             f"{'deg' if column.endswith('_deg') else 'rad'}, beyond one turn: "
                             f"{'are the values degrees? name the column ' + name + '_deg' if column.endswith('_rad') else 'check the set-point column'}")


#: plausible ranges in SI of quantities whose unit is easily mistaken for another (module doc):
#: a lab's temperatures (-100 to 200 C) and a rate table's rates (up to 20 turns per second)
PLAUSIBLE = {"K": (173.15, 473.15), "rad/s": (0.0, 2 * np.pi * 20)}


def check_unit_range(column: str, x_si: np.ndarray, unit_si: str, where: str) -> None:
    """Refuse a temperature or rate column whose values contradict its unit: a temperature outside
    -100..200 degC once converted (kelvin named _degC, or Celsius named _K), a rate beyond 20 turns
    per second (degrees per second named _rad_s)."""
    if unit_si not in PLAUSIBLE:
        return
    lo, hi = PLAUSIBLE[unit_si]
    fin = x_si[np.isfinite(x_si)]
    if not fin.size:
        return
    if unit_si == "K" and (fin.min() < lo or fin.max() > hi):
        base = column.rpartition("_")[0]
        hint = (f"the values look like kelvin: name the column {base}_K" if column.endswith("_degC") and fin.min() > 400
                else f"the values look like degrees Celsius: name the column {base}_degC" if column.endswith("_K")
                else "check the column's unit")
        raise RecordingError(f"{where}: column '{column}' gives {fin.min() - 273.15:.4g} to {fin.max() - 273.15:.4g} "
                             f"degC, outside a lab's -100..200 degC: {hint}")
    if unit_si == "rad/s" and np.abs(fin).max() > hi:
        base = column.rpartition("_")[0]
        hint = (f"are the values deg/s? name the column {base.removesuffix('_rad')}_dps"
                if column.endswith("_rad_s") else "check the column's unit")
        raise RecordingError(f"{where}: column '{column}' reaches {np.abs(fin).max():.6g} rad/s, beyond 20 turns "
                             f"per second: {hint}")


def infer_structure(rec: Recording, where: str, order: list[str], rig: str | None = None, site=None,
                    pulse_channel: str | None = None, min_plateau_s: float = MIN_PLATEAU_S,
                    column_notes: dict | None = None) -> Recording:
    """The inferences of a minimal lab file (see :mod:`imurig.kernel.infer`), recorded in ``meta``."""
    if column_notes:
        infer.note(rec, "columns", column_notes, "column suffixes")
    pulse_channel = pulse_channel or ("pulse" if "pulse" in rec.channels else None)
    infer.rename_channels(rec, pulse_channel, where)
    infer.resolve_site(rec, site, where)
    infer.sample_rate(rec)
    infer.temperatures(rec)
    sp = infer.setpoint_columns(rec)
    r = infer.infer_rig(rec, sp, rig)
    if r in ("tilt_table", "turn_table") and "site" not in rec.meta:
        raise RecordingError(f"{where}: no site: a {r} reference needs local gravity and the Earth's rate; add "
                             "'# site: delft' (or '# site.latitude_deg:', '# site.longitude_deg:', "
                             "'# site.altitude_m:' lines) or pass --site")
    infer.sensitivities(rec)
    infer.quantisation(rec)
    infer.scan_list(rec, [c if c not in (pulse_channel,) else "pulse" for c in order])
    infer.pulses(rec)
    if sp:
        rec.meta["setpoints"] = sp
        seg, units, evidence = plateau_segments(rec, sp, min_plateau_s)
        rec.segments, rec.segment_units = seg, units
        infer.note(rec, "segments", int(seg["start_s"].size), evidence)
        if r == "tilt_table":
            gravity_check.tilt_runs(rec, where)
        elif r == "turn_table":
            gravity_check.turn_runs(rec, where)
            infer.gyro_noise_model(rec)
    else:
        infer.warn(rec, "no set-point columns (theta_deg, phi_deg, psi_deg or rate_dps): no segments")
    return rec


def is_minimal(header: list[str], meta: dict) -> bool:
    """A file that declares no structure (no segment column, no setpoints line) is inferred."""
    return "segment" not in header and "setpoints" not in meta
