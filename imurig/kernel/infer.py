"""What a lab file with little metadata shows: the import's inferences.

A minimal lab file holds time, set-points (or a rate dial) and channel readings, with a rig
name and a site. :func:`imurig.kernel.import_lab.infer_structure` derives the rest and records every inference with its
evidence in ``rec.meta["inferred"]`` (key -> {"value", "evidence"}) and its doubts in
``rec.meta["import_warnings"]`` (text, prefixed "MARGINAL:" when a check was inconclusive):

- ``sample_rate_hz``: 1 / median(dt); the jitter std(dt)/median(dt); gaps (dt > 1.5 median);
- ``channel_names``: lab names mapped to the bench's (``gyro_x`` -> ``gyro_p``, ``rate`` ->
  ``rate_dial``, the chosen pulse channel -> ``pulse``);
- ``setpoints`` and ``segments``: plateaus of the set-points (ramps and moves are no segment),
  see :mod:`imurig.kernel.plateaus`;
- ``runs`` / mountings from the sign of gravity on the accelerometers (tilt table) or from the
  gyro that answers the dial (turn table), see :mod:`imurig.kernel.gravity_check`;
- ``pulses``: rising edges of the pulse channel, sub-sample times, as events ``pulse_channel``;
- ``nominal_sensitivity``: datasheet defaults (Q-Flex 1.33 mA/g x 750 ohm; FOG 6 mV/(deg/s));
- ``temperatures``: the unit of each ``temp*`` channel (K from degC/K, or V);
- ``adc_step``: the greatest common step q of each channel's values (``rec.channel_quantum``);
- ``adc.scan_list``: the file's channel order when the metadata give none.
"""
from __future__ import annotations

import math

import numpy as np

from imurig.kernel.errors import RecordingError
from imurig.kernel.recording import Recording
from imurig.kernel.site import Site
from imurig.kernel.units import DEG, G_STANDARD

#: datasheet defaults (the bench's sensors: Q-Flex QA-700 1.33 mA/g over 750 ohm; FOG 6 mV/(deg/s))
ACC_DEFAULT_V_PER_M_S2 = 1.33e-3 / G_STANDARD * 750.0
GYRO_DEFAULT_V_PER_RAD_S = 6e-3 / DEG
ACC_KEY = "acc_nominal_sensitivity_V_per_m_s2"
GYRO_KEY = "gyro_nominal_sensitivity_V_per_rad_s"
ACC = ("acc_x", "acc_y", "acc_z")
GYRO = ("gyro_p", "gyro_q", "gyro_r")
#: named sites for ``# site: NAME``
SITES = {"delft": Site(), "tu_delft": Site()}
SETPOINT_NAMES = {"theta": "theta", "phi": "phi", "psi": "psi", "rate": "rate_dial", "rate_dial": "rate_dial",
                  "dial_rate": "rate_dial", "rate_table": "rate_dial", "table_rate": "rate_dial"}
GYRO_ALIASES = {"gyro_x": "gyro_p", "gyro_y": "gyro_q", "gyro_z": "gyro_r"}
#: physical units a sensor channel may come in; it then stands for volts with 1 V per SI unit
PHYSICAL = {"acc": "m/s^2", "gyro": "rad/s"}


def normal_gravity(latitude_deg: float, altitude_m: float = 0.0) -> float:
    """WGS-84 normal gravity (Somigliana) with the free-air term: g = g_e (1 + k sin^2 L) /
    sqrt(1 - e^2 sin^2 L) - 3.086e-6 h  [m/s^2]."""
    s2 = math.sin(math.radians(latitude_deg)) ** 2
    return 9.7803253359 * (1 + 0.00193185265241 * s2) / math.sqrt(1 - 0.00669437999013 * s2) - 3.086e-6 * altitude_m


def note(rec: Recording, key: str, value, evidence: str) -> None:
    """Record one inference (JSON-like value) and the evidence for it."""
    rec.meta.setdefault("inferred", {})[key] = {"value": value, "evidence": evidence}


def warn(rec: Recording, text: str) -> None:
    rec.meta.setdefault("import_warnings", []).append(text)


def resolve_site(rec: Recording, site: str | None, where: str) -> None:
    """``# site: delft`` (a named site), dotted ``site.latitude_deg`` ... keys, or ``site`` given."""
    s = site if site is not None else rec.meta.get("site")
    if s is None:
        return
    if isinstance(s, str):
        if s.strip().lower() not in SITES:
            raise RecordingError(f"{where}: unknown site '{s}'; name one of {sorted(SITES)} or give "
                                 "'# site.latitude_deg:', '# site.longitude_deg:', '# site.altitude_m:' lines")
        rec.meta["site"] = SITES[s.strip().lower()].to_dict()
        note(rec, "site", rec.meta["site"], f"the named site '{s}'")
        return
    if isinstance(s, dict) and "latitude_deg" not in s and "gravity_m_s2" in s:
        warn(rec, "the site gives gravity but no latitude: nothing that needs the Earth's rate or the "
                  "field (turn-table Earth rate, IGRF) can be computed")
        return
    if not isinstance(s, dict) or "latitude_deg" not in s:
        raise RecordingError(f"{where}: the site needs at least 'site.latitude_deg' (and longitude_deg, altitude_m)")
    if "gravity_m_s2" not in s:
        s = dict(s)
        s["gravity_m_s2"] = normal_gravity(float(s["latitude_deg"]), float(s.get("altitude_m", 0.0)))
        note(rec, "site_gravity_m_s2", s["gravity_m_s2"], "WGS-84 normal gravity at the site's latitude and "
                                                            "altitude (give site.gravity_m_s2 if measured)")
        warn(rec, "local gravity not given: WGS-84 normal gravity is used (differs from a measured value by up "
                  "to ~1e-3 m/s^2)")
    rec.meta["site"] = s


def sample_rate(rec: Recording) -> None:
    """Rate 1/median(dt), jitter std(dt)/median(dt) within blocks, gaps dt > 1.5 median(dt)."""
    dt = np.diff(rec.time_s)
    med = float(np.median(dt))
    gaps = np.flatnonzero(dt > 1.5 * med)
    inside = np.delete(dt, gaps)
    jitter = float(np.std(inside) / med) if inside.size else 0.0
    rate = 1.0 / med
    rec.meta.setdefault("sample_rate_hz", rate)
    ev = f"median sample period {med:.9g} s over {dt.size} intervals; jitter {jitter:.2e} of the period"
    if gaps.size:
        first = ", ".join(f"{rec.time_s[i]:.6g} s (+{dt[i]:.3g} s)" for i in gaps[:3])
        ev += f"; {gaps.size} gap(s), first at {first}"
        warn(rec, f"{gaps.size} gap(s) in time_s (first at {first}); they split the record into blocks")
    if jitter > 0.1:
        warn(rec, f"the sample period jitters by {jitter:.1%}; time-series tests assume even sampling")
    note(rec, "sample_rate_hz", rate, ev)
    note(rec, "gaps", [[float(rec.time_s[i]), float(dt[i])] for i in gaps[:100]], f"{gaps.size} gap(s)")


def adc_step(x: np.ndarray) -> float | None:
    """The greatest common step q of the values: every value is offset + k q (k integer).

    q0 = the least positive difference of the distinct values; q = the median of d / round(d / q0)
    over the differences d, refined by least squares over growing spans of codes; accepted when
    every value lies within 0.05 q of the grid and the range spans at most 2^24 codes.
    """
    u = np.unique(x)
    if u.size < 3:
        return None
    d = np.diff(u)
    scale = max(float(np.max(np.abs(u))), 1e-300)
    d = d[d > 1e-12 * scale]
    if d.size == 0:
        return None
    q0 = float(d.min())
    k = np.round(d / q0)
    q = float(np.median(d / k))
    # refine q over growing spans of codes, so that printed values (rounded to a few decimals) do not
    # accumulate the first estimate's error over thousands of codes
    span = 64.0
    while True:
        sel = u - u[0] <= span * q
        n = np.round((u[sel] - u[0]) / q)
        if np.any(n > 0):
            q = float(np.dot(n, u[sel] - u[0]) / np.dot(n, n))
        if np.all(sel):
            break
        span *= 4.0
    codes = (u - u[0]) / q
    if q <= 1e-12 * scale or (u[-1] - u[0]) / q > 2.0 ** 24 or np.max(np.abs(codes - np.round(codes))) > 0.05:
        return None
    return q


def quantisation(rec: Recording) -> None:
    """ADC step of every channel in V (or counts converted to V), recorded in ``channel_quantum``."""
    steps = {}
    for name, x in rec.channels.items():
        if rec.units.get(name) != "V" or name in rec.meta.get("setpoints", []):
            continue
        q = adc_step(x)
        if q is not None:
            rec.channel_quantum.setdefault(name, q)
            steps[name] = q
    if steps:
        note(rec, "adc_step_V", steps, "greatest common step of each channel's distinct values (all values on "
                                       "its grid within 0.05 q); the noise floor is q/sqrt(12)")


def rename_channels(rec: Recording, pulse_channel: str | None, where: str) -> None:
    """Map lab names to the bench's: set-point names, gyro x/y/z -> p/q/r, the pulse channel."""
    ren = {}
    for k in list(rec.channels):
        if k in SETPOINT_NAMES and SETPOINT_NAMES[k] != k and rec.units[k] in ("rad", "rad/s"):
            ren[k] = SETPOINT_NAMES[k]
        elif k in GYRO_ALIASES and GYRO_ALIASES[k] not in rec.channels:
            ren[k] = GYRO_ALIASES[k]
    if pulse_channel:
        if pulse_channel not in rec.channels:
            raise RecordingError(f"{where}: no channel '{pulse_channel}' for the pulses; channels are "
                                 f"{sorted(rec.channels)}")
        if pulse_channel != "pulse":
            ren[pulse_channel] = "pulse"
    for old, new in ren.items():
        if new in rec.channels:
            raise RecordingError(f"{where}: '{old}' would be read as '{new}', which exists already; rename one")
        rec.channels[new] = rec.channels.pop(old)
        rec.units[new] = rec.units.pop(old)
        if old in rec.channel_quantum:
            rec.channel_quantum[new] = rec.channel_quantum.pop(old)
    if ren:
        note(rec, "channel_names", ren, "lab names read as the bench's (set-point, gyro p/q/r, pulse)")


def setpoint_columns(rec: Recording) -> list[str]:
    """Set-points by name: theta/phi/psi angles (rad) and the rate dial (rad/s)."""
    sp = [k for k in ("theta", "phi", "psi") if rec.units.get(k) == "rad"]
    if rec.units.get("rate_dial") == "rad/s":
        sp.append("rate_dial")
    return sp


def infer_rig(rec: Recording, setpoints: list[str], rig: str | None) -> str | None:
    r = rig or rec.meta.get("rig")
    if r:
        r = str(r).replace("-", "_")
        rec.meta["rig"] = r
        return r
    guess = "tilt_table" if "theta" in setpoints else "turn_table" if "rate_dial" in setpoints else None
    if guess:
        rec.meta["rig"] = guess
        note(rec, "rig", guess, f"set-point columns {setpoints}")
        warn(rec, f"no '# rig:' line: the rig is taken as {guess} from the set-point columns")
    return guess


def pulses(rec: Recording) -> None:
    """Rising edges of ``pulse``: threshold midway between the low and high levels (1st and 99.9th
    percentiles); the crossing time interpolated linearly between the two samples that straddle it."""
    if "pulse" not in rec.channels:
        return
    x, t = rec.channels["pulse"], rec.time_s
    lo, hi = np.percentile(x, [1.0, 99.9])
    if not hi > lo:
        warn(rec, "the pulse channel is constant: no pulses found")
        return
    thr = rec.meta.get("pulse_threshold_V", 0.5 * (lo + hi))
    i = np.flatnonzero((x[:-1] < thr) & (x[1:] >= thr))
    gap = np.diff(t) > 1.5 * float(np.median(np.diff(t)))
    i = i[~gap[i]]
    frac = (thr - x[i]) / (x[i + 1] - x[i])
    ev = t[i] + frac * (t[i + 1] - t[i])
    rec.events["pulse_channel"] = ev
    if not any(k.startswith("pulse_") and k != "pulse_channel" for k in rec.events):
        rec.meta.setdefault("timer", "channel")  # the only timer: the pulse channel's edges
    note(rec, "pulses", {"event": "pulse_channel", "count": int(ev.size), "threshold_V": float(thr)},
         f"rising edges of 'pulse' through the midpoint of its levels {lo:.4g} V and {hi:.4g} V, "
         "times interpolated between samples (timer 'channel'; meta 'timer' names it when no "
         "counter's events are given)")


def sensitivities(rec: Recording) -> None:
    """Datasheet sensitivities when the file gives none; 1 V per SI unit for channels in SI units."""
    for kind, names, key, default in (("acc", ACC, ACC_KEY, ACC_DEFAULT_V_PER_M_S2),
                                      ("gyro", GYRO, GYRO_KEY, GYRO_DEFAULT_V_PER_RAD_S)):
        have = [n for n in names if n in rec.channels]
        if not have:
            continue
        phys = [n for n in have if rec.units[n] == PHYSICAL[kind]]
        if phys:
            if len(phys) != len(have):
                raise RecordingError(f"the {kind} channels mix units {[rec.units[n] for n in have]}; give all "
                                     "in V (or counts) or all in physical units")
            rec.meta.setdefault("physical_unit_channels", {}).update({n: PHYSICAL[kind] for n in phys})
            rec.meta[key] = [1.0, 1.0, 1.0]
            note(rec, key, [1.0] * 3, f"{kind} channels come in {PHYSICAL[kind]}: they stand for volts with an "
                                      "effective sensitivity of 1 V per SI unit; the calibration fits what remains")
        elif any(rec.units[n] != "V" for n in have):
            continue   # counts (unit "1"): their counts per SI unit come from the file or are refused later
        elif key not in rec.meta:
            rec.meta[key] = [default] * 3
            note(rec, key, [default] * 3, "datasheet default (no sensitivity given)")
            warn(rec, f"no '{key}': the datasheet default {default:.6g} is used for every {kind} axis; "
                      f"give '# {key}: [s1, s2, s3]' if you know better")


def temperatures(rec: Recording) -> None:
    found = {k: rec.units[k] for k in rec.channels if k.startswith("temp")}
    bad = {k: u for k, u in found.items() if u not in ("K", "V")}
    if bad:
        raise RecordingError(f"temperature channel(s) {bad} must be in degC, K or V (suffix _degC, _K or _V)")
    if found:
        note(rec, "temperatures", found, "temp* channels: K (from _degC or _K) or sensor volts (_V)")


def scan_list(rec: Recording, order: list[str]) -> None:
    adc = rec.meta.get("adc")
    if isinstance(adc, dict) and "scan_list" in adc:
        return
    lst = [c for c in order if c in rec.channels and rec.units[c] == "V" and c not in setpoint_columns(rec)]
    if not lst:
        return
    rec.meta["adc"] = {**(adc if isinstance(adc, dict) else {}), "scan_list": lst}
    note(rec, "adc_scan_list", lst, "no 'adc.scan_list' given: the file's column order is taken as the ADC's "
                                    "scan order (crosstalk tests rely on it; give it if it differs)")


def inference_report(meta: dict) -> tuple[dict, str]:
    """What the import inferred, for a report: ({"inferred", "import_warnings"}, Markdown section);
    ({}, "") for a recording that declared everything."""
    inferred, warnings = meta.get("inferred", {}), meta.get("import_warnings", [])
    if not inferred and not warnings:
        return {}, ""
    lines = ["## What the import inferred", "", "| what | value | evidence |", "|---|---|---|"]
    for k, d in inferred.items():
        v = str(d.get("value"))
        lines.append(f"| {k} | {v if len(v) <= 80 else v[:77] + '...'} | {d.get('evidence', '')} |")
    if warnings:
        lines += ["", "Warnings:", ""] + [f"- {w}" for w in warnings]
    return {"inferred": inferred, "import_warnings": warnings}, "\n".join(lines) + "\n"


def warning_banner(meta: dict) -> str:
    """One bold line for the top of a report when the import accepted the file with warnings ("" if none)."""
    w = meta.get("import_warnings", [])
    if not w:
        return ""
    return (f"**Accepted with {len(w)} import warning{'s' if len(w) > 1 else ''}** (see \"What the import "
            f"inferred\" at the end): {w[0]}{' …' if len(w) > 1 else ''}\n")


def gyro_noise_model(rec: Recording) -> None:
    """``gyro_noise_model`` from the data when the file gives none: white rate noise sigma per sample
    from the first differences within the plateaus (2 % trimmed at each end), sigma = median over
    the plateaus of std(diff) / sqrt(2) (a slow drift cancels, a step at an edge does not count),
    floored at the ADC's q / sqrt(12); ARW N = sigma / sqrt(fs) (the bench's convention: sample
    noise N sqrt(fs)), the median over the axes, in rad/s/sqrt(Hz). The bias instability is
    not resolved from a calibration record: 0, with a warning."""
    if "gyro_noise_model" in rec.meta or not all(c in rec.channels for c in GYRO) or rec.n_segments == 0:
        return
    s = np.broadcast_to(np.asarray(rec.meta[GYRO_KEY], float), (3,))
    fs = rec.sample_rate_hz
    sig = []
    for j, c in enumerate(GYRO):
        per = []
        for sl in rec.segment_slices():
            trim = max(1, (sl.stop - sl.start) // 50)
            x = rec.channels[c][sl.start + trim:sl.stop - trim]
            if x.size > 10:
                per.append(float(np.std(np.diff(x))))
        if not per:
            return
        q = rec.channel_quantum.get(c, 0.0)
        sig.append(max(float(np.median(per)) / math.sqrt(2), q / math.sqrt(12)) / s[j])
    arw = float(np.median(sig)) / math.sqrt(fs)
    rec.meta["gyro_noise_model"] = {"arw_rad_s_per_sqrt_hz": arw, "bias_instability_rad_s": 0.0,
                                    "bias_instability_tau_s": 100.0}
    note(rec, "gyro_noise_model", rec.meta["gyro_noise_model"],
         f"white noise per sample {np.array2string(np.array(sig), precision=3)} rad/s from first differences in "
         f"the plateaus (median over plateaus) (floored at q/sqrt(12)), ARW = sigma/sqrt(fs), median over the axes")
    warn(rec, "gyro_noise_model inferred from the data with no bias instability; give '# gyro_noise_model: "
              "{...}' from an Allan variance if you have one")
