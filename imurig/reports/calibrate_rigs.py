"""``imurig calibrate`` for every rig: which rig a recording comes from, and each rig's calibration
written as ``calibration.json`` (what ``imurig apply`` takes), ``summary.json`` (every parameter as
{name, unit, estimate, std_error} and, with a simulation's truth, injected and z) and ``report.md``.

Rigs: ``tilt-table`` (accelerometers on set-point positions), ``turn-table`` (gyros on whole rounds
between index pulses, :class:`~imurig.calibration.gyro.GyroCalibration`), ``six-face`` (a box on its
six faces and rotated through a known angle about each axis, :mod:`imurig.calibration.six_face`),
``thermal`` (bias and scale against temperature) and ``magnetometer`` (ellipse / ellipsoid).
"""
from __future__ import annotations

import numpy as np

import imurig
from imurig.calibration.accelerometer import SPEC as ACC_SPEC
from imurig.calibration.gyro import SPEC as GYRO_SPEC
from imurig.calibration.gyro import GyroCalibration, reference_rates, round_windows, unexcited_axes
from imurig.calibration.six_face import FACES, detect, face_table, fit_accelerometer, site_gravity
from imurig.calibration.six_face_gyro import fit_gyro, inverse_model, refuse_nonlinearity
from imurig.calibration.triad import nominal_sensitivity
from imurig.calibration.turned_axis import TurnedAxisCalibration
from imurig.campaigns.turn_table import gyro_parameters
from imurig.kernel.errors import ConfigError, RecordingError
from imurig.kernel.infer import inference_report, warning_banner
from imurig.kernel.outputs import OutputFolder, clean_json
from imurig.kernel.recording import Recording
from imurig.reports.common import md_table

RIGS = ("tilt-table", "turn-table", "six-face", "thermal", "magnetometer")
#: the models each rig takes (the first is its default)
MODELS = {"tilt-table": ("physical", "linear", "cross", "seed_final", "paper_eq2", "stepwise", "backward"),
          "turn-table": ("physical", "linear", "seed_final", "paper_eq3", "stepwise", "backward"),
          "six-face": ("auto", "linear", "physical", "seed_final", "stepwise", "backward", "cross"),
          "thermal": ("auto",), "magnetometer": ("auto",)}
TIMERS = ("auto", "adc", "hp6700", "gps_mark")


def infer_rig(rec: Recording) -> str:
    """The rig of a recording: its ``rig`` metadata, else its set-points (theta/phi: tilt table;
    rate_dial: turn table; attitude/step/branch: thermal), else six-face when it has an accelerometer
    triad and no set-points."""
    rig = str(rec.meta.get("rig", "")).replace("_", "-")
    named = {"tilt-table": "tilt-table", "turn-table": "turn-table", "six-face": "six-face",
             "thermal-chamber": "thermal", "thermal": "thermal", "mag-rig": "magnetometer",
             "magnetometer": "magnetometer"}
    if rig in named:
        return named[rig]
    seg = set(rec.segments)
    if {"attitude", "step", "branch"} <= seg:
        return "thermal"
    if "rate_dial" in seg:
        return "turn-table"
    if {"theta", "phi"} <= seg:
        return "tilt-table"
    if all(c in rec.channels for c in ACC_SPEC.channels):
        return "six-face"
    raise RecordingError(f"cannot tell which rig recorded {rec.meta.get('source', 'this recording')}: no '# rig:' "
                         f"line, no set-points and no accelerometer triad; give --rig (one of {list(RIGS)})")


def check_model(rig: str, model: str | None) -> str:
    """The model for ``rig`` (its default when None); ConfigError for one the rig does not take."""
    if rig not in MODELS:
        raise ConfigError(f"unknown rig {rig!r}; choose one of {list(RIGS)}")
    if model is None:
        return MODELS[rig][0]
    if model not in MODELS[rig]:
        raise ConfigError(f"the {rig} calibration takes --model {list(MODELS[rig])}, not {model!r}")
    return model


def choose_timer(rec: Recording, timer: str) -> str:
    """The pulse timer: the one asked for, else the HP counter's events, another timer's, or the ADC pulse channel."""
    if timer != "auto":
        return timer
    ev = [k[len("pulse_"):] for k in rec.events if k.startswith("pulse_") and not k.endswith("_true")]
    if "hp6700" in ev:
        return "hp6700"
    if ev:
        return ev[0]
    if "pulse" in rec.channels:
        return "adc"
    raise RecordingError("the turn-table calibration needs the table's once-per-round pulses: a 'pulse' channel "
                         "(CSV column pulse_V) or pulse times from a timer (CSV column event_pulse_<timer>_s)")


def _write(out: OutputFolder, rig: str, rec: Recording, calibrations: dict, params: list, notes: list,
           extra: dict | None = None) -> dict:
    files = {"report": "report.md", "summary": "summary.json", **{k: k for k in calibrations}}
    for name, d in calibrations.items():
        out.write_json(name, d)
    imported, section = inference_report(rec.meta)
    summary = clean_json({"rig": rig, "imurig_version": imurig.__version__, "parameters": params, "notes": notes,
                          "n_samples": rec.n, "sample_rate_hz": rec.sample_rate_hz, "files": files,
                          "models": {}, **(extra or {}), **imported})
    out.write_json("summary.json", summary)
    L = [f"# {rig} calibration — imurig {imurig.__version__}\n", warning_banner(rec.meta),
         f"Recording: {rec.meta.get('source', '?')}, {rec.n:,} samples at {rec.sample_rate_hz:.6g} Hz.\n"]
    L += [f"- {n}" for n in notes]
    L.append("\n## Parameters (forward model)\n")
    L.append(md_table(["parameter", "unit", "estimate", "std. error", "injected", "z"],
                      [[p["name"], p["unit"], p["estimate"], p["std_error"], p.get("injected"), p.get("z")]
                       for p in params]))
    if section:
        L.append("\n" + section)
    out.write_text("report.md", "\n".join(L) + "\n")
    return summary


def calibrate_turn_table(rec: Recording, out: OutputFolder, model: str, timer: str) -> dict:
    """Gyros on the turn table: whole rounds between pulses, GLS with the recording's noise model."""
    tm = choose_timer(rec, timer)
    if model == MODELS["turn-table"][0]:
        rw, rate = round_windows(rec, tm)
        if unexcited_axes(reference_rates(rw, rate)):
            return calibrate_turned_axis(rec, out, tm)
    cal = GyroCalibration(model=model, timer=tm).fit(rec)
    params = gyro_parameters(cal, rec) if "mount" in rec.segments or not rec.truth else cal.physical_parameters()
    notes = [f"timer: {tm}; {cal.windows_.n_segments} steps of whole rounds; model {model}"]
    return _write(out, "turn-table", rec, {"calibration.json": cal.to_dict()}, params, notes)


def calibrate_turned_axis(rec: Recording, out: OutputFolder, timer: str) -> dict:
    """A table that turned about one gyro's axis only: that gyro, and the others' biases and cross-axis
    sensitivities (:mod:`imurig.calibration.turned_axis`)."""
    cal = TurnedAxisCalibration(timer=timer).fit(rec)
    others = " and ".join(a for a in "pqr" if a != cal.axis_)
    notes = [f"timer: {timer}; {cal.windows_.n_segments} steps of whole rounds",
             f"the table turned about the {cal.axis_} gyro's axis only: the {cal.axis_} gyro is calibrated (sensitivity, "
             f"bias{', nonlinearity' if len(cal.coef_[cal.axis_]) > 2 else ''}); for the {others} gyros only their "
             f"biases and their cross-axis sensitivity to {cal.axis_}, through their nominal sensitivities; their "
             f"scale factors need steps with them on the table axis ({others.replace(' and ', '_up, ')}_up)",
             f"standard errors from the scatter of the {cal.windows_.n_segments} step means ({cal.dof_} residual dof)"]
    return _write(out, "turn-table", rec, {"calibration.json": cal.to_dict()}, cal.parameters_, notes)


def calibrate_six_face(rec: Recording, out: OutputFolder, model: str, rotation_deg: float) -> dict:
    """The six-position-and-rotation protocol (module doc of :mod:`imurig.calibration.six_face`)."""
    p = detect(rec, rotation_deg)
    fs = rec.sample_rate_hz
    if p.gyro_channels and model not in ("auto", "linear"):
        refuse_nonlinearity(p.rotations, fs)
    if model not in ("auto", "linear"):
        raise ConfigError(f"the six-face protocol fits the linear model and the terms its faces identify "
                          f"(--model auto or linear), not {model!r}")
    s_a, unit_a = nominal_sensitivity(rec, ACC_SPEC)
    u = rec.stack(ACC_SPEC.channels) / s_a
    m, v, n = face_table(u, p.faces)
    acc = fit_accelerometer(m, v, site_gravity(rec), s_a, min_dof=2 if model == "auto" else 99,
                            unit=_word(unit_a))
    notes = [f"faces: " + ", ".join(f"{f} {len(p.faces[f])} window(s), {n[i] / fs:.1f} s"
                                    for i, f in enumerate(FACES)),
             "windows of one face pool into one observation (its mean; the variance of that mean by batch means)",
             *p.left_out, *acc["left_out"]]
    params = list(acc["parameters"])
    cal = {"calibration.json": _inverse_dict(ACC_SPEC, acc["C"], acc["c"], s_a, unit_a)}
    extra = {"faces": {f: {"windows": len(p.faces[f]), "samples": int(n[i])} for i, f in enumerate(FACES)},
             "accelerometer_terms": acc["terms"]}
    if p.gyro_channels:
        s_g, unit_g = nominal_sensitivity(rec, GYRO_SPEC, p.gyro_channels)
        gu = rec.stack(p.gyro_channels) / s_g
        gy = fit_gyro(gu, fs, p.faces, p.rotations, s_g, _word(unit_g))
        params += [{**q, "name": "gyro_" + q["name"]} for q in gy["parameters"]]
        notes.append(f"rotations: {len(p.rotations)} of {rotation_deg:g} deg, about "
                     + ", ".join(f"{'pqr'[r['axis']]} ({r['sign']:+.0f})" for r in p.rotations))
        cal["calibration_gyro.json"] = _inverse_dict(GYRO_SPEC, gy["K"], gy["bias"], s_g, unit_g)
        extra["rotations"] = [{"axis": "pqr"[r["axis"]], "reference_deg": float(np.degrees(r["angle_rad"])),
                               "integrated_deg": np.degrees(gy["angles_rad"][:, i]).tolist(),
                               "duration_s": float(gy["durations_s"][i])} for i, r in enumerate(p.rotations)]
    else:
        notes.append("no gyro channels: accelerometers only")
    return _write(out, "six-face", rec, cal, params, notes, extra)


def _word(unit: str) -> str:
    return "counts" if unit == "1" else unit


def _inverse_dict(spec, K: np.ndarray, b: np.ndarray, s: np.ndarray, unit: str) -> dict:
    """The linear inverse model q = K^-1 (u - b) in the calibration.json format of ``imurig apply``."""
    return {"kind": spec.json_kind, "version": 1, "model": "six_face_linear", "statistic": "mean",
            "nominal_sensitivity": np.asarray(s, float).tolist(), "nominal_sensitivity_unit": f"{_word(unit)}/"
            f"({spec.quantity_unit})", "equation": f"ref_i [{spec.quantity_unit}] = sum_k coef_ik * term_k(u), "
            "u = channel / nominal_sensitivity", "axes": inverse_model(K, b, spec.axes, spec.inputs)}


def calibrate_thermal(rec: Recording, out: OutputFolder) -> dict:
    """Bias and scale against temperature (the thermal campaign's analysis)."""
    from imurig.campaigns.thermal import analyse  # the campaign's sensor models: loaded for this rig only
    from imurig.reports.thermal import thermal_calibration_dict

    try:
        res = analyse(rec)
    except KeyError as e:
        raise RecordingError(f"the thermal calibration needs {e} in the recording (a thermal-chamber recording "
                             "with attitude, step and branch segments)") from None
    params = [{k: c[k] for k in ("name", "unit", "estimate", "std_error", "injected", "z")} for c in res["coefficients"]]
    return _write(out, "thermal", rec, {"calibration.json": thermal_calibration_dict(res)}, params,
                  ["temperature models per channel: bias and scale against the sensor's temperature"])


def calibrate_magnetometer(rec: Recording, out: OutputFolder) -> dict:
    """Ellipse (level circle) and ellipsoid (tumble) fits of the magnetometer."""
    from imurig.campaigns.magnetometer import analyse  # the IGRF field model: loaded for this rig only
    from imurig.reports.magnetometer import calibration_dict

    try:
        res = analyse(rec)
    except KeyError as e:
        raise RecordingError(f"the magnetometer calibration needs {e} in the recording (the field's "
                             "igrf_horizontal_T / igrf_total_T and the manoeuvre windows)") from None
    params = [{k: c.get(k) for k in ("name", "unit", "estimate", "std_error", "injected", "z")}
              for c in res["parameters"]]
    return _write(out, "magnetometer", rec, {"calibration.json": calibration_dict(res)}, params,
                  [f"calibrated field norm spread on the tumble: {res['norm_std_nT']:.1f} nT"])
