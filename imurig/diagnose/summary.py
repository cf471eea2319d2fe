"""The diagnosis in a rig-free form: ``findings``, ``unexplained`` and a one-line ``verdict``
(the top level of ``diagnosis.json``; schema in docs/diagnosis-json.md).

Every kind of diagnosis (tilt table, turn table, thermal chamber, appendix-B rows, magnetometer)
keeps its own detailed entries; :func:`summarise` walks them and lists

- each accepted effect once per channel: ``{effect, channel, observable, parameters: [{name,
  estimate, se, unit}], fit: {before_rms, after_rms, unit}}``, the fit being the residual RMS of the
  observable (in its own unit) before and after the effect joined the model (the engine's fit step
  by step), or the test's own before/after statistic for a test without a regression;
- what is left unexplained: where a channel's residual after the accepted effects is not white
  (lag-1 autocorrelation beyond 2.5 / sqrt(m)): ``{channel, observable, where, size, unit,
  signature}`` with where the largest residual sits (row, time, set-point), its size (the RMS of
  the residual after the accepted effects) and its signature: the dominant spectral peak of the
  residual in row order (periodogram, cycles per row, its share of the residual power), the
  correlation with the set-point / reading column and the dependence on level (correlation of |r|
  with |set-point|);
- the verdict: how many effects on which channels, and whether anything is left unexplained.
"""
from __future__ import annotations

import numpy as np

from imurig.diagnose.whiteness import residual_whiteness
from imurig.sensors import effects as library

#: the unit of a scatter finding's value, from the suffix of its key
_SUFFIX_UNITS = (("_V", "V"), ("_hz", "Hz"), ("_Hz", "Hz"), ("_s", "s"), ("_deg", "deg"), ("_m_s2", "m/s^2"),
                 ("_rad_s", "rad/s"), ("_dps", "deg/s"), ("_nT", "nT"))
#: the default unit of each kind's per-channel observable (where the entry's residuals do not say)
_KIND_UNIT = {"tilt_table": "m/s^2", "turn_table": "rad/s", "thermal": "–", "rate_table_rows": "V",
              "magnetometer": "nT"}


def _unit_of_key(key: str) -> str:
    if key in ("fraction", "variance_share"):
        return "1"
    for suf, unit in _SUFFIX_UNITS:
        if key.endswith(suf):
            return unit
    return "1" if key in ("spikes", "positions", "samples", "runs") else "–"


#: parameters whose unit the library's Param list does not name (the per-gyro form of a joint effect)
_PARAM_UNITS = {("instrument_range_change", "gain_step"): "V/(deg/s)", ("instrument_range_change", "offset_step"): "V"}


def _param_unit(effect: str, name: str, channel: str = "") -> str:
    """The unit the library's effect gives its parameter ``name`` ('effect:param' or 'param'); where
    sensors share a finding's name (scale_nonlinearity), the effect of the channel's sensor."""
    short = name.split(":", 1)[-1]
    if (effect, short) in _PARAM_UNITS:
        return _PARAM_UNITS[(effect, short)]
    classes = [c for c in library.LIBRARY if effect in (c.name, c.finding_name())]
    if not classes:
        return _unit_of_key(short)
    sensor = channel.split("_")[0]
    params = next((c.params for c in classes if sensor and c.name.startswith(sensor)), classes[0].params)
    for p in (*[p for p in params if p.name == short], *[p for p in params if short.startswith(p.name)]):
        return p.unit
    return _unit_of_key(short)


def _engine_finding(f: dict, channel: str, observable: str, entry: dict, unit: str) -> dict:
    """One engine finding (:class:`imurig.diagnose.engine.Finding`) in the summary's form."""
    params = [{"name": p["name"].split(":", 1)[-1], "estimate": p["estimate"], "se": p["std_error"],
               "unit": p.get("unit") or _param_unit(f["effect"], p["name"], f.get("channel", channel))}
              for p in f.get("parameters", [])]
    steps = entry.get("fit_steps") or []
    k = next((i for i, s in enumerate(steps) if s.get("after_effect") == f["effect"]), None)
    if k:
        fit = {"before_rms": steps[k - 1]["residual_rms"], "after_rms": steps[k]["residual_rms"], "unit": unit}
    elif f.get("rms_before") is not None:
        fit = {"before_rms": f["rms_before"], "after_rms": f["rms_after"],
               "unit": "whitened (1 = the noise model's sigma)" if f.get("rms_unit") == "whitened" else unit}
    else:
        fit = {"before_rms": f.get("cv_rms_before"), "after_rms": f.get("cv_rms_after"), "unit": unit,
               "note": "held-out (cross-validated) RMS"}
    out = {"effect": f["effect"], "channel": f.get("channel", channel), "observable": observable,
           "parameters": params, "fit": fit}
    if f.get("indistinguishable_from"):
        out["indistinguishable_from"] = f["indistinguishable_from"]
    if f.get("source_channel"):
        out["source_channel"] = f["source_channel"]
        out["note"] = (f"leak source '{f['source_channel']}' chosen among the logged channels "
                       f"{f.get('sources_tested')} (the scan order is unknown; the choice is counted in the threshold)")
    elif f.get("scan_order_from"):
        out["note"] = f"previous channel '{f.get('previous_channel')}' in the scan order from {f['scan_order_from']}"
    return out


def _test_finding(f: dict, channel: str, observable: str) -> dict:
    """A test's finding (spikes, a spectral peak, clipping, slip-ring noise): its numbers as parameters."""
    if f.get("parameters"):
        params = [{"name": p["name"], "estimate": p["estimate"], "se": p.get("std_error"),
                   "unit": _unit_of_key(p["name"])} for p in f["parameters"]]
    else:
        params = [{"name": k, "estimate": float(v), "se": None, "unit": _unit_of_key(k)} for k, v in f.items()
                  if isinstance(v, (int, float)) and not isinstance(v, bool) and k not in ("p_value",)]
    fit = f.get("fit") or {"before_rms": f.get("rms_before_V"), "after_rms": f.get("rms_after_V"), "unit": "V"}
    return {"effect": f["effect"], "channel": channel, "observable": observable, "parameters": params, "fit": fit}


def _channel_entries(d: dict):
    """(channel, observable, entry) for every per-channel entry of a diagnosis of any kind."""
    kind = d.get("kind")
    if kind == "tilt_table":
        for a, e in d.get("axes", {}).items():
            yield f"acc_{a}", "position means", e
    elif kind == "turn_table":
        for g, e in d.get("gyros", {}).items():
            yield f"gyro_{g}", "whole-round means", e
    elif kind == "thermal":
        for ch, e in d.get("channels", {}).items():
            yield ch, "bias per temperature step", e
    elif kind == "magnetometer":
        yield "mag", "1-s block means", d.get("magnetometer", {})
    elif kind == "rate_table_rows":
        yield "rate", "relative rate shortfall per timed row", d.get("shortfall", {}).get("diagnosis", {})
        for g, e in (d.get("gyros") or {}).items():
            yield f"gyro_{g}", "voltmeter readings per timed row", e
        if d.get("voltmeter"):
            yield "gyros", "voltmeter readings per timed row", d["voltmeter"]


def findings(d: dict) -> list[dict]:
    """Every accepted effect of the diagnosis ``d`` in the summary's form (module doc)."""
    out = []
    unit0 = _KIND_UNIT.get(d.get("kind"), "–")
    for ch, obs, e in _channel_entries(d):
        if not isinstance(e, dict):
            continue
        unit = (e.get("residuals") or {}).get("unit", "1" if ch == "rate" else unit0)
        out += [_engine_finding(f, ch, obs, e, unit) for f in e.get("findings", [])]
        sc = e.get("scatter") or {}
        for k, f in sorted(sc.items()):
            if (k.startswith("finding_") or k == "finding") and isinstance(f, dict) and "effect" in f:
                out.append(_test_finding(f, ch, "samples as logged" if k == "finding_saturation" else "sample scatter"))
    for f in (d.get("dynamic") or {}).get("findings", []):
        ch = f.get("channel", "acc")
        out.append(_engine_finding(f, "acc" if ch == "acc" else f"acc_{ch}", "slews against the dynamic twin",
                                   d["dynamic"], (d["dynamic"].get("residuals") or {}).get("unit", "m/s^2")))
    tr = d.get("table_rate") or {}
    if tr.get("finding_mains"):
        out.append({**_test_finding(tr["finding_mains"], "table_rate", "measured / dial rate per whole-round window"),
                    "fit": {"before_rms": None, "after_rms": None, "unit": "1",
                            "note": "the measured/dial ratio matched to a motor's mains factor, not a regression"}})
    for f in (tr.get("shortfall") or {}).get("findings", []):
        out.append(_engine_finding(f, "table_rate", "relative rate shortfall per whole-round window", {}, "1"))
    if (tr.get("timer") or {}).get("finding"):
        out.append(_test_finding(tr["timer"]["finding"], "table_rate",
                                 "index-pulse times against the table-axis gyro's integrated angle"
                                 if tr["timer"].get("method") == "gyro angle" else
                                 "index-pulse times about each dial plateau's line"))
    if d.get("rate_factor"):
        rf = d["rate_factor"]
        out.append({"effect": rf["effect"], "channel": "rate", "observable": "stopwatch rate per timed row",
                    "parameters": [{"name": "factor", "estimate": rf["factor"], "se": None, "unit": "1"},
                                   {"name": "mean_ratio", "estimate": rf["mean_ratio"], "se": rf["mean_ratio_se"],
                                    "unit": "1"}],
                    "fit": {"before_rms": None, "after_rms": None, "unit": "1",
                            "note": "the measured/dial ratio matched to a motor's mains factor, not a regression"}})
    return out


def _signature(r: np.ndarray, setpoint: np.ndarray | None) -> dict:
    """The residual's dominant spectral peak in row order and its relation to the set-point."""
    r = np.asarray(r, float) - np.mean(r)
    P = np.abs(np.fft.rfft(r)) ** 2
    P[0] = 0.0
    k = int(np.argmax(P)) if P.size > 1 else 0
    sig = {"peak_cycles_per_row": k / r.size, "peak_power_share": float(P[k] / P.sum()) if P.sum() > 0 else 0.0}
    if setpoint is not None and np.std(setpoint) > 0 and np.std(r) > 0:
        s = np.asarray(setpoint, float)
        sig["correlation_with_setpoint"] = float(np.corrcoef(r, s)[0, 1])
        sig["level_dependence"] = float(np.corrcoef(np.abs(r), np.abs(s))[0, 1])
    return sig


def unexplained(d: dict) -> list[dict]:
    """The channels whose residual after the accepted effects is not white (module doc)."""
    out = []
    unit0 = _KIND_UNIT.get(d.get("kind"), "–")
    for ch, obs, e in _channel_entries(d):
        if not isinstance(e, dict):
            continue
        res = e.get("residuals") or {}
        r = np.asarray(res.get("after", []), float)
        white = (e.get("unexplained") or {}).get("white")
        if r.size >= 4 and not np.all(np.isfinite(r)):
            continue
        lag1, white_here = residual_whiteness(r)
        if r.size >= 4 and np.isnan(lag1):
            continue   # no spread left (a model as large as the data, an axis not excited): nothing unexplained
        if r.size >= 4 and white is None:
            white = white_here
        if white is not False:
            continue
        setpoint = next((np.asarray(res[k], float) for k in ("reading_m_s2", "table_rate_rad_s", "temperature_K")
                         if k in res), None)
        when = next((np.asarray(res[k], float) for k in ("time_s", "elapsed_h") if k in res), None)
        where = {"row": None}
        if r.size:
            i = int(np.argmax(np.abs(r)))
            where = {"row": i, "residual": float(r[i])}
            if when is not None:
                where["time_s" if "time_s" in res else "elapsed_h"] = float(when[i])
            if setpoint is not None:
                where["setpoint"] = float(setpoint[i])
        size = float(np.sqrt(np.mean(r**2))) if r.size else (e.get("unexplained") or {}).get("sigma_res")
        out.append({"channel": ch, "observable": obs, "where": where, "size": size,
                    "unit": res.get("unit", unit0) if r.size else "whitened",
                    "signature": _signature(r, setpoint) if r.size >= 4 else {}})
    return out


def verdict(found: list[dict], left: list[dict]) -> str:
    """One line: the effects found (effect on channel) and whether anything is left unexplained."""
    if found:
        names = "; ".join(f"{f['effect']}" + (f" (or {f['indistinguishable_from']})" if f.get("indistinguishable_from")
                                                else "") + f" on {f['channel']}" for f in found)
        line = f"{len(found)} effect(s) found: {names}"
    else:
        line = "no effect found: the recording agrees with its twin"
    if left:
        line += "; unexplained residual on " + ", ".join(sorted({u["channel"] for u in left}))
    else:
        line += "; nothing left unexplained"
    return line


def summarise(d: dict) -> dict:
    """{"findings", "unexplained", "verdict"} of the diagnosis ``d`` (module doc)."""
    f, u = findings(d), unexplained(d)
    return {"findings": f, "unexplained": u, "verdict": verdict(f, u)}


#: the schema of the summary (docs/diagnosis-json.md): field -> type(s)
SCHEMA = {"findings": {"effect": str, "channel": str, "observable": str, "parameters": list, "fit": dict},
          "parameter": {"name": str, "estimate": (int, float), "se": (int, float, type(None)), "unit": str},
          "fit": {"before_rms": (int, float, type(None)), "after_rms": (int, float, type(None)), "unit": str},
          "unexplained": {"channel": str, "observable": str, "where": dict, "size": (int, float, type(None)),
                          "unit": str, "signature": dict}}


def check_schema(doc: dict) -> list[str]:
    """What in ``doc`` (a diagnosis.json) breaks the summary's schema (:data:`SCHEMA`); [] when none."""
    bad = []

    def has(obj, spec, where):
        if not isinstance(obj, dict):
            bad.append(f"{where}: not an object")
            return
        for k, t in spec.items():
            if k not in obj:
                bad.append(f"{where}: no '{k}'")
            elif not isinstance(obj[k], t) or isinstance(obj[k], bool):
                bad.append(f"{where}.{k}: {type(obj[k]).__name__}, expected {t}")

    if not isinstance(doc.get("verdict"), str) or "\n" in doc.get("verdict", "\n"):
        bad.append("verdict: not one line of text")
    for i, f in enumerate(doc.get("findings", None) or []):
        has(f, SCHEMA["findings"], f"findings[{i}]")
        for j, p in enumerate(f.get("parameters", []) if isinstance(f, dict) else []):
            has(p, SCHEMA["parameter"], f"findings[{i}].parameters[{j}]")
        if isinstance(f, dict) and isinstance(f.get("fit"), dict):
            has(f["fit"], SCHEMA["fit"], f"findings[{i}].fit")
    for i, u in enumerate(doc.get("unexplained", None) or []):
        has(u, SCHEMA["unexplained"], f"unexplained[{i}]")
    for k in ("findings", "unexplained"):
        if not isinstance(doc.get(k), list):
            bad.append(f"{k}: not a list")
    return bad
