"""Diagnosis of a tilt-table recording (seed 4.3.3-4.3.4: the cable, the pump, crosstalk).

The twin is the nominal model: the physical accelerometer calibration (linear in all axes plus
each axis' own square) fitted to the per-position medians. Two levels are examined:

1. **Position means** (per axis): the residual of the nominal fit, tested by the engine of
   :mod:`imurig.diagnose.engine` against a library of mean-level effects:
   - ``adc_crosstalk``: the previously scanned channel's voltage leaks in (its per-position
     median is the column; amplitude = the settling residual c);
   - ``temperature_drift``: bias drifting with the accelerometer temperature / elapsed time;
   - ``cross_coupling``: products u_j u_k of the other axes.
2. **Within-position scatter** (per axis): the spread of the 100 Hz samples around each
   position's median, against the quiet positions' level:
   - ``building_vibration``: the spread rises in a time window (working hours) and the
     spectrum holds a peak (the pump's frequency);
   - ``cable_fault_spikes``: isolated outliers (> 8 robust sigma) on one channel.
"""
from __future__ import annotations

import datetime as _dt

import numpy as np
from scipy import signal

from imurig.calibration.accelerometer import AXES, indicated
from imurig.calibration.preprocess import lowpass_downsample, segment_statistic
from imurig.campaigns.tilt_table import calibrate, tilt_table_reference
from imurig.diagnose.engine import Candidate, select_effects
from imurig.errors import ConfigError
from imurig.recording import Recording
from imurig.site import parse_time


def _hours(rec: Recording, t: np.ndarray) -> np.ndarray:
    start = parse_time(rec.meta.get("start_time", "2005-01-01T00:00:00+00:00"))
    return (start.hour + start.minute / 60 + (t - rec.time_s[0]) / 3600) % 24


TWIN_MODELS = ("physical", "own_axis", "linear")


def diagnose_tilt_table(rec: Recording, rng: np.random.Generator, alpha: float = 0.01, n_sim: int = 300,
                        twin_model: str = "physical") -> dict:
    """Diagnose a tilt-table recording against the twin ``twin_model``:

    - ``physical``: u_j = b + s (f_j + m_jk f_k + m_jl f_l) + k2 f_j^2 (the lab's final model);
    - ``own_axis``: b + s f_j + k2 f_j^2 (a twin without misalignment);
    - ``linear``: b + s f_j + m_jk f_k + m_jl f_l (a twin without nonlinearity).

    Effects the twin lacks (misalignment, nonlinearity) join the candidate library.
    """
    if twin_model not in TWIN_MODELS:
        raise ConfigError(f"unknown twin model '{twin_model}'; choose one of {', '.join(TWIN_MODELS)}")
    rec100 = lowpass_downsample(rec)
    cal = calibrate(rec, model=twin_model, processed=rec100)
    u, _ = indicated(rec100)
    seg = rec100.segments
    mid = 0.5 * (seg["start_s"] + seg["stop_s"])
    scan = list(rec.meta.get("adc", {}).get("scan_list", []))
    out = {"twin": f"'{twin_model}' accelerometer model fitted to per-position medians", "twin_model": twin_model,
           "axes": {}}
    inputs = {n: u[:, j] for j, n in enumerate(("ax", "ay", "az"))}
    temp_names = [c for c in ("temp_acc_x", "temp_acc_y", "temp_acc_z", "temp_box") if c in rec100.channels]
    temps = segment_statistic(rec100, temp_names, "median") if temp_names else None
    for j, a in enumerate(AXES):
        res = cal.results_[a]
        from imurig.calibration.terms import TermLibrary

        X0 = TermLibrary.from_names(res.names).design(inputs)
        ref, J, _ = tilt_table_reference(rec100)
        y = ref[:, j]
        # the survey leaves each table error uncertain (inclinometer accuracy): its effect on the
        # reference, dref/d(error), joins the twin as nuisance columns where the model terms do
        # not already hold it (a per-mounting phi-zero difference is not a misalignment)
        X0, names0 = _with_survey_nuisance(X0, list(res.names), J[:, j, :])
        lib = []
        ch = f"acc_{a}"
        if ch in scan:
            prev = scan[scan.index(ch) - 1] if scan.index(ch) > 0 else scan[-1]
            if prev in rec100.channels:
                pv = segment_statistic(rec100, [prev], "median")[:, 0]
                lib.append(Candidate("adc_crosstalk", f"ADC multiplexer crosstalk: the previously scanned channel "
                                     f"'{prev}' leaks into '{ch}' (settling too short for the mux frequency)",
                                     ("c",), lambda _, pv=pv: pv))
        # a drift with temperature can only be named where the temperature moved (> 0.2 K)
        if temps is not None and np.ptp(temps[:, 0]) * 1e3 * 0.1 > 0.2:  # volts -> K: 1 uA/K over 10 kohm
            lib.append(Candidate("temperature_drift", "the bias drifts with the sensor's temperature over the "
                                 "campaign", ("drift",), lambda _, t=temps[:, 0] - temps[:, 0].mean(): t))
        others = [n for n in ("ax", "ay", "az") if n != f"a{a}"]
        if not set(others) & set(res.names):
            lib.append(Candidate("axis_misalignment", f"the sensitive axis of acc_{a} leans towards the other two "
                                 "axes (misalignment; the inverse model's coefficients of the other axes' readings)",
                                 tuple(f"m_{a}{o[1]}" for o in others),
                                 lambda _, o=others: np.column_stack([inputs[o[0]], inputs[o[1]]])))
        if f"a{a}^2" not in res.names:
            lib.append(Candidate("scale_nonlinearity", f"second-order scale-factor nonlinearity of acc_{a} (the inverse "
                                 "model's coefficient of its own reading squared, 1/(m/s^2))", ("k2",),
                                 lambda _, n=f"a{a}": inputs[n] ** 2))
        lib.append(Candidate("cross_coupling", "cross-coupling of the other two axes (product term)", ("c",),
                             lambda _, o=others: inputs[o[0]] * inputs[o[1]]))
        d = select_effects(y, X0, names0, lib, rng, alpha=alpha, n_sim=n_sim)
        entry = d.to_dict()
        entry["scatter"] = _scatter(rec100, ch, mid)
        out["axes"][a] = entry
    return out


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


def _scatter(rec100: Recording, ch: str, mid: np.ndarray) -> dict:
    """Within-position scatter: vibration in a time window (with its spectral peak) and spikes."""
    sl = rec100.segment_slices()
    x = rec100.channels[ch]
    robust = np.array([1.4826 * np.median(np.abs(x[s] - np.median(x[s]))) for s in sl])
    floor = np.median(robust)
    spikes = np.array([int(np.sum(np.abs(x[s] - np.median(x[s])) > 8 * max(r, floor))) for s, r in zip(sl, robust)])
    std = np.array([np.std(x[s]) for s in sl])
    hours = _hours(rec100, mid)
    out = {"robust_sigma_V": float(floor), "spikes_total": int(spikes.sum()),
           "positions_with_spikes": int(np.sum(spikes > 0))}
    # a spike count far above what Gaussian noise gives (P(|z| > 8) ~ 1e-15 per sample)
    if spikes.sum() >= 3:
        out["finding_spikes"] = {"effect": "cable_fault_spikes",
                                 "physics": f"a loose cable or connector spikes '{ch}' (seed 4.3.3)",
                                 "spikes": int(spikes.sum()), "positions": int(np.sum(spikes > 0))}
    # vibration: a narrow spectral peak far above the noise floor in the positions' spectra,
    # then located in time by each position's power in that band
    fs = rec100.sample_rate_hz
    nper = int(min(256, min(s_.stop - s_.start for s_ in sl)))
    psd = np.array([signal.welch(x[s_] - np.median(x[s_]), fs=fs, nperseg=nper)[1] for s_ in sl])
    f = signal.welch(x[sl[0]], fs=fs, nperseg=nper)[0]
    band = (f > 2.0) & (f < 0.45 * fs)
    mean_psd = psd.mean(axis=0)
    k = np.flatnonzero(band)[np.argmax(mean_psd[band])]
    ratio = float(mean_psd[k] / np.median(mean_psd[band]))
    out["spectral_peak_to_median"] = ratio
    if ratio > 25:
        pk = psd[:, max(k - 1, 0):k + 2].sum(axis=1)
        loud = pk > 10 * np.median(psd[:, band], axis=1) * 3
        out["finding_vibration"] = {"effect": "building_vibration",
                                    "physics": "narrow-band building vibration (the basement pump) at "
                                               f"{f[k]:.1f} Hz (seed 4.3.3)",
                                    "spectral_peak_hz": float(f[k]), "peak_to_median": ratio,
                                    "positions_affected": int(loud.sum()),
                                    "window_hours": [float(hours[loud].min()), float(hours[loud].max())]
                                    if loud.any() else None}
    _ = std, _dt
    return out
