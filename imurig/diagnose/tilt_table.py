"""Diagnosis of a tilt-table recording (seed 4.3.3-4.3.4: the cable, the pump, crosstalk).

The twin is the nominal model: the physical accelerometer calibration (linear in all axes plus
each axis' own square) fitted to the per-position medians (clipped means for a record on an
ADC's grid at up to ~400 Hz, :func:`position_statistic`). Two levels are examined:

1. **Position means** (per axis): the residual of the nominal fit, tested by the engine of
   :mod:`imurig.diagnose.engine` against the effect library's mean-level effects
   (:mod:`imurig.sensors.effects`, each offering its columns for a ``PositionView``):
   - ``adc_crosstalk``: the previously scanned channel's voltage leaks in (its per-position
     median is the column; amplitude = the settling residual c);
   - ``temperature_drift``: bias drifting with the accelerometer temperature;
   - ``axis_misalignment``, ``scale_nonlinearity``: where the twin lacks them;
   - ``cross_coupling``: products u_j u_k of the other axes;
   - ``saturation``: a clip of the channel, the hinge max(y - L, 0) of the reference (limit in V
     refitted from the clipped codes).
   Where the ADC step is coarse, positions at one level share the rounding error of their medians;
   the engine's threshold is simulated with it and the refitted parameters' standard errors come
   from its covariance (:mod:`imurig.diagnose.position_noise`).
2. **Within-position scatter** (per axis): the spread of the 100 Hz samples around each
   position's median; each scatter effect runs its own test on a ``ScatterView``:
   - ``building_vibration``: the spectrum holds a narrow peak (the pump's frequency), located
     in a time window (working hours), then refitted (amplitude at the peak frequency);
   - ``cable_fault_spikes``: isolated outliers (> 8 robust sigma) on one channel.

The slews between positions, against the dynamic twin, are :mod:`imurig.diagnose.tilt_dynamics`.
"""
from __future__ import annotations

import numpy as np

from imurig.calibration.accelerometer import AXES, indicated
from imurig.calibration.preprocess import segment_statistic
from imurig.calibration.terms import TermLibrary
from imurig.calibration.tilt_reference import calibrate, tilt_table_reference
from imurig.diagnose.engine import select_effects
from imurig.diagnose.crosstalk_sources import (TRIAD_LEAK_VS_MISALIGNMENT, absorbed_note, identifiable_sources,
                                               unknown_scan_sources)
from imurig.diagnose.position_noise import dither_sd, position_noise
from imurig.diagnose.raw_record import as_raw
from imurig.diagnose.samples import scan_order, scan_order_known
from imurig.diagnose.steps import effect_steps
from imurig.diagnose.tilt_dynamics import MAX_DYNAMIC_SAMPLES, diagnose_tilt_dynamics
from imurig.diagnose.tilt_ramps import diagnose_setpoint_delay
from imurig.kernel.errors import ConfigError
from imurig.kernel.filerecord import FileRecord
from imurig.kernel.recording import Recording
from imurig.kernel.site import parse_time
from imurig.sensors.effects import AdcCrosstalk, PositionView, ScatterView, for_view, run_tests
from imurig.sensors.effects.saturation import limit_from_samples
from imurig.sensors.effects.temperature_drift import TemperatureDrift


def _hours(rec: Recording, t: np.ndarray) -> np.ndarray:
    start = parse_time(rec.meta.get("start_time", "2005-01-01T00:00:00+00:00"))
    return (start.hour + start.minute / 60 + (t - rec.time_s[0]) / 3600) % 24


TWIN_MODELS = ("physical", "own_axis", "linear")
#: the lowest logger rate at which the slews are compared with the dynamic twin: at 100 Hz its
#: replay lags the recording by ~3 ms (a 1 kHz time-delay case decimated to 100 Hz gave a delay of
#: -3.2 +- 0.09 ms on all three axes instead of 0.1 ms on acc_y), so slower records are not tested
MIN_SLEW_RATE_HZ = 200.0


def diagnose_tilt_table(rec: Recording | FileRecord, rng: np.random.Generator, alpha: float = 0.01, n_sim: int = 300,
                        twin_model: str = "physical", dynamics: bool = False, skew_in_twin: bool = True) -> dict:
    """Diagnose a tilt-table recording against the twin ``twin_model``:

    - ``physical``: u_j = b + s (f_j + m_jk f_k + m_jl f_l) + k2 f_j^2 (the lab's final model);
    - ``own_axis``: b + s f_j + k2 f_j^2 (a twin without misalignment);
    - ``linear``: b + s f_j + m_jk f_k + m_jl f_l (a twin without nonlinearity).

    Effects the twin lacks (misalignment, nonlinearity) join the candidate library. With
    ``dynamics`` the slews between positions are compared with the dynamic twin as well
    (:func:`imurig.diagnose.tilt_dynamics.diagnose_tilt_dynamics`: time delay, lever arm, wrong
    local gravity; ``skew_in_twin``: whether that twin models the multiplexer's channel skew); a
    set-point delay on logged ramps re-tests the positions without the settling (:func:`settle_guard`).
    ``rec``: a Recording, or a FileRecord read in row ranges (the raw statistics streamed:
    :mod:`imurig.diagnose.raw_record`; the same findings in memory of the 100 Hz working record).
    """
    if twin_model not in TWIN_MODELS:
        raise ConfigError(f"unknown twin model '{twin_model}'; choose one of {', '.join(TWIN_MODELS)}")
    raw = as_raw(rec)
    out, cal = _static(raw, rng, alpha, n_sim, twin_model)
    if dynamics:
        dyn = _dynamic(raw, cal, out["axes"], rng, alpha, n_sim, skew_in_twin)
        guard = settle_guard(dyn)
        if guard is not None:
            # the positions tested again without the samples the table still moves in (on the whole record)
            out, _ = _static(as_raw(guarded(raw.full(), *guard)), rng, alpha, n_sim, twin_model)
            out["settle_guard_s"] = {"start": guard[0], "stop": guard[1], "why": SETTLE_WHY}
        out["dynamic"] = dyn
    return out


#: why the position means are taken again after a set-point delay is accepted
SETTLE_WHY = ("the table follows its set-points tau late, so it is still moving for tau after each plateau of the "
              "set-points begins (leaves it tau early for tau < 0): a clipped mean on a coarse converter keeps those "
              "samples (1 deg off at 20 deg/s and 50 ms), a bias ordered like the moves; each position is cut by "
              "|tau| + 3 SE + one sample at that end and the position means are tested again")


def settle_guard(dyn: dict) -> tuple[float, float] | None:
    """(start, stop) seconds to cut from each position where the set-point ramps' test
    (:func:`imurig.diagnose.tilt_ramps.diagnose_setpoint_delay`) accepted a delay tau +- se: the
    table reaches each plateau |tau| late (tau > 0) or leaves it |tau| early (tau < 0), so
    |tau| + 3 se + one sample (the interpolation between a ramp's last sample and the plateau)
    is cut at that end; None where no delay was accepted or the slews were the dynamic twin's."""
    f = next((f for f in dyn.get("findings", []) if f["effect"] == "time_delay" and f["channel"] == "acc"), None)
    if f is None or "setpoint_sample_s" not in dyn:
        return None
    tau, se = next((q["estimate"], q["std_error"]) for q in f["parameters"] if q["name"] == "tau_s")
    cut = abs(tau) + 3 * se + dyn["setpoint_sample_s"]
    return (cut, 0.0) if tau > 0 else (0.0, cut)


def guarded(rec: Recording, start_s: float, stop_s: float) -> Recording:
    """``rec`` with every segment cut by ``start_s`` at its start and ``stop_s`` at its end (at most
    a quarter of the segment at each end)."""
    seg = dict(rec.segments)
    a, b = np.asarray(seg["start_s"], float), np.asarray(seg["stop_s"], float)
    q = 0.25 * (b - a)
    seg["start_s"], seg["stop_s"] = a + np.minimum(start_s, q), b - np.minimum(stop_s, q)
    return rec.replace(segments=seg)


def _static(raw, rng: np.random.Generator, alpha: float, n_sim: int, twin_model: str):
    """(the position means' and scatter's diagnosis, the twin's calibration) of :func:`diagnose_tilt_table`;
    ``raw``: :func:`imurig.diagnose.raw_record.as_raw` of the recording."""
    rec100 = raw.working()
    stat = position_statistic(raw, rec100)
    cal = calibrate(rec100, model=twin_model, processed=rec100, statistic=stat)
    u, _ = indicated(rec100, stat)
    seg = rec100.segments
    mid = 0.5 * (seg["start_s"] + seg["stop_s"])
    median_cache = {}

    def medians(name: str):
        """Per-position level of a recorded channel (V; the position statistic, a temperature's
        clipped mean: :func:`level_statistic`), or None where it is not recorded."""
        if name not in median_cache:
            median_cache[name] = (segment_statistic(rec100, [name], level_statistic(name, stat))[:, 0]
                                  if name in rec100.channels else None)
        return median_cache[name]
    # a scan order the metadata give is trusted; without one (the import's guess from the column
    # order is not), every logged channel outside the triad is a candidate leak source
    ref, J, _ = tilt_table_reference(rec100)
    scan, scan_source = scan_order(raw)
    known = scan_order_known(raw)
    sources, source_report = (), {}
    if not known:
        scan, scan_source = [], "unknown (no adc.scan_list in the metadata)"
        sources, source_report = unknown_scan_sources(raw, rec100, medians, median_cache, ref, J,
                                                      tuple(f"acc_{a}" for a in AXES))
    out = {"twin": f"'{twin_model}' accelerometer model fitted to per-position {STATISTIC_WORDS[stat]}",
           "twin_model": twin_model, "position_statistic": stat,
           "adc_scan_order": {"channels": scan, "from": scan_source, **source_report}, "axes": {}}
    inputs = {n: u[:, j] for j, n in enumerate(("ax", "ay", "az"))}
    for j, a in enumerate(AXES):
        res = cal.results_[a]
        X0 = TermLibrary.from_names(res.names).design(inputs)
        y = ref[:, j]
        # the survey leaves each table error uncertain (inclinometer accuracy): its effect on the
        # reference, dref/d(error), joins the twin as nuisance columns where the model terms do
        # not already hold it (a per-mounting phi-zero difference is not a misalignment)
        X0, names0 = _with_survey_nuisance(X0, list(res.names), J[:, j, :])
        ch = f"acc_{a}"
        src, absorbed = identifiable_sources(sources, medians, X0)
        view = PositionView(channel=ch, axis=a, readings=inputs, channel_median=medians, scan_list=tuple(scan),
                            model_terms=frozenset(res.names), reference=y, crosstalk_sources=src)
        # the mean-level effects of the library (crosstalk, temperature drift, misalignment and
        # nonlinearity where the twin lacks them, cross-coupling) offer their columns
        lib = [c for cls in for_view(PositionView.kind) for c in cls().candidates(view)]
        prev = AdcCrosstalk.previous_channel(scan, ch)
        alias = _crosstalk_alias_of_drift(lib, X0, prev)
        if alias is not None:
            lib = [c for c in lib if c.name != "adc_crosstalk"]
        noise, noise_info = _level_noise(raw, rec100, ch, y, X0, medians(ch), averaged=stat != "median")
        d = select_effects(y, X0, names0, lib, rng, alpha=alpha, n_sim=n_sim, noise=noise)
        entry = d.to_dict()
        entry["noise_model"] = noise_info
        for f in entry["findings"]:
            if f["effect"] == "adc_crosstalk" and sources:
                prev = f["scan"]["source_channel"]
                f.update(source_channel=prev, sources_tested=list(sources))
            elif f["effect"] == "adc_crosstalk":
                f.update(previous_channel=prev, scan_order_from=scan_source)
            if f["effect"] == "saturation":
                _saturation_limit(f, raw, ch, y, u[:, j], raw.adc_step(ch))
            if f["effect"] == "temperature_drift":
                # per unit of the temperature channel as read (V of a 10 mV/K sensor, or K)
                t_ch = next((c for c in TemperatureDrift.channels if c in raw.channels), None)
                for q in f.get("parameters", []):
                    q["unit"] = f"m/s^2/{raw.units.get(t_ch, 'V')}"
        if alias is not None:
            entry["indistinguishable"] = [alias]
        if absorbed:
            entry.setdefault("indistinguishable", []).append(absorbed_note(ch, absorbed))
        entry["scatter"] = _scatter(rec100, ch, mid, raw.adc_step(ch))
        entry["scatter"].update(raw.raw_tests(ch, alpha))
        entry.update(_position_residuals(y, X0, names0, lib, d, a, hours_elapsed=(mid - rec100.time_s[0]) / 3600.0,
                                         reading=inputs[f"a{a}"], prev=prev))
        out["axes"][a] = entry
    out["indistinguishable"] = [GRAVITY_VS_SCALE] + ([] if known else [TRIAD_LEAK_VS_MISALIGNMENT])
    return out, cal


#: the per-position statistic: the median (seed C.1.1), or for a record on an ADC's grid that is
#: used as logged or barely decimated, the clipped mean (:func:`imurig.calibration.preprocess.clipped_mean`)
STATISTIC_WORDS = {"median": "medians", "clipped_mean": "clipped means (median +- 6 robust sigma + 1 ADC step)"}


def position_statistic(raw, rec100: Recording, max_decimation: float = 4.0) -> str:
    """'clipped_mean' where every accelerometer channel is logged on an ADC's grid (step q > 0)
    and the working record averages at most ``max_decimation`` logged samples per sample (the
    record as logged, or 200 Hz low-passed to 100 Hz), else 'median'. The median of values on or
    near a grid stays on it (half-steps at best): an error up to q/2 per position that no number
    of samples reduces. At 16 bits over +-5 V (q = 153 uV, noise 0.4 q, 102.4 Hz) it hid a
    48 ug/g^2 nonlinearity (non-centrality 0.7-9 per axis with the median, 100-1100 with the
    clipped mean); at 12 bits, 200 Hz it doubled the position scatter (4.6 vs 2.2 mm/s^2). A
    1 kHz record low-passed to 100 Hz averages enough codes (median and clipped mean within
    their sqrt(pi/2) efficiency ratio), so the seed's median is kept there. ``raw``: the record as
    logged (:func:`imurig.diagnose.raw_record.as_raw`)."""
    if raw.sample_rate_hz / rec100.sample_rate_hz > max_decimation:
        return "median"
    acc = [f"acc_{a}" for a in AXES]
    return "clipped_mean" if all(c in raw.channels and raw.adc_step(c) > 0 for c in acc) else "median"


def level_statistic(name: str, stat: str) -> str:
    """The per-position statistic of a recorded channel ``name``: the accelerometers' ``stat``, but
    'clipped_mean' for a temperature channel (``temp*``).

    A bias drift is linear in the temperature, kb (T(t) - T0), so each position's level holds kb
    times the mean of T(t) over the window (for a median of the accelerometer samples too: its
    drift within a window is a smooth ramp under symmetric noise). A thermometer is logged on a
    coarse grid (0.01 degC) and moves by a few steps within a dwell; the median of such values
    stays on the grid or half-way between, an error up to q/2 (0.005 K) per position that no
    number of samples reduces and no noise model holds. At 20 x a Q-Flex's tempco (a numpy-made
    50 Hz record, 0.01 degC steps) it left 59/45/38 um/s^2 RMS after the drift's fit where the
    same record with the temperature logged finely left 22/25/18. The clipped mean
    (:func:`imurig.calibration.preprocess.clipped_mean`) averages the steps and keeps the
    median's robustness to spikes."""
    return "clipped_mean" if name.startswith("temp") else stat


#: a wrong local gravity and the scale factors, which the position means cannot tell apart
GRAVITY_VS_SCALE = {
    "effects": ["wrong_local_gravity", "scale_factors"],
    "note": "a wrong local gravity in the twin scales every reference by g_twin / g_true: the position "
            "means cannot tell it from the scale factors, which absorb it exactly; only the slews' g-free "
            "kinematic accelerations could show it, and there it equals a lever-arm error along the phi axis"}


def _dynamic(raw, cal, axes: dict, rng: np.random.Generator, alpha: float, n_sim: int,
             skew_in_twin: bool) -> dict:
    """The slews against the dynamic twin (:func:`imurig.diagnose.tilt_dynamics.diagnose_tilt_dynamics`),
    given what the position means found (``axes``), or why they were not tested."""
    if "inferred" in raw.meta and not raw.meta.get("protocol"):
        # another lab's file: its logged (ramped) set-points are the trajectory, at any sample rate
        return diagnose_setpoint_delay(raw.full(), cal, alpha=alpha)
    if raw.sample_rate_hz < MIN_SLEW_RATE_HZ or not {"theta", "phi"} <= set(raw.channels):
        return {"tested": False, "why": f"the slews need per-sample theta/phi set-point channels at >= "
                                        f"{MIN_SLEW_RATE_HZ:g} Hz"}
    if raw.n > MAX_DYNAMIC_SAMPLES:
        return {"tested": False, "why": f"{raw.n} samples: this version keeps five replays of the whole "
                                        f"record (the twin's specific force) in memory; records up to "
                                        f"{MAX_DYNAMIC_SAMPLES} samples (cut the record into runs)"}
    static_found = tuple(a for a in AXES if axes[a]["findings"])
    crosstalk = tuple(a for a in AXES if any(f["effect"] == "adc_crosstalk" for f in axes[a]["findings"]))
    return diagnose_tilt_dynamics(raw.full(), cal, rng, alpha=alpha, n_sim=n_sim, skew_in_twin=skew_in_twin,
                                  recalibrate_axes=static_found, crosstalk_axes=crosstalk)


#: what each position-mean effect's column is (the revealing variable of the report's plots): label, unit
_REVEAL = {"adc_crosstalk": ("median of the previously scanned channel '{prev}'", "V"),
           "temperature_drift": ("sensor temperature reading − mean (10 mV/K)", "V"),
           "axis_misalignment": ("indicated specific force of the other axis, {col}", "m/s²"),
           "scale_nonlinearity": ("own indicated specific force squared", "(m/s²)²"),
           "cross_coupling": ("product of the other two axes' indicated specific forces", "(m/s²)²"),
           "saturation": ("the twin's reference beyond the clip limit, max(y − L, 0)", "m/s²")}


def _level_noise(raw, rec100: Recording, ch: str, y: np.ndarray, X0: np.ndarray, median_V: np.ndarray,
                 averaged: bool = False):
    """The position regression's noise where positions at one level share the ADC's rounding error
    (:func:`imurig.diagnose.position_noise.position_noise`): (noise generator or None, its figures).
    ``averaged``: the position statistic averages codes (a clipped mean), so the shared error is the
    rounding smoothed by the samples' own dither, as for a low-passed record, not by the median's
    sampling spread. ``raw``: the record as logged (its positions' sds and codes)."""
    sens = rec100.meta.get("acc_nominal_sensitivity_V_per_m_s2")
    if sens is None or median_V is None:
        return None, {"shared_level_errors": False, "why": "no nominal sensitivity"}
    _, sd, n = raw.segment_moments(ch)
    q = raw.adc_step(ch)
    decimated = raw.decimated or averaged
    dither = raw.dither(ch, q) if decimated and q > 0 else None
    return position_noise(y, X0, y, median_V, q, float(sens["xyz".index(ch[-1])]), sd, n,
                          decimated=decimated, dither_V=dither)


def _saturation_limit(f: dict, raw, ch: str, y: np.ndarray, reading: np.ndarray, quantum_V: float) -> None:
    """Complete an accepted clipping finding ``f`` (the engine's hinge at (side, L) in m/s^2): the
    positions it clips, the limit in volts refitted from their logged samples
    (:func:`imurig.sensors.effects.saturation.limit_from_samples`) and the evidence: the clipped
    readings' spread against the reference, and the within-position spread there and elsewhere (a clip
    before the converter leaves only the converter's noise)."""
    side, limit = (float(v) for v in f["scan"]["side, limit_m_s2"])
    S = side * (y - limit) > 0
    _, sds, _ = raw.segment_moments(ch)
    L, se = limit_from_samples([raw.segment_samples(ch, i) for i in np.flatnonzero(S)], quantum_V)
    name = "upper_limit_V" if side > 0 else "lower_limit_V"
    f["parameters"].append({"name": f"saturation:{name}", "estimate": L, "std_error": se})
    f.update(channel=ch, clipped_positions=np.flatnonzero(S).tolist(), limit_m_s2=limit,
             evidence={"reading_range_clipped_m_s2": float(np.ptp(reading[S])),
                       "reference_range_clipped_m_s2": float(np.ptp(y[S])),
                       "within_sd_clipped_V": float(np.sqrt(np.mean(sds[S] ** 2))),
                       "within_sd_other_V": float(np.sqrt(np.mean(sds[~S] ** 2))) if (~S).any() else None,
                       "adc_step_V": quantum_V})


def _position_residuals(y, X0, names0, lib, d, a: str, hours_elapsed, reading, prev) -> dict:
    """The position means' fit step by step and the residuals before/after (m/s^2) with the
    revealing variable of each accepted effect (its column), for the report.

    Observable: y = the twin's reference specific force per position (m/s^2); the recording
    through the nominal calibration is y - r_before, the corrected twin y - r_before + r_after
    (so that twin - recording = r_before and corrected twin - recording = r_after)."""
    st = effect_steps(y, X0, names0, lib, d)
    variables = []
    for f in d.findings:
        C = st["columns"][f.name]
        pnames = next(c.param_names for c in lib if c.name == f.name)
        for k in range(C.shape[1]):
            label, unit = _REVEAL.get(f.name, (f.name, "–"))
            col = f"u_{pnames[k][-1]}" if f.name == "axis_misalignment" else ""
            variables.append({"effect": f.name, "parameter": pnames[k], "label": label.format(prev=prev, col=col),
                              "unit": unit, "values": C[:, k].tolist(),
                              "coef": st["coef"].get(f"{f.name}:{pnames[k]}")})
    return {"fit_steps": st["steps"], "residuals": {
        "unit": "m/s^2", "reference": np.asarray(y, float).tolist(), "before": st["resid_before"].tolist(),
        "after": st["resid_after"].tolist(), "elapsed_h": np.asarray(hours_elapsed, float).tolist(),
        "reading_m_s2": np.asarray(reading, float).tolist(), "variables": variables,
        "convention": "residual = twin's reference - recording through the calibration (position medians)"}}


def _crosstalk_alias_of_drift(lib: list, X0: np.ndarray, prev: str | None, r_max: float = 0.9) -> dict | None:
    """Crosstalk from a temperature channel (the scan wraps from 'temp_box' to acc_x) moves
    with the temperature: across the positions its column, given the twin's columns X0, can
    match the temperature drift's. When |r| > ``r_max`` the two cannot be told apart; the
    drift is tested (a crosstalk c ~ 2e-4 of a 10 mV/K temperature channel is ~2 uV/K, far
    below a Q-Flex's bias tempco) and the pair is reported as indistinguishable."""
    if prev is None or not prev.startswith("temp"):
        return None
    cols = {c.name: c.design(None)[:, 0] for c in lib
            if c.name in ("adc_crosstalk", "temperature_drift")}
    if len(cols) < 2:
        return None
    Q, _ = np.linalg.qr(X0)
    a, b = (v - Q @ (Q.T @ v) for v in (cols["adc_crosstalk"], cols["temperature_drift"]))
    r = float(a @ b / np.sqrt((a @ a) * (b @ b)))
    if abs(r) <= r_max:
        return None
    return {"effects": ["temperature_drift", "adc_crosstalk"], "correlation": r,
            "note": f"crosstalk from the previously scanned channel '{prev}' (a temperature channel) has the "
                    f"temperature drift's signature across the positions (r = {r:.3f} given the twin); the drift, "
                    "the physically likely one, is tested"}


def _with_survey_nuisance(X0: np.ndarray, names: list, Jj: np.ndarray, rtol: float = 1e-6):
    """Append the survey-error columns of ``Jj`` (m, q) that add rank to X0 (m, p)."""
    X, out = X0, list(names)
    rank = np.linalg.matrix_rank(X, tol=rtol * np.linalg.norm(X, 2))
    for k in range(Jj.shape[1]):
        X1 = np.column_stack([X, Jj[:, k]])
        r1 = np.linalg.matrix_rank(X1, tol=rtol * np.linalg.norm(X1, 2))
        if r1 > rank:
            X, rank = X1, r1
            out.append(f"survey_error_{k}")
    return X, out


def _scatter(rec100: Recording, ch: str, mid: np.ndarray, quantum_V: float = 0.0) -> dict:
    """Within-position scatter: each scatter effect of the library runs its own test (the pump's
    spectral peak located in the day, with its refit; the loose cable's spikes) on the samples
    of every position; a test that fires reports its finding under the effect's key.
    ``quantum_V``: the recorded channel's ADC step q (V), the floor q / sqrt(12) of every noise level."""
    j = "xyz".index(ch[-1])
    sens = rec100.meta.get("acc_nominal_sensitivity_V_per_m_s2")
    # each position's edges trimmed by 0.25 s: the working low-pass (and a table that settles) smears
    # the move into the first and last samples, which would count as spikes
    trim = int(np.ceil(0.25 * rec100.sample_rate_hz))
    pos = [slice(s.start + trim, s.stop - trim) if s.stop - s.start > 4 * trim else s
           for s in rec100.segment_slices()]
    view = ScatterView(channel=ch, samples=rec100.channels[ch], positions=pos,
                       sample_rate_hz=rec100.sample_rate_hz, hour_of_day=_hours(rec100, mid),
                       sensitivity_V_per_SI=float(sens[j]) if sens is not None else None, quantum_V=quantum_V)
    return run_tests(ScatterView.kind, view)

