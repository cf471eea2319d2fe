"""Run the tilt-table campaign and write its report folder.

Folder contents: ``report.md`` (seed-style tables and figures), ``summary.json`` (every
estimated parameter as {name, unit, injected, estimate, std_error, z}), ``recording.h5``
(the 1 kHz recording with truth), ``campaign.rrd`` (rerun), and PNG figures.

:func:`run` streams the campaign (:mod:`imurig.campaigns.tilt_stream`): the 1 kHz record goes to
``recording.h5`` piece by piece while its windows are low-passed for the analysis, so no array of the
record's length is held; the figures and the .rrd are made in two forked processes
(:class:`imurig.reports.beside.Beside`), started before the fits: they load matplotlib and rerun while
the fits run, then draw and write beside each other.
"""
from __future__ import annotations

import resource
import sys
import time
from types import SimpleNamespace

import numpy as np

import imurig
from imurig.calibration.accelerometer import ACC, AXES, AccelerometerCalibration
from imurig.calibration.preprocess import lowpass_downsample, reuse_statistics
from imurig.campaigns.tilt_stream import ANALYSED, stream_campaign
from imurig.campaigns.tilt_table import (Z_BOUND, TiltTableCampaign, calibrate, coefficient_table,
                                         compare_with_truth, tilt_table_reference)
from imurig.kernel.errors import UnidentifiableTermsError
from imurig.kernel.progress import StageBar
from imurig.kernel.recording import Recording
from imurig.kernel.outputs import OutputFolder, clean_json
from imurig.reports.beside import Beside
from imurig.reports.common import md_figures_and_run, md_table, published_figures

def peak_rss_bytes() -> int:
    """Peak resident memory of this process so far (bytes)."""
    r = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return int(r if sys.platform == "darwin" else r * 1024)


SEED_MODELS = ("linear", "cross", "seed_final")
#: how the report names a per-position statistic
STATISTIC_WORDS = {"huber": "Huber M-estimates (k = 1.345, 95 % Gaussian efficiency)", "median": "medians",
                   "mean": "means"}
SEED_TABLE = {"linear": "4.4", "cross": "4.5", "seed_final": "4.6"}


def analyse(rec: Recording, model: str = "physical", statistic: str = "huber",
            processed: Recording | None = None, on_main=None) -> dict:
    """All fits the report shows, on one recording (simulated or measured): the main model and the
    stepwise selections on the per-position ``statistic`` (huber, median or mean), the seed's
    models (Tables 4.4-4.6) on the seed's per-position medians. ``processed``: the low-passed 100 Hz
    record when already made (e.g. by the streamed campaign), else made here from ``rec``.
    ``on_main``: called with ``{"main", "parameters"}`` as soon as the main fit is made, before the others
    (the figures and the .rrd need no more: their processes draw while the other fits run)."""
    # only the windows are analysed (bounded memory)
    rec100 = processed if processed is not None else lowpass_downsample(rec, windows_only=True, filtered=ANALYSED)
    with reuse_statistics():   # the fits share their per-position statistics: each computed once
        return _analyse(rec, rec100, model, statistic, on_main)


def _analyse(rec: Recording, rec100: Recording, model: str, statistic: str, on_main=None) -> dict:
    out = {"rec100": rec100}
    out["main"] = calibrate(rec, model=model, processed=rec100, statistic=statistic)
    out["parameters"] = compare_with_truth(out["main"], rec.truth)
    if on_main is not None:
        on_main({"main": out["main"], "parameters": out["parameters"]})
    out["coefficients"] = coefficient_table(out["main"], rec100)
    out["stepwise"] = calibrate(rec, model="stepwise", processed=rec100, statistic=statistic)
    out["backward"] = calibrate(rec, model="backward", processed=rec100, statistic=statistic)
    out["seed_models"] = {}
    for m in SEED_MODELS:
        try:
            out["seed_models"][m] = calibrate(rec, model=m, processed=rec100, statistic="median")
        except UnidentifiableTermsError as e:
            out["seed_models"][m] = e
    out["raw"] = calibrate(rec, model="linear", statistic="raw", processed=rec100)
    out["median_linear"] = out["seed_models"]["linear"]
    return out


def _stats_rows(cal: AccelerometerCalibration):
    rows = []
    for key, label in (("sigma_res", "σ_res (m/s²)"), ("ms_res", "MS_res (m²/s⁴)"), ("R", "R"),
                       ("R_adj", "R_adj"), ("condition_number", "condition number")):
        rows.append([label] + [getattr(cal.results_[a], key) for a in AXES])
    return rows


def _coef_table(cal: AccelerometerCalibration) -> str:
    names = []
    for a in AXES:
        for n in cal.results_[a].names:
            if n not in names:
                names.append(n)
    rows = []
    for i, n in enumerate(names):
        row = [f"β{i} ({n})"]
        for a in AXES:
            r = cal.results_[a]
            row.append(f"{r.coef(n):.8f} ± {r.std_error(n):.1e}" if n in r.names else "–")
        rows.append(row)
    return md_table(["term", "A_x", "A_y", "A_z"], rows + _stats_rows(cal))


def make_figures(out: OutputFolder, rec: Recording, res: dict) -> dict:
    """The report's figures of the fits ``res`` (:func:`analyse`, its ``rec100``): name -> file."""
    return fit_figures(out, res["rec100"], res, record_figures(out, res["rec100"]))


def _pyplot():
    import matplotlib  # heavy: loaded when figures are drawn, not when the CLI starts

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def record_figures(out: OutputFolder, rec100: Recording) -> dict:
    """The figures of the 100 Hz record alone (no fits): Fig. 4.10 (raw channels) and 4.9 (the reference)."""
    plt = _pyplot()
    figs = {}
    seg = rec100.segments
    # Fig 4.10: raw channels at theta = 40 deg (or the tilt nearest to it), last run
    last = seg["run"] == seg["run"].max() if "run" in seg else np.ones(rec100.n_segments, bool)
    th_near = seg["theta"][last][np.argmin(np.abs(seg["theta"][last] - np.radians(40)))]
    theta40 = np.flatnonzero(np.isclose(seg["theta"], th_near) & last)
    if theta40.size:
        sl = rec100.segment_slices()
        fig, ax = plt.subplots(figsize=(8, 4))
        for c, col in zip(ACC, ("C0", "C3", "C2")):
            y = np.concatenate([rec100.channels[c][sl[i]] for i in theta40])
            ax.plot(y, col, lw=0.6, label=c)
        ax.set(xlabel=f"samples (100 Hz, {theta40.size} phi positions)", ylabel="volts",
               title=f"Raw accelerometer outputs at θ = {np.degrees(th_near):.0f}° (cf. seed Fig. 4.10)")
        ax.legend()
        ax.grid(alpha=0.3)
        # fixed margins (tight_layout's for this figure): its search measures every tick label again
        fig.subplots_adjust(left=0.1, right=0.98, bottom=0.145, top=0.905)
        fig.savefig(out.file("fig_4_10_raw_theta40.png"), dpi=110)
        plt.close(fig)
        figs["raw_theta40"] = "fig_4_10_raw_theta40.png"
    # Reference data (Fig 4.9)
    ref, _, _ = tilt_table_reference(rec100)
    fig, ax = plt.subplots(figsize=(8, 3.5))
    for j, a in enumerate(AXES):
        ax.plot(ref[:, j], ".-", ms=3, lw=0.6, label=f"f_{a}")
    ax.set(xlabel="position", ylabel="m/s²", title="Reference specific force per position (cf. seed Fig. 4.9)")
    ax.legend()
    ax.grid(alpha=0.3)
    # fixed margins (tight_layout's for this figure): its search measures every tick label again
    fig.subplots_adjust(left=0.11, right=0.97, bottom=0.165, top=0.895)
    fig.savefig(out.file("fig_4_9_reference.png"), dpi=110)
    plt.close(fig)
    figs["reference"] = "fig_4_9_reference.png"
    return figs


def fit_figures(out: OutputFolder, rec100: Recording, res: dict, figs: dict) -> dict:
    """The figures of the fits ``res`` (Fig. 4.14, the z-scores) beside those of the record ``figs``
    (:func:`record_figures`), in the report's order: name -> file."""
    plt = _pyplot()
    # Fig 4.14: residuals of the final model per position, beside the seed's sigma
    pub = published_figures()
    cal = res["main"]
    # left: on the seed's scale (+-0.015 m/s^2) beside its sigma; right: on imurig's own scale, where
    # the structure of its (smaller) residuals shows
    fig, grid = plt.subplots(3, 2, figsize=(11, 7), sharex=True)
    for j, a in enumerate(AXES):
        r = cal.results_[a].residuals_
        s = pub["table_4_6"]["sigma_res"][j]
        for k, ax in enumerate(grid[j]):
            ax.plot(r, ".-", ms=3, lw=0.5, label=f"imurig ({cal.model}), σ = {np.std(r, ddof=1):.2e}")
            if k == 0:
                ax.axhspan(-s, s, color="orange", alpha=0.2, label=f"seed Table 4.6 ±σ_res = {s:.2e}")
                ax.set_ylim(-0.015, 0.015)
                ax.set_ylabel(f"{a.upper()} error, m/s²")
            else:
                lim = 1.2 * float(np.max(np.abs(r))) if r.size and np.max(np.abs(r)) > 0 else 1.0
                ax.set_ylim(-lim, lim)
            ax.grid(alpha=0.3)
            ax.legend(loc="upper right", fontsize=7)
    for ax in grid[-1]:
        ax.set_xlabel("position")
    grid[0, 0].set_title("On the seed's scale (cf. seed Fig. 4.14)")
    grid[0, 1].set_title("On imurig's own scale")
    # fixed margins (those tight_layout finds for this figure, with room for 8-character tick labels): its
    # search measures every tick label, a third of this figure's drawing time, after the fits
    fig.subplots_adjust(left=0.075, right=0.98, bottom=0.085, top=0.95, wspace=0.25, hspace=0.1)
    fig.savefig(out.file("fig_4_14_residuals.png"), dpi=110)
    plt.close(fig)
    figs["residuals"] = "fig_4_14_residuals.png"
    # z-scores of recovered parameters
    params = [p for p in res["parameters"] if p.get("z") is not None]
    if params:
        fig, ax = plt.subplots(figsize=(8, 3.8))
        z = [p["z"] for p in params]
        ax.bar(range(len(z)), z, color=["C0" if abs(v) <= Z_BOUND else "C3" for v in z], label="z of each parameter")
        ax.axhline(Z_BOUND, color="k", ls="--", lw=0.8, label=f"+{Z_BOUND:g} bound")
        ax.axhline(-Z_BOUND, color="k", ls="--", lw=0.8, label=f"−{Z_BOUND:g} bound")
        ax.legend(fontsize=7, loc="upper right")
        ax.set_xticks(range(len(z)), [p["name"] for p in params], rotation=60, ha="right", fontsize=7)
        ax.set_ylabel("(estimate − injected) / std. error")
        ax.set_title(f"Recovered vs injected parameters (bound ±{Z_BOUND:g}σ)")
        fig.tight_layout()
        fig.savefig(out.file("fig_truth_z.png"), dpi=110)
        plt.close(fig)
        figs["truth_z"] = "fig_truth_z.png"
    order = ("raw_theta40", "residuals", "reference", "truth_z")
    return {k: figs[k] for k in order if k in figs}


def _report_md(camp, rec: Recording, res: dict, figs: dict, timing: dict) -> str:
    pub = published_figures()
    cal = res["main"]
    L = [f"# Tilt-table accelerometer calibration — imurig {imurig.__version__}\n"]
    p = camp.protocol if camp else None
    if p:
        L.append(f"Protocol: θ = {list(p.theta_deg)} deg, φ = {list(p.phi_deg)} deg, runs {list(p.runs)}, "
                 f"{p.dwell_s:g} s per position at {p.sample_rate_hz:g} Hz "
                 f"({rec.n_segments} positions, {rec.n:,} samples). Seed {camp.seed}, start {camp.start_time}. "
                 f"ADC: {camp.grounding}, f_mux = {camp.mux_frequency_hz / 1e3:g} kHz.\n")
    L.append("## Recovered vs injected (forward-model parameters)\n")
    L.append(f"Model `{cal.model}` fitted on per-position {STATISTIC_WORDS.get(cal.statistic, cal.statistic)} of "
             "the 100 Hz data. z = (estimate − injected)"
             f" / std. error; std. errors include the table survey's uncertainty. Bound |z| ≤ {Z_BOUND:g}.\n")
    rows = [[q["name"], q["unit"], q["injected"], q["estimate"], q["std_error"], q["z"], q["within_bound"]]
            for q in res["parameters"]]
    L.append(md_table(["parameter", "unit", "injected", "estimate", "std. error", "z", "within bound"], rows))
    if "truth_z" in figs:
        L.append(f"\n![z-scores]({figs['truth_z']})\n")
    if any(c["injected"] is not None for c in res["coefficients"]):
        L.append("\nInverse-model coefficients against the noise-free twin (the same model fitted to the true "
                 "sensor's output at the true specific force of each position):\n")
        L.append(md_table(["coefficient", "unit", "noise-free twin", "estimate", "std. error", "z"],
                          [[c["name"], c["unit"], c["injected"], c["estimate"], c["std_error"], c["z"]]
                           for c in res["coefficients"]]))
    L.append("\n## Model statistics next to the seed (Tables 4.4-4.6)\n")
    t46 = pub["table_4_6"]
    L.append(md_table(["", "imurig A_x", "A_y", "A_z", "seed A_x", "A_y", "A_z"], [
        ["σ_res (m/s²)"] + [cal.results_[a].sigma_res for a in AXES] + t46["sigma_res"],
        ["R"] + [cal.results_[a].R for a in AXES] + t46["r"],
        ["R_adj"] + [cal.results_[a].R_adj for a in AXES] + t46["r_adj"],
        ["scale (own axis β)"] + [cal.results_[a].coef(f"a{a}") for a in AXES] + t46["scale_factor"],
    ]))
    L.append("\nThe seed's MS_res (e.g. 0.00125 for A_x) is not σ_res²: its MATLAB code (appendix C.1.1) forms "
             "SS_res from raw volts minus calibrated values. Here MS_res = SS_res/(n−p) of the residuals.\n")
    for m, c in res["seed_models"].items():
        L.append(f"\n### Seed Table {SEED_TABLE[m]} model (`{m}`)\n")
        if isinstance(c, Exception):
            L.append(f"Not identifiable on this schedule: {c}\n")
            continue
        L.append(_coef_table(c))
        if m == "seed_final":
            L.append("\nOn a ±1 g tilt table |f| = g at every position, so 1, a_x², a_y², a_z² are nearly "
                     "collinear (exactly so without noise): see the condition number. This is why the seed's "
                     "A_y model shows β0 = 0.412 with compensating square terms.\n")
    L.append(f"\n### Main model (`{cal.model}`)\n")
    L.append(_coef_table(cal))
    st = res["stepwise"]
    bw = res["backward"]
    L.append("\n### Stepwise selection (BIC, degree-2 library, linear terms always kept)\n")
    L.append(md_table(["axis", "method", "selected terms", "σ_res", "R_adj", "BIC"],
                      [[a, meth, ", ".join(c.results_[a].names), c.results_[a].sigma_res, c.results_[a].R_adj,
                        c.results_[a].bic] for a in AXES for meth, c in (("forward", st), ("backward", bw))]))
    left = sorted({f"{h['term']}: {h['reason']}" for c in (st, bw) for sel in c.selection_.values()
                   for h in sel.history if h["action"] in ("skip", "stop")})
    if left:
        L.append("\nLeft out of the selection, and why:\n\n" + "\n".join(f"- {x}" for x in left) + "\n")
    L.append("\n## Medians vs raw samples (cf. seed Table 4.2)\n")
    raw, med = res["raw"], res["median_linear"]
    t42 = pub["table_4_2"]
    L.append(md_table(["axis", "σ raw 100 Hz samples", "σ per-position medians", "seed raw", "seed medians"],
                      [[a, raw.results_[a].sigma_res, med.results_[a].sigma_res, t42["raw_sigma"][j],
                        t42["median_sigma"][j]] for j, a in enumerate(AXES)]))
    L.append(md_figures_and_run(figs, ("reference", "raw_theta40", "residuals"), timing))
    return "\n".join(L)


def summary_dict(camp, rec: Recording, res: dict, timing: dict, files: dict) -> dict:
    cal = res["main"]
    models = {}
    for name, c in [("main", cal), ("stepwise", res["stepwise"]), ("backward", res["backward"]),
                    ("raw_linear", res["raw"])] + \
            list(res["seed_models"].items()):
        if isinstance(c, Exception):
            models[name] = {"error": str(c), "unidentifiable_terms": getattr(c, "terms", [])}
            continue
        models[name] = {"model": c.model, "statistic": c.statistic,
                        "axes": {a: {"terms": [{"name": t["name"], "estimate": t["estimate"],
                                                "std_error": t["std_error"]} for t in c.results_[a].table()],
                                     "sigma_res": c.results_[a].sigma_res, "ms_res": c.results_[a].ms_res,
                                     "R": c.results_[a].R, "R_adj": c.results_[a].R_adj, "r2": c.results_[a].r2,
                                     "r2_adj": c.results_[a].r2_adj, "bic": c.results_[a].bic,
                                     "condition_number": c.results_[a].condition_number, "n": c.results_[a].n}
                                 for a in AXES}}
    return clean_json({
        "campaign": "tilt-table", "imurig_version": imurig.__version__,
        "settings": camp.to_dict() if camp else None,
        "z_bound": Z_BOUND,
        "parameters": res["parameters"],
        "coefficients": res["coefficients"],
        "all_within_bound": all(p["within_bound"] for p in res["parameters"] if p["within_bound"] is not None),
        "models": models, "seed_published": {k: published_figures()[k] for k in ("table_4_2", "table_4_6")},
        "timing": timing, "files": files,
        "n_samples": rec.n, "n_positions": rec.n_segments,
    })


#: each stage's share of the default campaign's time (simulate: with recording.h5 written as it goes): the
#: progress bar's ETA
STAGE_SHARES = {"simulate": 70, "analyse": 14, "figures": 8, "campaign.rrd": 6, "report": 2}


def _figures(out: OutputFolder, rec100: Recording, fits: dict, early: dict | None) -> dict:
    """The figures' process: those of the record drawn while the parent fits (``early``), then the fits'."""
    if early is None:
        early = record_figures(out, rec100)
    return fit_figures(out, rec100, {**fits, "rec100": rec100}, early)


def _load_rrd(out: OutputFolder, rec100: Recording):
    """The .rrd's process, while the parent fits: rerun loaded and the record's part logged (the open
    writer)."""
    from imurig.reports.tilt_table_rrd import start_rrd   # rerun: heavy, loaded in the .rrd's process

    return start_rrd(out.file("campaign.rrd"), rec100)


def _rrd(out: OutputFolder, rec100: Recording, fits: dict, early=None) -> dict:
    from imurig.reports.tilt_table_rrd import finish_rrd

    finish_rrd(early if early is not None else _load_rrd(out, rec100), {**fits, "rec100": rec100})
    return {"rrd": "campaign.rrd"}


def run(camp: TiltTableCampaign, out_dir, overwrite: bool = False, rrd: bool = True,
        save_recording: bool = True, rig=None) -> dict:
    """Simulate, calibrate and report. Returns the summary dict. ``rig``: the rig's run started ahead
    (:class:`imurig.campaigns.tilt_rig.RigAhead`; used if made for ``camp``'s settings)."""
    out = OutputFolder(out_dir, overwrite=overwrite)
    stages = ["simulate", "analyse", "figures"] + (["campaign.rrd"] if rrd else []) + ["report"]
    with out:  # committed on success, removed on any error
        with StageBar(STAGE_SHARES, stages, "tilt-table campaign") as stage:
            t0 = time.perf_counter()
            stage("simulate")
            # streamed: the 1 kHz record goes to recording.h5 piece by piece; the analysis gets the 100 Hz windows
            sim = stream_campaign(camp, out.file("recording.h5") if save_recording else None, overwrite=True,
                                  rig=rig)
            rec100 = sim.rec100
            rec = SimpleNamespace(n=sim.n, n_segments=sim.n_segments, truth=sim.truth)
            t_sim = time.perf_counter() - t0
            t1 = time.perf_counter()
            stage("analyse")
            # the figures and the .rrd in forked processes (:mod:`imurig.reports.beside`): they load matplotlib
            # and rerun while the fits run here, then draw and write beside each other
            figures = Beside(out, rec100, record_figures, _figures, "drawing the figures")
            rrd_writer = Beside(out, rec100, _load_rrd, _rrd, "writing campaign.rrd") if rrd else None
            def give(fits):   # the main fit made: the figures and the .rrd drawn while the other fits run
                figures.give(fits)
                if rrd_writer is not None:
                    rrd_writer.give(fits)

            try:
                res = analyse(rec100, camp.model, camp.statistic, processed=rec100, on_main=give)
            except BaseException:
                for b in (figures, rrd_writer):
                    if b is not None:
                        b.cancel()
                raise
            t_cal = time.perf_counter() - t1
            t2 = time.perf_counter()
            files = {"report": "report.md", "summary": "summary.json", "calibration": "calibration.json"}
            out.write_json("calibration.json", res["main"].to_dict())
            stage("figures")
            if rrd_writer is not None:
                stage("campaign.rrd")
            products = rrd_writer.wait() if rrd_writer is not None else {}
            figs = figures.wait()
            files.update({f"figure_{k}": v for k, v in figs.items()})
            if save_recording:
                files["recording"] = "recording.h5"
            files.update(products)
            stage("report")
            t_out = time.perf_counter() - t2
            peak = peak_rss_bytes()
            timing = {"simulate_s": round(t_sim, 2), "analyse_s": round(t_cal, 2), "outputs_s": round(t_out, 2),
                      "total_s": round(time.perf_counter() - t0, 2),
                      "simulated_samples_per_s": round(rec.n / t_sim),
                      "peak_rss_MB": round(peak / 2**20, 1)}
            summary = summary_dict(camp, rec, res, timing, files)
            out.write_json("summary.json", summary)
            out.write_text("report.md", _report_md(camp, rec, res, figs, timing))
    return summary
