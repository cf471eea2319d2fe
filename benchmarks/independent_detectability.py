"""Whether a concealed mean-level effect of the independent lab is detectable at all in one recording:
its expected non-centrality, computed from the lab's own manifest, against the one a test needs.

The tilt table's mean-level effects (temperature drift, scale nonlinearity, axis misalignment,
ADC crosstalk) are seen only through the per-position means. Per axis j, with the generator's
positions (theta, phi), its specific force f (n_pos, 3) and its sensor parameters:

- the effect's signal s_j (m/s^2 per position): kT_j (T_pos - mean T) (T_pos the logged box
  temperature's mean over the position's dwell window), k2_j f_j^2, M_jk f_k + M_jl f_l, or
  c m_prev / K_j (m_prev the fluxgate channel converted before acc_j, the lab's field model);
- the twin's design X_j the diagnosis fits without the effect ('physical': 1, f_x, f_y, f_z,
  f_j^2; 'own_axis': 1, f_j, f_j^2; 'linear': 1, f_x, f_y, f_z; the manifest's ``diagnose_twin``),
  plus the table's two zero errors d f_j / d theta, d f_j / d phi (the survey nuisance);
- the noise of one position's mean (m/s^2): sigma_j^2 = [(s^2 + q^2/12) e / N + sigma_g^2] / K_j^2,
  with s^2 = (white noise per sample)^2 + (converter noise)^2, N = dwell * f_s samples, e = pi / 2
  where the diagnosis takes medians (f_s > 400 Hz) else 1, and sigma_g^2 = sum_k q^2 / (2 pi^2
  k^2) exp(-4 pi^2 k^2 s^2 / q^2) the part of the rounding error the samples' dither does not
  average away (the Fourier series of the sawtooth), counted here as if independent.

    lambda_j = || (I - X_j X_j^+) s_j ||^2 / sigma_j^2

The test needs lambda_90: the non-centrality at which a chi-square test with the effect's k
degrees of freedom at the level alpha / M (alpha = 0.01 per axis, M = 20 candidate columns and
scan values, a Bonferroni stand-in for the engine's max-statistic threshold) has 90 % power.
An effect is detectable in a recording when every axis it must be named on has lambda_j >=
lambda_90. The shared rounding error is treated as independent and the engine's simulated
threshold is higher where it dominates, so this errs on the side of calling a recording detectable.

The turn table's counterpart (slip-ring ripple, timer jitter): ``independent_detectability_turn.py``.
"""
from __future__ import annotations

import importlib
import importlib.util
import math
from pathlib import Path

import numpy as np
from scipy import optimize, stats

#: the mean-level effects this applies to (the others are always scored)
MEAN_LEVEL = ("temperature_drift", "scale_nonlinearity", "axis_misalignment", "adc_crosstalk")
ALPHA, M_TESTS, POWER = 0.01, 20, 0.9
#: the fluxgate channel converted before each accelerometer (the lab's scan list)
PREVIOUS_MAG = {0: 2, 1: 0, 2: 1}


def lambda_needed(k: int, alpha: float = ALPHA, m: int = M_TESTS, power: float = POWER) -> float:
    """The non-centrality giving ``power`` to a chi-square(k) test at level alpha / m."""
    crit = stats.chi2.isf(alpha / m, k)
    return float(optimize.brentq(lambda lam: stats.ncx2.sf(crit, k, lam) - power, 1e-6, 1e4))


def _log_columns(csv: Path, names: tuple[str, ...]) -> np.ndarray:
    """The columns ``names`` of the lab CSV (after its '# key: value' lines and header)."""
    with open(csv) as fh:
        skip = 0
        for line in fh:
            skip += 1
            if not line.startswith("#"):
                header = line.strip().split(",")
                break
    return np.loadtxt(csv, delimiter=",", skiprows=skip, usecols=[header.index(n) for n in names], ndmin=2)


def _windows(tilt, truth: dict) -> np.ndarray:
    """(n_pos, 2) dwell windows (s) of the generator's set-point schedule."""
    knots_t, _ = tilt.setpoint_knots(tilt.positions(), truth["dwell_s"], truth["slew_deg_s"])
    return np.column_stack([knots_t[0::2], knots_t[1::2]])


def _signals(tilt, truth: dict, effect: dict, f: np.ndarray, rot: np.ndarray, csv: Path) -> np.ndarray:
    """(n_pos, 3) the effect's signal per position and axis (m/s^2), columns for k = 2 stacked as (n_pos, 3, 2)."""
    name, p, tri = effect["effect"], effect["parameters"], truth["triad"]
    if name == "temperature_drift":
        tT = _log_columns(csv, ("time_s", "temp_box_degC"))
        T = np.array([tT[(tT[:, 0] >= a) & (tT[:, 0] < b), 1].mean() for a, b in _windows(tilt, truth)])
        return np.asarray(p["bias_tempco_m_s2_per_K"])[None, :] * (T - T.mean())[:, None]
    if name == "scale_nonlinearity":
        return np.asarray(p["k2_per_m_s2"])[None, :] * f ** 2
    if name == "axis_misalignment":
        M = np.asarray(p["M_rad"])
        out = np.zeros(f.shape + (2,))
        for j in range(3):
            others = [k for k in range(3) if k != j]
            out[:, j, :] = M[j, others][None, :] * f[:, others]
        return out
    if name == "adc_crosstalk":
        dec = math.radians(2.0)
        B_lab_uT = np.array([18.5 * math.cos(dec), 18.5 * math.sin(dec), -45.0])
        m_V = 0.08 * rot @ B_lab_uT
        K = np.asarray(tri["K_V_per_m_s2"])
        return np.column_stack([p["leak_fraction"] * m_V[:, PREVIOUS_MAG[j]] / K[j] for j in range(3)])
    raise KeyError(name)


def _design(f: np.ndarray, j: int, twin: str, survey: np.ndarray) -> np.ndarray:
    one = np.ones(f.shape[0])
    if twin == "own_axis":
        cols = [one, f[:, j], f[:, j] ** 2]
    elif twin == "linear":
        cols = [one, f[:, 0], f[:, 1], f[:, 2]]
    else:
        cols = [one, f[:, 0], f[:, 1], f[:, 2], f[:, j] ** 2]
    return np.column_stack(cols + [survey[:, j, 0], survey[:, j, 1]])


def position_sigma(truth: dict) -> np.ndarray:
    """(3,) the noise of one position's mean per axis (m/s^2), module doc."""
    fs, q, lsb = truth["fs_hz"], truth["adc"]["step_V"], truth["adc"]["input_noise_lsb_rms"]
    s2 = truth["noise_V_rms_per_sample"] ** 2 + (lsb * q) ** 2
    n = truth["dwell_s"] * fs
    eff = math.pi / 2 if fs > 400 else 1.0
    k = np.arange(1, 51)
    shared = float(np.sum(q * q / (2 * np.pi ** 2 * k ** 2) * np.exp(-4 * np.pi ** 2 * k ** 2 * s2 / q ** 2)))
    var_V = (s2 + q * q / 12) / n * eff + shared
    return np.sqrt(var_V) / np.asarray(truth["triad"]["K_V_per_m_s2"])


def detectability(truth: dict, csv: Path, tilt) -> dict | None:
    """{lambda: {channel: non-centrality}, lambda_90, detectable, sigma_position_m_s2} of a recording's
    mean-level effect (module doc), or None for a null or another effect. ``tilt``: the lab's
    tilt module (its positions, set-point schedule and specific force)."""
    if truth.get("rig") == "turn_table":     # the table's effects: benchmarks/independent_detectability_turn.py
        spec = importlib.util.spec_from_file_location("independent_detectability_turn",
                                                      Path(__file__).with_name("independent_detectability_turn.py"))
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        return mod.detectability(truth, importlib.import_module(tilt.__package__ + ".turn"))
    eff = [e for e in truth.get("effects", []) if e["effect"] in MEAN_LEVEL]
    if truth.get("rig") != "tilt_table" or not eff:
        return None
    e = eff[0]
    pos = np.radians(tilt.positions())
    rot = tilt.table_to_body(pos[:, 0], pos[:, 1])
    f = tilt.specific_force_body(pos[:, 0], pos[:, 1], truth["g_m_s2"])
    h = 1e-6
    survey = np.stack([(tilt.specific_force_body(pos[:, 0] + h, pos[:, 1], truth["g_m_s2"]) - f) / h,
                       (tilt.specific_force_body(pos[:, 0], pos[:, 1] + h, truth["g_m_s2"]) - f) / h], -1)
    sig = _signals(tilt, truth, e, f, rot, Path(csv))
    sigma = position_sigma(truth)
    twin = (truth.get("diagnose_twin") or {}).get("twin_model", "physical")
    lam = {}
    for j, a in enumerate("xyz"):
        X = _design(f, j, twin, survey)
        S = sig[:, j].reshape(f.shape[0], -1)
        R = S - X @ np.linalg.lstsq(X, S, rcond=None)[0]
        lam[f"acc_{a}"] = float(np.sum(R ** 2) / sigma[j] ** 2)
    k = sig.shape[-1] if sig.ndim == 3 else 1
    need = lambda_needed(k)
    chans = [x.split(":")[0] for x in truth["expected"]]
    return {"effect": e["effect"], "lambda": lam, "lambda_90": need, "dof": k,
            "detectable": all(lam[c] >= need for c in chans if c in lam),
            "sigma_position_m_s2": sigma.tolist()}
