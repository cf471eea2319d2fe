"""Diagnosis of a magnetometer-calibration recording (seed 4.6-4.7, paper 3.2).

The twin is the same experiment simulated from the recording's metadata: the manoeuvres of
``meta["manoeuvres"]`` re-run on the MuJoCo gimbal (:class:`imurig.rigs.mag_rig.MagRig`) at the
site and time of the recording, in the IGRF field there, with the DAQ's known channel skew
(slot j of the scan is sampled j / f_mux late). It gives the reference field in the case frame
B_ref (n, 3) [nT] and, from the gimbal's specific force and field (TRIAD), the attitude R_CW
(:mod:`imurig.diagnose.magnetometer_twin`).

Observable: 1-s block means of the indicated field m = V / s_nom [nT] on the three axes,
stacked into one vector (3 n_b,), so that effects that tie the axes together (a symmetric soft
iron, a rotation, a field anomaly fixed in the world) are tested jointly. Twin models:

- ``nominal``:    m_j = g_j B_ref,j                              (a per-axis gain; nothing else)
- ``calibrated``: m_j = sum_k A_jk B_ref,k + b_j                 (the full linear vector calibration:
  gains, soft iron, misalignment and hard iron all fitted)

Candidate effects (each linear in its amplitudes; columns in the stacked space, nT):

- ``hard_iron``: b_j, a constant field of the vehicle/rack magnetised with the sensor [nT];
- ``soft_iron``: symmetric cross-axis coupling, m_j += g_j s_jk B_k and m_k += g_k s_jk B_j
  (induced magnetisation; a symmetric non-orthogonality of the sensor axes looks the same);
- ``misalignment``: a small rotation of the sensor axes against the rig's frame,
  m_j += g_j w_jk B_k, m_k -= g_k w_jk B_j [rad];
- ``local_field_anomaly``: the local field differs from IGRF by dB (fixed in the lab frame W):
  m += A R_CW dB. Only dB's components perpendicular to the IGRF field are tested (u1:
  horizontal, a declination error; u2: in the magnetic meridian, an inclination error); the
  component along the field scales all axes alike and is indistinguishable from the gains;
- ``temperature_drift``: b_j(T) = c_j (T - mean T), T from ``temp_box`` [nT/K] (offered only when
  the temperature moved by more than 0.2 K);
- ``time_drift``: b_j(t) = d_j (t - mean t) [nT/h];
- ``scale_nonlinearity``: m_j += k_j (B_twin,j)^2 [1/nT];
- ``time_delay``: the samples lag the attitude by tau: m_j -= tau dB_twin,j/dt [s].

Selection: :func:`imurig.diagnose.engine.select_effects` (max-statistic threshold simulated over
the whole library, blocked cross-validation, BIC). The noise model comes first: the sample noise
per axis from second differences of the 100 Hz samples (robust, the slow field cancels), white,
which predicts the block-mean noise sigma_s / sqrt(N). What is left after the selection is
checked against that prediction (variance ratio, chi^2) and for whiteness (lag-1 correlation);
a failed check is reported as an unexplained structured residual, with where it sits (per
manoeuvre) and its signature (spectral peak, correlation with heading, time, temperature).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy import signal, stats

from imurig.calibration.thermal import sensor_temperature_K
from imurig.diagnose.engine import select_effects
from imurig.diagnose.magnetometer_twin import AXES, MAG, NT, Twin, build_twin
from imurig.diagnose.steps import effect_steps
from imurig.kernel.errors import ConfigError, RecordingError
from imurig.kernel.recording import Recording
from imurig.sensors.effects import MagView, for_view

TWIN_MODELS = ("nominal", "calibrated")
PAIRS = ((0, 1), (0, 2), (1, 2))


# ---------------------------------------------------------------------------------------------
# the observable


def _block_index(rec: Recording, block_s: float) -> np.ndarray:
    """(n_b, N) sample indices of whole blocks of ``block_s`` inside each contiguous manoeuvre."""
    N = max(1, round(block_s * rec.sample_rate_hz))
    rows = []
    for b in rec.blocks():
        k = (b.stop - b.start) // N
        rows.append(b.start + np.arange(k * N).reshape(k, N))
    return np.concatenate(rows)


def indicated_nT(rec: Recording) -> np.ndarray:
    """m = V / s_nom (n, 3) [nT]: the manufacturer's calibration."""
    rec.require({c: "V" for c in MAG})
    x = rec.stack(MAG)
    if not np.all(np.isfinite(x)):
        raise RecordingError("the magnetometer channels hold NaN/inf samples; drop or repair them first")
    s = np.asarray(rec.meta.get("mag_nominal_sensitivity_V_per_T", [4.0e4] * 3), float)
    return x / s * NT


def sample_noise_nT(m: np.ndarray, rec: Recording) -> np.ndarray:
    """White sample noise per axis (3,) [nT] from second differences inside each block:
    Var(d2) = 6 sigma^2; the median of d2^2 (/ 0.4549, the chi^2_1 median) resists transients."""
    d2 = np.concatenate([np.diff(m[b], 2, axis=0) for b in rec.blocks() if b.stop - b.start > 3])
    return np.sqrt(np.median(d2**2, axis=0) / stats.chi2.ppf(0.5, 1) / 6.0)


def _temperature_K(rec: Recording):
    if "temp_box" not in rec.channels:
        return None
    ts = rec.meta.get("temperature_sensor", {})
    return sensor_temperature_K(rec.channels["temp_box"], ts.get("uA_per_K", 1.0), ts.get("uA_at_298_15K", 298.2),
                                ts.get("load_resistor_ohm", 10e3))


def _heading(m_block: np.ndarray) -> np.ndarray:
    return np.mod(np.degrees(np.arctan2(m_block[:, 1], m_block[:, 0])), 360.0)


@dataclass
class _Blocks:
    """The observable on whole ``block_s`` blocks (nb of N samples, inside each manoeuvre):
    block means of the indicated field mb, of the twin's field Bb, its rate dBb (nb, 3) [nT, nT/s],
    of R_CW Rb (nb, 3, 3), of the time tb [s] and of the temperature Tb [K] (None without
    'temp_box'); the manoeuvre of each block; the sample noise sig_s and the block-mean noise it
    predicts sig_b (3,) [nT]; the stacked observable y (3 nb,) = x blocks, y blocks, z blocks."""

    nb: int
    mb: np.ndarray
    Bb: np.ndarray
    dBb: np.ndarray
    Rb: np.ndarray
    tb: np.ndarray
    Tb: np.ndarray | None
    man_of_block: np.ndarray
    sig_s: np.ndarray
    sig_b: np.ndarray
    y: np.ndarray


def _blocks(rec: Recording, tw: Twin, block_s: float) -> _Blocks:
    """The recording and the twin on whole blocks of ``block_s`` (see :class:`_Blocks`)."""
    m = indicated_nT(rec)
    idx = _block_index(rec, block_s)
    nb, N = idx.shape
    if nb < 30:
        raise RecordingError(f"only {nb} whole {block_s:g}-s blocks: the diagnosis needs at least 30")
    mb, Bb, dBb = m[idx].mean(1), tw.B_ref[idx].mean(1), tw.dB[idx].mean(1)
    Rb = tw.R_CW[idx].mean(1)
    tb = rec.time_s[idx].mean(1)
    man_names = [mm["name"] for mm in rec.meta["manoeuvres"]]
    blocks = rec.blocks()
    man_of_block = np.array([man_names[next(i for i, b in enumerate(blocks) if b.start <= r[0] < b.stop)]
                             if len(man_names) == len(blocks) else "record" for r in idx])
    sig_s = sample_noise_nT(m, rec)
    sig_b = sig_s / math.sqrt(N)
    y = mb.T.reshape(-1)                                   # stacked: x blocks, y blocks, z blocks
    T = _temperature_K(rec)
    Tb = None if T is None else T[idx].mean(1)
    return _Blocks(nb=nb, mb=mb, Bb=Bb, dBb=dBb, Rb=Rb, tb=tb, Tb=Tb, man_of_block=man_of_block, sig_s=sig_s,
                   sig_b=sig_b, y=y)


def _axis_blocks(nb: int):
    """blk(j, col): the column ``col`` (nb,) in axis j's block of the stacked observable (3 nb,)."""
    def blk(j, col):
        out = np.zeros(3 * nb)
        out[j * nb:(j + 1) * nb] = col
        return out
    return blk


# ---------------------------------------------------------------------------------------------
# the diagnosis


def _nominal_design(twin_model: str, Bb: np.ndarray, nb: int, blk) -> tuple[np.ndarray, list]:
    """The twin's nominal model: per-axis gains ('nominal') or the full linear calibration."""
    if twin_model == "nominal":
        X0 = np.column_stack([blk(j, Bb[:, j]) for j in range(3)])
        names0 = [f"g_{a}" for a in AXES]
    else:
        X0 = np.column_stack([blk(j, Bb[:, k]) for j in range(3) for k in range(3)]
                             + [blk(j, np.ones(nb)) for j in range(3)])
        names0 = [f"A_{a}{b}" for a in AXES for b in AXES] + [f"b_{a}_nT" for a in AXES]
    return X0, names0


def diagnose_magnetometer(rec: Recording, rng: np.random.Generator, alpha: float = 0.01, n_sim: int = 300,
                          twin_model: str = "nominal", block_s: float = 1.0) -> dict:
    """Diagnose a magnetometer-calibration recording against the twin ``twin_model`` (module doc)."""
    if twin_model not in TWIN_MODELS:
        raise ConfigError(f"unknown magnetometer twin model '{twin_model}'; choose one of {', '.join(TWIN_MODELS)}")
    tw = build_twin(rec)
    ob = _blocks(rec, tw, block_s)
    y = ob.y
    X0, names0 = _nominal_design(twin_model, ob.Bb, ob.nb, _axis_blocks(ob.nb))
    coef0 = np.linalg.lstsq(X0, y, rcond=None)[0]
    A_fit = np.diag(coef0[:3]) if twin_model == "nominal" else coef0[:9].reshape(3, 3)
    view0 = MagView(twin_model=twin_model, field_nT=ob.Bb, rate_nT_s=ob.dBb, R_CW=ob.Rb, time_s=ob.tb,
                    igrf_W_nT=tw.B_W, calibration=A_fit, temperature_K=ob.Tb)

    def library(A_fit):
        """The candidates of the effect library, linearised about the current calibration A_fit (3, 3)."""
        view = replace(view0, calibration=A_fit)
        return [c for cls in for_view(MagView.kind) for c in cls().candidates(view)]

    # the candidates depend on the calibration (gains): re-linearise about the fit with the
    # effects found until the gains settle (Gauss-Newton on the nonlinear installation model)
    for _ in range(4):
        lib_used = library(A_fit)
        d = select_effects(y, X0, names0, lib_used, rng, alpha=alpha, n_sim=n_sim)
        if not d.findings:
            break
        A_new = (np.diag([d.after.coef(f"g_{a}") for a in AXES]) if twin_model == "nominal" else
                 np.array([[d.after.coef(f"A_{a}{b}") for b in AXES] for a in AXES]))
        done = np.max(np.abs(A_new - A_fit)) < 1e-7
        A_fit = A_new
        if done:
            break
    out = {"twin": f"'{twin_model}' magnetometer model on {block_s:g}-s block means; reference field: the "
                   "manoeuvres re-run on the gimbal in the IGRF field at the site, with the DAQ channel skew",
           "twin_model": twin_model, "igrf_field_W_nT": tw.B_W.tolist(), "blocks": int(ob.nb), "block_s": block_s,
           "noise": {"sample_sigma_nT": ob.sig_s.tolist(), "block_sigma_predicted_nT": ob.sig_b.tolist(),
                     "model": "white (second differences of the samples)"},
           "magnetometer": d.to_dict(), "indistinguishable": _aliases([f.name for f in d.findings], d, ob.Tb, ob.tb)}
    out["magnetometer"]["fit_steps"] = effect_steps(y, X0, names0, lib_used, d)["steps"]
    out.update(_residual_entries(ob, d, alpha))
    return out


def _residual_entries(ob: _Blocks, d, alpha: float) -> dict:
    """The residual before/after per axis and per manoeuvre, its checks against the noise model
    (an unexplained structured residual, if any) and the block series for the report."""
    nb, y, sig_b, man_of_block, mb, tb, Tb = ob.nb, ob.y, ob.sig_b, ob.man_of_block, ob.mb, ob.tb, ob.Tb
    r0 = d.before.residuals_.reshape(3, nb).T
    r1 = d.after.residuals_.reshape(3, nb).T
    fitted1 = (y - d.after.residuals_).reshape(3, nb).T
    out = {}
    out["per_axis"] = {a: {"sigma_before_nT": float(np.std(r0[:, j])), "sigma_after_nT": float(np.std(r1[:, j])),
                           "sigma_predicted_nT": float(sig_b[j])} for j, a in enumerate(AXES)}
    out["locate"] = {mn: {a: {"rms_before_nT": float(np.sqrt(np.mean(r0[man_of_block == mn, j] ** 2))),
                              "rms_after_nT": float(np.sqrt(np.mean(r1[man_of_block == mn, j] ** 2)))}
                          for j, a in enumerate(AXES)} for mn in dict.fromkeys(man_of_block)}
    checks, unexplained = _residual_checks(r1, sig_b, d.after.n - d.after.p, alpha, man_of_block, mb, tb, Tb)
    out["residual_checks"] = checks
    out["unexplained_finding"] = unexplained
    out["series"] = {"time_s": tb.tolist(), "manoeuvre": man_of_block.tolist(), "recording_nT": mb.tolist(),
                     "twin_nT": (mb - r0).tolist(), "corrected_twin_nT": fitted1.tolist()}
    return out


def _aliases(names, d, Tb, tb) -> list:
    notes = [{"effects": ["local_field_anomaly (along the field)", "scale factors"],
              "note": "a local field whose intensity differs from IGRF along the IGRF direction scales the three "
                      "axes alike: the twin's gains absorb it, the data cannot tell it from a scale error"}]
    if Tb is not None and np.ptp(Tb) > 0.2:
        rho = float(np.corrcoef(Tb, tb)[0, 1])
        if abs(rho) > 0.99:
            notes.append({"effects": ["temperature_drift", "time_drift"], "correlation": rho,
                          "note": "the temperature changed almost linearly in time: a drift with temperature "
                                  "and one with time are indistinguishable"})
    if "soft_iron" in names and "misalignment" in names:
        si = next(f for f in d.findings if f.name == "soft_iron")
        s_max = max(abs(v[0]) for v in si.params.values())
        notes.append({"effects": ["misalignment", "soft_iron"],
                      "note": "soft iron on axes of unequal soft-iron scale makes an apparent rotation of up to "
                              f"|s| x (scale difference) / 2 = {s_max * 0.1 / 2:.2g} rad for a 10 % difference; a "
                              "misalignment of that size cannot be told from soft iron with free per-axis gains"})
    return notes


def _residual_checks(r, sig_b, dof, alpha, man, mb, tb, Tb):
    """Variance ratio against the noise model and lag-1 whiteness, per axis (alpha split over the
    six tests); a failure is an unexplained structured residual, located and described."""
    nb = r.shape[0]
    a_each = alpha / 6
    checks, fired = {}, []
    dof_axis = dof / 3
    for j, a in enumerate(AXES):
        ratio = float(np.sum(r[:, j] ** 2) / sig_b[j] ** 2)
        p_var = float(stats.chi2.sf(ratio, dof_axis))
        checks[f"variance_{a}"] = {"kind": "residual variance vs noise model (chi^2)", "threshold_p": a_each,
                                   "variance_ratio": ratio / dof_axis, "p_value": p_var, "finding": p_var < a_each}
        same = man[1:] == man[:-1]
        x0, x1 = r[:-1, j][same], r[1:, j][same]
        rho = float(np.sum(x0 * x1) / np.sqrt(np.sum(x0**2) * np.sum(x1**2)))
        p_w = float(stats.norm.sf(rho * math.sqrt(x0.size)))   # one-sided: structure correlates neighbours
        checks[f"whiteness_{a}"] = {"kind": "residual lag-1 correlation", "threshold_p": a_each, "lag1": rho,
                                    "p_value": p_w, "finding": p_w < a_each}
        if p_var < a_each or p_w < a_each:
            fired.append(j)
    if not fired:
        return checks, None
    where, sig = {}, {}
    head = _heading(mb)
    for j in fired:
        a = AXES[j]
        where[a] = {mn: float(np.sqrt(np.mean(r[man == mn, j] ** 2)) / sig_b[j]) for mn in dict.fromkeys(man)}
        f, p = signal.periodogram(r[:, j] - r[:, j].mean(), fs=1.0 / float(np.median(np.diff(tb))))
        k = int(np.argmax(p[1:]) + 1)
        sig[a] = {"spectral_peak_hz": float(f[k]), "peak_to_median": float(p[k] / np.median(p[1:])),
                  "corr_with_time": float(np.corrcoef(r[:, j], tb)[0, 1]),
                  "corr_with_cos_heading": float(np.corrcoef(r[:, j], np.cos(np.radians(head)))[0, 1]),
                  "corr_with_sin_heading": float(np.corrcoef(r[:, j], np.sin(np.radians(head)))[0, 1])}
        if Tb is not None and np.ptp(Tb) > 0:
            sig[a]["corr_with_temperature"] = float(np.corrcoef(r[:, j], Tb)[0, 1])
    return checks, {"effect": "unexplained_residual",
                    "physics": "a structured residual that no library effect explains (not forced onto a name)",
                    "axes": [AXES[j] for j in fired], "rms_over_noise_by_manoeuvre": where, "signature": sig,
                    "blocks": nb}
