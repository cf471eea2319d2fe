"""Diagnosis of a magnetometer-calibration recording (seed 4.6-4.7, paper 3.2).

The twin is the same experiment simulated from the recording's metadata: the manoeuvres of
``meta["manoeuvres"]`` re-run on the MuJoCo gimbal (:class:`imurig.rigs.mag_rig.MagRig`) at the
site and time of the recording, in the IGRF field there, with the DAQ's known channel skew
(slot j of the scan is sampled j / f_mux late). It gives the reference field in the case frame
B_ref (n, 3) [nT] and, from the gimbal's specific force and field (TRIAD), the attitude R_CW.

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

import copy
import functools
import json
import math
from dataclasses import dataclass, replace

import numpy as np
from scipy import stats

from imurig.diagnose.engine import select_effects
from imurig.kernel import random_streams
from imurig.kernel.errors import ConfigError, RecordingError
from imurig.kernel.recording import Recording
from imurig.kernel.site import Site
from imurig.sensors.effects import ChainContext, LocalFieldAnomaly, MagTimeDelay, MagView, by_name, for_view

AXES = "xyz"
MAG = ("mag_x", "mag_y", "mag_z")
TWIN_MODELS = ("nominal", "calibrated")
PAIRS = ((0, 1), (0, 2), (1, 2))
NT = 1e9


# ---------------------------------------------------------------------------------------------
# forward models used to conceal effects (the suite) -- the same mechanisms the candidates fit


@dataclass(frozen=True)
class AnomalousSite(Site):
    """A site whose local field is IGRF plus a constant anomaly ``anomaly_W_T`` (ENU, tesla),
    e.g. the steel of a building; B_W = B_IGRF + dB."""

    anomaly_W_T: tuple = (0.0, 0.0, 0.0)

    def magnetic_field_W(self, when):
        return LocalFieldAnomaly(self.anomaly_W_T).inject(super().magnetic_field_W(when))


# ---------------------------------------------------------------------------------------------
# the twin


def _manoeuvres(meta: dict) -> list:
    from imurig.rigs import mag_rig

    out = []
    for m in meta.get("manoeuvres", []):
        kw = {k: v for k, v in m.items() if k != "kind"}
        kind = getattr(mag_rig, m.get("kind", ""), None)
        if kind is None:
            raise RecordingError(f"unknown manoeuvre kind {m.get('kind')!r} in the recording's metadata; "
                                 "expected LevelCircle, Tumble or CompassSwing (imurig.rigs.mag_rig)")
        if "headings_deg" in kw:
            kw["headings_deg"] = tuple(kw["headings_deg"])
        if "wobble_deg" in kw:
            kw["wobble_deg"] = 0.0  # the twin follows the commands; a taxi wobble is not a set-point
        out.append(kind(**kw))
    if not out:
        raise RecordingError("the recording's metadata lists no 'manoeuvres': the twin cannot be built "
                             "(a magnetometer recording needs meta['manoeuvres'], see imurig.rigs.mag_rig)")
    return out


def _twin_key(site: dict, start_time: str, rate: float, manoeuvres: list) -> str:
    return json.dumps({"site": Site.from_dict(site).to_dict(), "start_time": start_time, "rate": float(rate),
                       "manoeuvres": manoeuvres}, sort_keys=True, default=list)


@functools.lru_cache(maxsize=2)
def _twin_rig(key: str) -> Recording:
    """The gimbal run of the manoeuvres in ``key`` in the IGRF field (the twin's rig; cached)."""
    from imurig.rigs.mag_rig import MagRig

    d = json.loads(key)
    return MagRig(site=Site.from_dict(d["site"]), record_rate_hz=d["rate"]).simulate(
        _manoeuvres(d), d["start_time"], np.random.default_rng(0))


@functools.lru_cache(maxsize=4)
def _twin_cached(key: str):
    from imurig.kernel.site import parse_time

    d = json.loads(key)
    site = Site.from_dict(d["site"])
    rig = _twin_rig(key)
    B = np.column_stack([rig.truth_signals[f"B_C_{a}"] for a in AXES])
    f = np.column_stack([rig.truth_signals[f"f_C_{a}"] for a in AXES])
    B_W = site.magnetic_field_W(parse_time(d["start_time"]))
    return rig.time_s, B, _triad(f, B, np.array([0.0, 0.0, 1.0]), B_W), B_W


def _triad(v1_C, v2_C, v1_W, v2_W) -> np.ndarray:
    """R_CW (n, 3, 3) from two vectors known in both frames (TRIAD): v_C = R_CW v_W."""
    def basis(a, b):
        t1 = a / np.linalg.norm(a, axis=-1, keepdims=True)
        t2 = np.cross(a, b)
        t2 = t2 / np.linalg.norm(t2, axis=-1, keepdims=True)
        return np.stack([t1, t2, np.cross(t1, t2)], axis=-1)   # columns t1, t2, t3
    Mc = basis(v1_C, v2_C)
    Mw = basis(v1_W[None], v2_W[None])
    return Mc @ np.swapaxes(Mw, -1, -2)


@dataclass
class Twin:
    """The twin on the recording's samples: B_ref (n, 3) [nT] with the DAQ skew, its rate
    dB (n, 3) [nT/s], R_CW (n, 3, 3), the IGRF field B_W (3,) [nT]."""

    B_ref: np.ndarray
    dB: np.ndarray
    R_CW: np.ndarray
    B_W: np.ndarray
    skew_s: np.ndarray


def build_twin(rec: Recording) -> Twin:
    """Re-run the recording's manoeuvres on the gimbal in the IGRF field (see module doc)."""
    meta = rec.meta
    for k in ("site", "start_time", "manoeuvres"):
        if k not in meta:
            raise RecordingError(f"the recording's metadata lacks '{k}': the twin is built from the site, the "
                                 "start time and the manoeuvres (imurig.rigs.mag_rig) of the recording")
    key = _twin_key(meta["site"], meta["start_time"], meta.get("sample_rate_hz", rec.sample_rate_hz),
                    meta["manoeuvres"])
    t, B, R, B_W = _twin_cached(key)
    if t.size != rec.n or np.max(np.abs(t - rec.time_s)) > 0.25 / rec.sample_rate_hz:
        raise RecordingError(f"the recording's time base ({rec.n} samples) does not match its manoeuvres' "
                             f"schedule ({t.size} samples): the twin is built from meta['manoeuvres'] and "
                             "expects the rig's own time stamps")
    B = B * NT
    dB = np.gradient(B, t, axis=0)
    adc = meta.get("adc", {})
    skew = np.zeros(3)
    if adc.get("skew_enabled") and adc.get("mux_frequency_hz"):
        scan = list(adc.get("scan_list", []))
        skew = np.array([scan.index(c) / adc["mux_frequency_hz"] if c in scan else 0.0 for c in MAG])
    return Twin(B + dB * skew, dB, R, B_W * NT, skew)


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
    from imurig.calibration.thermal import sensor_temperature_K

    ts = rec.meta.get("temperature_sensor", {})
    return sensor_temperature_K(rec.channels["temp_box"], ts.get("uA_per_K", 1.0), ts.get("uA_at_298_15K", 298.2),
                                ts.get("load_resistor_ohm", 10e3))


def _heading(m_block: np.ndarray) -> np.ndarray:
    return np.mod(np.degrees(np.arctan2(m_block[:, 1], m_block[:, 0])), 360.0)


# ---------------------------------------------------------------------------------------------
# the diagnosis


def diagnose_magnetometer(rec: Recording, rng: np.random.Generator, alpha: float = 0.01, n_sim: int = 300,
                          twin_model: str = "nominal", block_s: float = 1.0) -> dict:
    """Diagnose a magnetometer-calibration recording against the twin ``twin_model`` (module doc)."""
    if twin_model not in TWIN_MODELS:
        raise ConfigError(f"unknown magnetometer twin model '{twin_model}'; choose one of {', '.join(TWIN_MODELS)}")
    tw = build_twin(rec)
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

    def blk(j, col):
        out = np.zeros(3 * nb)
        out[j * nb:(j + 1) * nb] = col
        return out

    # --- the twin's nominal model ---------------------------------------------------------
    if twin_model == "nominal":
        X0 = np.column_stack([blk(j, Bb[:, j]) for j in range(3)])
        names0 = [f"g_{a}" for a in AXES]
    else:
        X0 = np.column_stack([blk(j, Bb[:, k]) for j in range(3) for k in range(3)]
                             + [blk(j, np.ones(nb)) for j in range(3)])
        names0 = [f"A_{a}{b}" for a in AXES for b in AXES] + [f"b_{a}_nT" for a in AXES]
    coef0 = np.linalg.lstsq(X0, y, rcond=None)[0]
    A_fit = np.diag(coef0[:3]) if twin_model == "nominal" else coef0[:9].reshape(3, 3)
    T = _temperature_K(rec)
    Tb = None if T is None else T[idx].mean(1)

    view0 = MagView(twin_model=twin_model, field_nT=Bb, rate_nT_s=dBb, R_CW=Rb, time_s=tb, igrf_W_nT=tw.B_W,
                    calibration=A_fit, temperature_K=Tb)

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
    names = [f.name for f in d.findings]
    r0 = d.before.residuals_.reshape(3, nb).T
    r1 = d.after.residuals_.reshape(3, nb).T
    fitted1 = (y - d.after.residuals_).reshape(3, nb).T
    out = {"twin": f"'{twin_model}' magnetometer model on {block_s:g}-s block means; reference field: the "
                   "manoeuvres re-run on the gimbal in the IGRF field at the site, with the DAQ channel skew",
           "twin_model": twin_model, "igrf_field_W_nT": tw.B_W.tolist(), "blocks": int(nb), "block_s": block_s,
           "noise": {"sample_sigma_nT": sig_s.tolist(), "block_sigma_predicted_nT": sig_b.tolist(),
                     "model": "white (second differences of the samples)"},
           "magnetometer": d.to_dict(), "indistinguishable": _aliases(names, d, Tb, tb)}
    from imurig.reports.diagnosis import effect_steps

    out["magnetometer"]["fit_steps"] = effect_steps(y, X0, names0, lib_used, d)["steps"]
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
    from scipy import signal

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


# ---------------------------------------------------------------------------------------------
# the report (report.md, diagnosis.json, figure, .rrd)


SEED_SAYS = {
    "hard_iron": "4.6, eq. 4.45-4.47: hard iron shifts the circle's centre",
    "soft_iron": "4.6, eq. 4.48-4.51: soft iron and scale factors stretch the circle into an ellipse",
    "misalignment": "4.6, Fig. 4.24: misalignment / soft iron rotate the ellipse's axes",
    "local_field_anomaly": "4.7 / paper 4.3: the calibration assumes the IGRF field at the site",
    "temperature_drift": "4.5: temperature changes bias and scale",
}


def findings_rows(d: dict) -> list[list]:
    """Report rows: observable, effect, physics, fitted/evidence, what the seed says."""
    rows = []
    for f in d["magnetometer"]["findings"]:
        ps = "; ".join(f"{p['name']} = {p['estimate']:.4g} ± {p['std_error']:.2g}" for p in f["parameters"])
        alias = f"; indistinguishable from {f['indistinguishable_from']}" if f.get("indistinguishable_from") else ""
        ev = (f"{ps}; F = {f['statistic']:.1f} > {f['threshold']:.1f}; share {f['variance_share'] * 100:.0f} % "
              f"of the residual{alias}")
        rows.append(["mag x, y, z block means (joint)", f["effect"], f["physics"], ev, SEED_SAYS.get(f["effect"], "–")])
    u = d.get("unexplained_finding")
    if u:
        ev = "; ".join(f"{a}: rms/noise " + ", ".join(f"{k} {v:.2f}" for k, v in w.items())
                       for a, w in u["rms_over_noise_by_manoeuvre"].items())
        rows.append(["mag residual after the fit", u["effect"], u["physics"], ev, "–"])
    return rows


def _figure(out, d: dict) -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = d["series"]
    t = np.asarray(s["time_s"])
    rec_, tw, cor = (np.asarray(s[k]) for k in ("recording_nT", "twin_nT", "corrected_twin_nT"))
    fig, axs = plt.subplots(3, 2, figsize=(11, 8), sharex=True)
    for j, a in enumerate(AXES):
        axs[j, 0].plot(t, rec_[:, j] - tw[:, j], ".", ms=2)
        axs[j, 0].set(ylabel=f"mag_{a} residual, nT")
        axs[j, 1].plot(t, rec_[:, j] - cor[:, j], ".", ms=2, color="C1")
        sb = d["noise"]["block_sigma_predicted_nT"][j]
        axs[j, 1].axhspan(-2 * sb, 2 * sb, color="0.85", zorder=0, label="±2σ noise model")
        axs[j, 0].grid(alpha=0.3)
        axs[j, 1].grid(alpha=0.3)
    axs[0, 0].set_title("recording − nominal twin")
    axs[0, 1].set_title("recording − corrected twin (effects found)")
    axs[0, 1].legend(fontsize=7)
    axs[2, 0].set_xlabel("time, s")
    axs[2, 1].set_xlabel("time, s")
    fig.tight_layout()
    fig.savefig(out.file("fig_diagnosis.png"), dpi=110)
    plt.close(fig)
    return "fig_diagnosis.png"


def _rrd(path, d: dict):
    from imurig.reports.viz import RrdWriter, log_scalars, log_text

    s = d["series"]
    t = np.asarray(s["time_s"])
    with RrdWriter(path, recording_name="diagnosis", overwrite=True) as w:
        for key, name in (("recording_nT", "recording"), ("twin_nT", "twin"), ("corrected_twin_nT", "corrected_twin")):
            v = np.asarray(s[key])
            log_scalars(w, f"signals/mag/{name}", t, {f"mag_{a}": v[:, j] for j, a in enumerate(AXES)},
                        {f"mag_{a}": "nT" for a in AXES})
        log_text(w, "summary", "# Diagnosis\n\n" + "\n".join(f"- **{r[1]}**: {r[2]}" for r in findings_rows(d)))


def run(rec: Recording, out_dir, overwrite: bool = False, seed: int = 0, twin_model: str = "nominal") -> dict:
    """Diagnose ``rec`` and write report.md, diagnosis.json, fig_diagnosis.png, diagnosis.rrd."""
    from imurig.reports.diagnosis import fit_tables
    from imurig.reports.common import OutputFolder, clean_json, md_table

    d = {"kind": "magnetometer", **diagnose_magnetometer(rec, np.random.default_rng(seed), twin_model=twin_model)}
    with OutputFolder(out_dir, overwrite=overwrite) as out:
        fig = _figure(out, d)
        _rrd(out.file("diagnosis.rrd"), d)
        rows = findings_rows(d)
        e = d["magnetometer"]
        md = ["# Diagnosis: where the magnetometer recording and its twin differ\n",
              f"Recording: {rec.meta.get('source', rec.meta.get('rig', '–'))}. Twin: {d['twin']}.\n",
              "" if rows else "No effect passed the thresholds: the recording agrees with its twin.\n",
              "## Findings, beside what the seed says\n",
              md_table(["observable", "effect", "physics left out", "fitted / evidence", "seed"], rows) if rows else "",
              "\n## Indistinguishable\n",
              "\n".join(f"- {' / '.join(n['effects'])}: {n['note']}" for n in d["indistinguishable"]),
              "\n## Fit before and after (1-s block means)\n",
              md_table(["axis", "σ before, nT", "σ after, nT", "σ noise model, nT"],
                       [[a, v["sigma_before_nT"], v["sigma_after_nT"], v["sigma_predicted_nT"]]
                        for a, v in d["per_axis"].items()]),
              (f"\nJoint: R²adj {e['fit_before']['r2_adj']:.6f} → {e['fit_after']['r2_adj']:.6f}, BIC "
               f"{e['fit_before']['bic']:.1f} → {e['fit_after']['bic']:.1f}.\n"),
              *fit_tables(d),
              "\n## Where: residual RMS per manoeuvre (nT, before → after)\n",
              md_table(["manoeuvre"] + [f"mag_{a}" for a in AXES],
                       [[mn] + [f"{v[a]['rms_before_nT']:.3g} → {v[a]['rms_after_nT']:.3g}" for a in AXES]
                        for mn, v in d["locate"].items()]),
              ("\nAn effect is accepted only when its statistic beats the max-statistic threshold simulated under "
               "the noise model over the whole library, it improves blocked cross-validation and lowers BIC. "
               "The residual left is then checked against the noise model (variance, whiteness); a failure is "
               "reported as an unexplained structured residual.\n"),
              f"\n![diagnosis]({fig})\n"]
        out.write_text("report.md", "\n".join(md))
        out.write_json("diagnosis.json", clean_json(d))
    return d


# ---------------------------------------------------------------------------------------------
# recordings with concealed effects (the suite)


@functools.lru_cache(maxsize=8)
def _rig_run(anomaly_W_T):
    """The campaign's manoeuvres on the gimbal (deterministic without a taxi wobble: cached)."""
    from imurig.campaigns.magnetometer import MagnetometerCampaign
    from imurig.rigs.mag_rig import MagRig

    camp = MagnetometerCampaign()
    plan = [camp.circle, camp.tumble, camp.swing, camp.validation]
    if anomaly_W_T is None:  # the IGRF field: the same gimbal run as the twin's
        from dataclasses import asdict

        from imurig.kernel.site import parse_time

        rig = MagRig(site=camp.site)
        return _twin_rig(_twin_key(camp.site.to_dict(), parse_time(camp.start_time).isoformat(), rig.record_rate_hz,
                                   [dict(asdict(m), kind=type(m).__name__) for m in plan]))
    site = AnomalousSite(**camp.site.to_dict(), anomaly_W_T=anomaly_W_T)
    return MagRig(site=site).simulate(plan, camp.start_time, np.random.default_rng(0))


def magnetometer_recording(seed: int, magnetometer=None, anomaly_W_T=None, tempco_T_per_K=None,
                           air_warming_K: float = 0.0, air_tau_s: float = 600.0, delay_s: float = 0.0):
    """The magnetometer campaign (:class:`imurig.campaigns.magnetometer.MagnetometerCampaign`) with
    its fluxgate replaced by ``magnetometer`` (None: the campaign's drawn installation), a local
    field anomaly ``anomaly_W_T`` (ENU, T) in the lab, and a fluxgate offset tempco
    ``tempco_T_per_K`` (3,) [T/K] (the fluxgate's own, injected by the chain at the box
    temperature) while the lab air warms by ``air_warming_K`` (1 - exp(-t/tau)), and a delay
    ``delay_s`` of the sensor's output (e.g. its output filter): V(t) = V_ideal(t - tau).
    The metadata carry the IGRF field (what a lab writes down); the truth carries the anomaly
    and the IGRF field it was added to."""
    from imurig.campaigns.magnetometer import MAG as MAGC
    from imurig.campaigns.magnetometer import MagnetometerCampaign
    from imurig.sensors.adc import DAQ6036E
    from imurig.sensors.chain import ImuLab
    from imurig.sensors.disturbances import PeopleTransients, PumpVibration
    from imurig.sensors.magnetometer import FluxgateTriad
    from imurig.kernel.site import parse_time

    camp = MagnetometerCampaign(seed=seed)
    mag = FluxgateTriad.from_datasheet(random_streams.generator("magnetometer_install", seed),
                                       hard_iron_max_nT=camp.hard_iron_max_nT,
                                       soft_iron_max=camp.soft_iron_max, noise_nT_rms=camp.noise_nT)
    if magnetometer is not None:
        mag = magnetometer(mag) if callable(magnetometer) else magnetometer
    if tempco_T_per_K is not None:
        mag = replace(mag, tempco_T_per_K=np.asarray(tempco_T_per_K, float))
    lab = replace(ImuLab(), magnetometer=mag, pump=PumpVibration(enabled=False), people=PeopleTransients(enabled=False),
                  adc=DAQ6036E(scan_list=MAGC + ("temp_box",), sample_rate_hz=100.0, averaging=10))
    if any(getattr(m, "wobble_deg", 0.0) for m in (camp.circle, camp.validation)):
        raise ConfigError("magnetometer_recording caches the rig run and needs wobble-free circles")
    rig = copy.deepcopy(_rig_run(None if anomaly_W_T is None else tuple(map(float, anomaly_W_T))))
    if air_warming_K:
        t = rig.time_s
        rig.truth_signals["T_air"] = 273.15 + lab.climate.temperature_C + air_warming_K * (1 - np.exp(-(t - t[0]) / air_tau_s))
        rig.truth_units["T_air"] = "K"
    truth_extra = {}
    B_true = {c: rig.truth_signals[f"B_C_{c}"].copy() for c in AXES}
    if delay_s:
        delay = MagTimeDelay(delay_s)
        for c in AXES:
            x = rig.truth_signals[f"B_C_{c}"]
            for b in rig.blocks():  # the field the sensor puts out at t is the field at t - tau
                x[b] = delay.inject(x[b], ChainContext(time_s=rig.time_s[b], sample_rate_hz=rig.sample_rate_hz))
        truth_extra["delay_s"] = float(delay_s)
    rec = lab.measure(rig, random_streams.seed_sequence("campaign/magnetometer/sensor-chain", seed))
    for c in AXES:
        rec.truth_signals[f"B_C_{c}"] = B_true[c]
    site_igrf = Site.from_dict(camp.site.to_dict())
    B_W = site_igrf.magnetic_field_W(parse_time(camp.start_time))
    truth_extra["igrf_field_W_T"] = B_W.tolist()
    rec.meta["site"] = site_igrf.to_dict()
    rec.meta["igrf_field_W_T"] = B_W.tolist()
    rec.meta["igrf_horizontal_T"] = float(math.hypot(B_W[0], B_W[1]))
    rec.meta["igrf_total_T"] = float(np.linalg.norm(B_W))
    rec.meta["campaign"] = {"name": "magnetometer", **camp.to_dict()}
    rec.meta["mag_nominal_sensitivity_V_per_T"] = [4.0e4] * 3
    rec.truth["magnetometer_diagnosis"] = {"anomaly_W_T": None if anomaly_W_T is None else list(map(float, anomaly_W_T)),
                                           **truth_extra}
    return rec


# ---------------------------------------------------------------------------------------------
# the concealed-effect cases (used by imurig.concealed.suite)

#: off-diagonal patterns (xy, xz, yz) of the injected soft iron and rotation, and the hard iron's direction
PAIR_PATTERN = np.array([1.0, -0.6, 0.4])
HARD_IRON_PATTERN = np.array([1.0, -0.6, 0.4])
ANOMALY_DIRECTION_W = np.array([0.5, -0.4, 0.77]) / np.linalg.norm([0.5, -0.4, 0.77])
TEMPCO_PATTERN = np.array([1.0, -0.6, 0.8])
AIR_WARMING_K = 3.0


def _ideal(mag, hard=None, soft=None, rot=None):
    """The drawn fluxgate (its gains kept) with only the given installation errors."""
    S, M = np.eye(3), np.zeros((3, 3))
    for (j, k), v in zip(PAIRS, PAIR_PATTERN):
        if soft is not None:
            S[j, k] = S[k, j] = soft * v
        if rot is not None:
            M[j, k], M[k, j] = rot * v, -rot * v
    return replace(mag, hard_iron_T=np.zeros(3) if hard is None else hard * 1e-9 * HARD_IRON_PATTERN,
                   soft_iron=S, misalignment_rad=M)


def case_recording(effect: str, seed: int, size: float) -> Recording:
    """A recording with ``effect`` at ``size`` concealed (units: hard_iron nT, soft_iron 1,
    misalignment rad, local_field_anomaly nT, temperature_drift nT/K, time_delay s)."""
    if effect == "hard_iron":
        return magnetometer_recording(seed, lambda m: _ideal(m, hard=size))
    if effect == "soft_iron":
        return magnetometer_recording(seed, lambda m: _ideal(m, soft=size))
    if effect == "misalignment":
        return magnetometer_recording(seed, lambda m: _ideal(m, rot=size))
    if effect == "local_field_anomaly":
        return magnetometer_recording(seed, anomaly_W_T=ANOMALY_DIRECTION_W * size * 1e-9)
    if effect == "temperature_drift":
        return magnetometer_recording(seed, tempco_T_per_K=TEMPCO_PATTERN * size * 1e-9, air_warming_K=AIR_WARMING_K)
    if effect == "time_delay":
        return magnetometer_recording(seed, _ideal, delay_s=size)
    if effect == "installation":
        return magnetometer_recording(seed)
    raise ConfigError(f"no magnetometer case '{effect}'")


def null_recording(seed: int, twin_model: str) -> Recording:
    """Nothing omitted from the twin: an ideal installation (gains only) for the nominal twin,
    the drawn installation (hard and soft iron, misalignment) in the IGRF field for the calibrated one."""
    return magnetometer_recording(seed, _ideal if twin_model == "nominal" else None)


#: the effect of the library behind each magnetometer case ("installation": its hard iron)
CASE_EFFECT = {"hard_iron": "hard_iron", "installation": "hard_iron", "soft_iron": "soft_iron",
               "misalignment": "mag_misalignment", "local_field_anomaly": "local_field_anomaly",
               "temperature_drift": "mag_temperature_drift", "time_delay": "mag_time_delay"}


def truth_param(effect: str, rec: Recording) -> float:
    """The injected value of the first parameter the diagnosis reports for ``effect``: the
    effect's own truth map (:meth:`imurig.sensors.effects.base.Effect.fitted`) on the recording."""
    if effect not in CASE_EFFECT:
        raise ConfigError(f"no magnetometer case '{effect}'")
    return next(iter(by_name(CASE_EFFECT[effect])().fitted(rec.truth, "mag").values()))


def found_param(effect: str, d: dict):
    """(estimate, std_error) of the first parameter of ``effect`` in a diagnosis, or None."""
    name = "hard_iron" if effect == "installation" else effect
    for f in d["magnetometer"]["findings"]:
        if f["effect"] == name:
            return f["parameters"][0]["estimate"], f["parameters"][0]["std_error"]
    return None


def found_effects(d: dict) -> set:
    """(channel, effect) pairs of a magnetometer diagnosis (channel 'mag': the joint analysis)."""
    out = {("mag", f["effect"]) for f in d["magnetometer"]["findings"]}
    if d.get("unexplained_finding"):
        out.add(("mag", "unexplained_residual"))
    return out
