"""Run the turn-table campaign and its studies; write the report folder.

Folder: ``report.md`` (tables and figures beside the seed's), ``summary.json`` (every
estimated parameter as {name, unit, injected, estimate, std_error, z}), ``calibration.json``
(the gyro calibration), ``recording.h5``, ``campaign.rrd``, PNG figures.
"""
from __future__ import annotations

import time
from types import SimpleNamespace

import numpy as np

import imurig
from imurig.calibration.gyro import AXES, GyroCalibration
from imurig.calibration.simona import SimonaCalibration, read_simona
from imurig.calibration.simona_report import plot_fig_4_19, simona_markdown
from imurig.reports.tilt_table import peak_rss_bytes
from imurig.campaigns.turn_stream import stream_campaign
from imurig.campaigns.turn_table import (TIMERS, Z_BOUND, TurnTableCampaign, arm_study,
                                         gyro_parameters, round_time_error_at, simona_virtual, timer_study)
from imurig.kernel.progress import StageBar
from imurig.kernel.recording import Recording
from imurig.kernel.outputs import OutputFolder, clean_json
from imurig.reports.figure_process import FigureProcess
from imurig.reports.common import md_figures_and_run, md_table, published_figures
from imurig.reports.display_means import calibrated_means

SEED_ENVELOPE = {"adc": 0.1, "gps_mark": 0.06, "hp6700": 0.03}
TIMER_LABEL = {"adc": "ADC (1 kHz pulse channel)", "gps_mark": "GPS board mark input", "hp6700": "HP 6700 counter"}


def analyse(rec: Recording, timer: str = "hp6700", model: str = "physical") -> dict:
    cal = GyroCalibration(model=model, timer=timer).fit(rec)
    return {"main": cal, "windows": cal.windows_, "rate": cal.table_rate_, "reference": cal.reference_,
            "parameters": gyro_parameters(cal, rec),
            "seed_final": GyroCalibration(model="seed_final", timer=timer, gls=False).fit(rec)}


def _fig_timers(out, ts: dict):
    import matplotlib.pyplot as plt  # heavy: loaded when figures are drawn, not when the CLI starts

    fig, axs = plt.subplots(4, 1, figsize=(8, 9), sharex=True)
    hp = ts["timers"]["hp6700"]
    axs[0].plot(hp["rate_dps"], "o-", ms=3, label="reference rate of each step (HP timer)")
    axs[0].legend(fontsize=7, loc="upper left")
    axs[0].set_ylabel("rotation rate, °/s")
    axs[0].set_title("Timer study, r gyro (cf. seed Fig. 4.20)")
    for ax, tm in zip(axs[1:], TIMERS):
        r = ts["timers"][tm]["residual_dps"]
        ax.plot(r, "o-", ms=3, label=f"imurig, envelope {np.max(np.abs(r)):.3f} °/s")
        e = SEED_ENVELOPE[tm]
        ax.axhspan(-e, e, color="orange", alpha=0.2, label=f"seed envelope ±{e} °/s")
        ax.set_ylabel("residual, °/s")
        ax.set_title(TIMER_LABEL[tm], fontsize=9)
        ax.legend(fontsize=7, loc="upper left")
        ax.grid(alpha=0.3)
    axs[-1].set_xlabel("step (rates 1 … 500 °/s on the dial)")
    # fixed margins (tight_layout's for this figure, with some room): its search measures every tick label again
    fig.subplots_adjust(left=0.115, right=0.98, bottom=0.065, top=0.96, hspace=0.23)
    fig.savefig(out.file("fig_4_20_timers.png"), dpi=110)
    plt.close(fig)
    return "fig_4_20_timers.png"


def _fig_residuals(out, res: dict):
    import matplotlib.pyplot as plt  # heavy: loaded when figures are drawn, not when the CLI starts

    cal = res["main"]
    rate = np.degrees(res["rate"])
    fig, axs = plt.subplots(3, 1, figsize=(8, 7), sharex=True)
    for j, a in enumerate(AXES):
        r = np.degrees(cal.results_[a].residuals_)
        on = res["reference"][:, j] != 0
        axs[j].plot(np.abs(rate[on]), r[on], "o", ms=4, label="axis on the table")
        axs[j].plot(np.abs(rate[~on]), r[~on], ".", ms=3, color="gray", label="other mountings")
        axs[j].set_ylabel(f"residual {a.upper()}-gyro, °/s")
        axs[j].grid(alpha=0.3)
        axs[j].legend(fontsize=7)
    axs[-1].set_xlabel("|table rate|, °/s")
    axs[0].set_title(f"Residuals of the final gyro calibration, model {cal.model} (cf. seed Fig. 4.21)")
    # fixed margins (tight_layout's for this figure, with some room): its search measures every tick label again
    fig.subplots_adjust(left=0.14, right=0.98, bottom=0.085, top=0.945, hspace=0.11)
    fig.savefig(out.file("fig_4_21_gyro_residuals.png"), dpi=110)
    plt.close(fig)
    return "fig_4_21_gyro_residuals.png"


def _fig_slip_ring(out, rec: Recording):
    """Seed Fig. 4.16: a temperature channel at 1 kHz while the table turns; noise periodic in angle."""
    import matplotlib.pyplot as plt  # heavy: loaded when figures are drawn, not when the CLI starts

    seg = rec.segments
    i = int(np.argmax(np.abs(seg["rate_dial"])))
    sl = rec.segment_slices()[i]
    v = rec.channels["temp_box"][sl]
    ang = np.degrees(np.mod(rec.truth_signals["spin_angle"][sl], 2 * np.pi)) if "spin_angle" in \
        rec.truth_signals else None
    fig, axs = plt.subplots(1, 2 if ang is not None else 1, figsize=(10, 3.5), squeeze=False)
    axs[0, 0].plot(np.arange(v.size), v, lw=0.4, label="temp_box")
    axs[0, 0].legend(fontsize=7)
    axs[0, 0].set(xlabel="samples (1 kHz)", ylabel="V",
                  title=f"temp_box at {abs(np.degrees(seg['rate_dial'][i])):.0f}°/s dial (cf. seed Fig. 4.16)")
    if ang is not None:
        axs[0, 1].plot(ang, v - np.median(v), ",", alpha=0.5, label="temp_box − median")
        axs[0, 1].legend(fontsize=7)
        axs[0, 1].set(xlabel="table angle, °", ylabel="V − median", title="noise against table angle (slip rings)")
    # fixed margins (tight_layout's for this figure, with some room): its search measures every tick label again
    fig.subplots_adjust(left=0.095, right=0.985, bottom=0.17, top=0.89, wspace=0.34)
    fig.savefig(out.file("fig_4_16_slip_rings.png"), dpi=110)
    plt.close(fig)
    return "fig_4_16_slip_rings.png"


def _fig_arm(out, arm: dict):
    import matplotlib.pyplot as plt  # heavy: loaded when figures are drawn, not when the CLI starts

    g = np.abs(np.asarray(arm["f_ref_m_s2"])) / 9.81242231
    fig, ax = plt.subplots(figsize=(8, 3.5))
    ax.plot(g, np.asarray(arm["residual_linear_m_s2"]) * 1e3, "o", label=f"linear, σ = {arm['sigma_res_linear']:.2e}")
    ax.plot(g, np.asarray(arm["residual_quadratic_m_s2"]) * 1e3, "s", ms=4,
            label=f"with second order, σ = {arm['sigma_res_quadratic']:.2e}")
    ax.set(xlabel="centripetal acceleration, g", ylabel="residual, mm/s²",
           title=f"Accelerometer x on the {arm['radius_m']} m arm, beyond 1 g")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    # fixed margins (tight_layout's for this figure, with some room): its search measures every tick label again
    fig.subplots_adjust(left=0.1, right=0.98, bottom=0.17, top=0.89)
    fig.savefig(out.file("fig_arm_accelerometer.png"), dpi=110)
    plt.close(fig)
    return "fig_arm_accelerometer.png"


def _load_rrd_writer(out) -> None:
    """The .rrd process's first job: load rerun (~1 CPU-s) while the campaign runs."""
    import imurig.reports.turn_table_rrd  # noqa: F401


def _rrd(out, rec, res, rows):
    """campaign.rrd (:func:`imurig.reports.turn_table_rrd.write_rrd`) from the record's rows ``rows``."""
    from imurig.reports.turn_table_rrd import write_rrd  # rerun: heavy, loaded for the .rrd only

    write_rrd(out.file("campaign.rrd"), rec, res, rows=rows)
    return "campaign.rrd"


#: the .rrd begun in this process by :func:`_rrd_start`, finished by :func:`_rrd_finish` (the .rrd's process)
_RRD_STARTED: dict = {}


def _rrd_start(out, rec, rows):
    """The .rrd's parts that need no fits (:func:`imurig.reports.turn_table_rrd.start_rrd`), logged in the
    .rrd's process while the campaign's process fits."""
    from imurig.reports.turn_table_rrd import start_rrd

    _RRD_STARTED["rrd"] = start_rrd(out.file("campaign.rrd"), rec, rows)


def _rrd_finish(out, rec, res, calibrated=None):
    """The rest of the .rrd begun by :func:`_rrd_start`, from the fits ``res`` (and the calibrated rates'
    block means, :func:`imurig.reports.display_means.calibrated_means`, if made by the sender)."""
    from imurig.reports.turn_table_rrd import finish_rrd

    started = _RRD_STARTED.pop("rrd")
    if started is not None:
        finish_rrd(started, rec, res, calibrated)
    return "campaign.rrd"


def _fig_simona(out, real, virt):
    plot_fig_4_19(out.file("fig_4_19_simona.png"), real, virt)
    return "fig_4_19_simona.png"


def _param_table(params) -> str:
    return md_table(["parameter", "unit", "injected", "estimate", "std. error", "z", "within bound"],
                    [[p["name"], p["unit"], p["injected"], p["estimate"], p["std_error"], p["z"], p["within_bound"]]
                     for p in params])


def _report_md(camp, rec, res, ts, arm, simona, figs, timing, n: int | None = None) -> str:
    cal = res["main"]
    L = [f"# Turn-table gyro calibration — imurig {imurig.__version__}\n"]
    if camp:
        p = camp.protocol
        L.append(f"Schedule: dial {list(p.dial_rates_dps)} deg/s × {camp.mains_hz:g}/60 (mains), directions "
                 f"{list(p.directions)}, mountings {list(p.mounts)}; {rec.n_segments} steps, {rec.n if n is None else n:,} samples at "
                 f"{p.sample_rate_hz:g} Hz. Timer: {TIMER_LABEL[camp.timer]}. Seed {camp.seed}.\n")
    L.append("## Recovered vs injected gyro parameters\n")
    L.append("Whole-round means per step; generalised least squares with the gyro noise model (angle random "
             "walk + Gauss-Markov bias instability + timer error). Misalignment on a turn table includes the "
             "table's wobble as seen in each mounting; the injected values shown are those effective values. "
             f"Bound |z| ≤ {Z_BOUND:g}.\n")
    L.append(_param_table(res["parameters"]))
    if "truth_z" in figs:
        L.append(f"\n![z]({figs['truth_z']})\n")
    L.append("\n## Model statistics\n")
    rows = []
    for name, c in (("main (" + cal.model + ")", cal), ("seed eq. 4.39-4.41", res["seed_final"])):
        for a in AXES:
            r = c.results_[a]
            rows.append([name, a, ", ".join(r.names), np.degrees(r.sigma_res), r.R_adj, r.condition_number])
    L.append(md_table(["model", "gyro", "terms", "σ_res (°/s)", "R_adj", "condition number"], rows))
    L.append("\nThe seed's eq. 4.39-4.41 carry products ω_p ω_q … that a one-axis-at-a-time turn table barely "
             "excites (only through misalignment); see their condition numbers.\n")
    if ts:
        L.append("\n## Timers (seed section 4.4.3, Fig. 4.20)\n")
        L.append(md_table(["timer", "resolution / jitter", "residual envelope (°/s)", "σ_res (°/s)",
                           "seed envelope (°/s)"],
                          [[TIMER_LABEL[t], {"adc": "1 ms sampling", "gps_mark": "1 µs tags, 0.1 ms jitter",
                                             "hp6700": "1 µs"}[t], ts["timers"][t]["envelope_dps"],
                            ts["timers"][t]["sigma_res_dps"], SEED_ENVELOPE[t]] for t in TIMERS]))
        e = round_time_error_at(500, 1e-3)
        e6 = round_time_error_at(500, 1e-6)
        L.append(f"\nRound-time resolution at 500 °/s (seed 4.4.2): 1 ms gives ±{e['angle_error_deg']:.2g}° per "
                 f"round ({e['rate_error_dps_one_round']:.2f} °/s over one round); 1 µs gives "
                 f"±{e6['angle_error_deg']:.2g}°. The seed: \"about ±0.0005° per round … would grow to 0.5° at "
                 "500 °/s\".\n")
        if "timers" in figs:
            L.append(f"\n![timers]({figs['timers']})\n")
    if arm:
        L.append("\n## Accelerometers beyond 1 g on the arm (seed chapter 6)\n")
        L.append(f"Radius {arm['radius_m']} m, up to {arm['max_g']:.2f} g, both directions, HP timer.\n")
        L.append(_param_table(arm["parameters"]))
        L.append(f"\nσ_res linear {arm['sigma_res_linear']:.3e} m/s², with the second-order term "
                 f"{arm['sigma_res_quadratic']:.3e} m/s².\n")
        if "arm" in figs:
            L.append(f"\n![arm]({figs['arm']})\n")
    if simona:
        L.append("\n## SIMONA quick calibration (seed section 4.4.2, appendix B, Fig. 4.19)\n")
        L.append(simona_markdown(simona["real"], simona["virtual"]))
        L.append("\nRound times, real vs virtual (s), first rows: " + ", ".join(
            f"{a:.1f}/{b:.1f}" for a, b in zip(simona["real_rounds"][1:7], simona["virtual_rounds"][1:7])) + "\n")
        if "simona" in figs:
            L.append(f"\n![simona]({figs['simona']})\n")
    L.append(md_figures_and_run(figs, ("residuals", "slip_rings"), timing))
    return "\n".join(L)


def _fig_z(out, params):
    import matplotlib.pyplot as plt  # heavy: loaded when figures are drawn, not when the CLI starts

    ps = [p for p in params if p.get("z") is not None]
    fig, ax = plt.subplots(figsize=(8, 3.8))
    z = [p["z"] for p in ps]
    ax.bar(range(len(z)), z, color=["C0" if abs(v) <= Z_BOUND else "C3" for v in z], label="z of each parameter")
    for s in (Z_BOUND, -Z_BOUND):
        ax.axhline(s, color="k", ls="--", lw=0.8, label=f"{s:+g} bound")
    ax.legend(fontsize=7, loc="upper right")
    ax.set_xticks(range(len(z)), [p["name"] for p in ps], rotation=60, ha="right", fontsize=7)
    ax.set_ylabel("(estimate − injected) / std. error")
    ax.set_title("Gyro parameters: recovered vs injected")
    fig.tight_layout()
    fig.savefig(out.file("fig_truth_z.png"), dpi=110)
    plt.close(fig)
    return "fig_truth_z.png"


#: each stage's share of the default campaign's time (2 cores): the progress bar's ETA
STAGE_SHARES = {"simulate": 66, "analyse": 4, "figures": 12, "campaign.rrd": 14, "studies": 2, "report": 2}


def _studies(camp: TurnTableCampaign) -> tuple:
    """The timer study, the arm study and SIMONA (their own records and streams, nothing of the campaign's)."""
    ts = timer_study(camp.seed, lab=camp.lab)
    arm = arm_study(camp.seed)
    real = read_simona()
    virt = simona_virtual(camp.seed)
    simona = {"real": SimonaCalibration().fit(real).summary_, "virtual": SimonaCalibration().fit(virt).summary_,
              "real_rounds": real.channels["measured_round"].tolist(),
              "virtual_rounds": virt.channels["measured_round"].tolist()}
    return ts, arm, simona, (real, virt)


def _studies_and_figures(out, camp: TurnTableCampaign) -> dict:
    """The studies (:func:`_studies`) and their figures: the first job of the studies' process, which runs
    beside the campaign from its start. Returns what the report reads (the studies' records left out)."""
    ts, arm, simona, (real, virt) = _studies(camp)
    figs = {"simona": _fig_simona(out, real, virt), "timers": _fig_timers(out, ts), "arm": _fig_arm(out, arm)}
    return {"ts": _without_recording(ts), "arm": _without_recording(arm), "simona": simona, "figs": figs}


def _without_recording(d: dict) -> dict:
    return {k: v for k, v in d.items() if k != "recording"}


def _residual_data(res: dict) -> dict:
    """What :func:`_fig_residuals` reads of the analysis (small: sent to the figure process)."""
    cal = res["main"]
    main = SimpleNamespace(model=cal.model, results_={a: SimpleNamespace(residuals_=cal.results_[a].residuals_)
                                                      for a in AXES})
    return {"main": main, "rate": res["rate"], "reference": res["reference"]}


def run(camp: TurnTableCampaign, out_dir, overwrite: bool = False, rrd: bool = True, save_recording: bool = True,
        studies: bool = True) -> dict:
    """Simulate, analyse and report (module doc). Three processes share the work, both helpers forked at the
    start (before this process starts a thread): the studies (their own records) and their figures run beside
    the campaign's simulation, and that process then draws the campaign's figures; the second loads rerun,
    then writes the .rrd from the rows this process sends it after the analysis. Where fork is missing each job
    runs here, in order."""
    out = OutputFolder(out_dir, overwrite=overwrite)
    stages = ["simulate", "analyse", "figures"] + (["campaign.rrd"] if rrd else []) + \
        (["studies"] if studies else []) + ["report"]
    with out:  # the folder committed on success, removed on any error
        with StageBar(STAGE_SHARES, stages, "turn-table campaign") as stage:
            t0 = time.perf_counter()
            stage("simulate")
            # forked before any thread of this process starts; draws the campaign's figures later (draw())
            figures = FigureProcess(out, [("studies", _studies_and_figures, (camp,))] if studies else [])
            writer = FigureProcess(out, [("rerun", _load_rrd_writer, ())], pyplot=False) if rrd else None
            try:
                # streamed: the HDF5 file written as the rows are made; rec holds the acquisition windows
                sim = stream_campaign(camp, out.file("recording.h5") if save_recording else None, overwrite=True)
                rec = sim.rec
                t_sim = time.perf_counter() - t0
                figures.draw("slip_rings", _fig_slip_ring, sim.fig)   # needs no fit: drawn while this one fits
                # the record's metadata, truth and events (not its windows' rows)
                light = SimpleNamespace(n=rec.n, n_segments=rec.n_segments, meta=rec.meta, truth=rec.truth,
                                        events=rec.events)
                if rrd and sim.streamed:   # the .rrd's parts that need no fit (its rows sent: ~0.1 GB), beside the fits
                    writer.draw("rrd_start", _rrd_start, light, sim.rows, beside=True)
                stage("analyse")
                res = analyse(rec, camp.timer, camp.model)
                rec = light   # keep the windows' segments, let go of their rows
                res["windows"] = SimpleNamespace(segments=res["windows"].segments)
                for c in (res["main"], res["seed_final"]):
                    c.windows_ = res["windows"]
                sim.rec = None
                stage("figures")
                # the campaign's figures in the studies' process; the .rrd finished in the second process (the
                # whole-record chain's rows are not sent: a process forked now has them)
                figures.draw("residuals", _fig_residuals, _residual_data(res))
                figures.draw("truth_z", _fig_z, res["parameters"])
                if rrd and sim.streamed:   # the calibrated rates' means made here (~0.5 CPU-s), the rest there
                    writer.draw("rrd", _rrd_finish, rec, res, calibrated_means(sim.rows, rec, res["main"]))
                elif rrd:
                    writer.wait()
                    writer = FigureProcess(out, [("rrd", _rrd, (rec, res, sim.rows))], pyplot=False)
                out.write_json("calibration.json", res["main"].to_dict())
                files = {"report": "report.md", "summary": "summary.json", "calibration": "calibration.json"}
                if save_recording:
                    files["recording"] = "recording.h5"
                n_samples = sim.n
                del sim
                if rrd:
                    stage("campaign.rrd")   # written by the second process
                    files["rrd"] = writer.wait()["rrd"]
                if studies:
                    stage("studies")
                figs = figures.wait()
            except BaseException:
                for p in (figures, writer):
                    if p is not None:
                        p.cancel()
                raise
            ts = arm = simona = None
            if studies:
                done = figs.pop("studies")
                ts, arm, simona = done["ts"], done["arm"], done["simona"]
                figs.update(done["figs"])
            files.update({f"figure_{k}": v for k, v in figs.items()})
            stage("report")
            timing = {"simulate_s": round(t_sim, 2), "total_s": round(time.perf_counter() - t0, 2),
                      "simulated_samples_per_s": round(n_samples / t_sim), "samples": n_samples,
                      "peak_rss_MB": round(peak_rss_bytes() / 2**20, 1)}
            summary = summary_dict(camp, rec, res, ts, arm, simona, timing, files, n_samples)
            out.write_json("summary.json", summary)
            out.write_text("report.md", _report_md(camp, rec, res, ts, arm, simona, figs, timing, n_samples))
    return summary


def summary_dict(camp, rec, res, ts, arm, simona, timing, files, n: int | None = None) -> dict:
    cal = res["main"]

    def strip(d):
        return {k: v for k, v in d.items() if k != "recording"} if d else None

    def simona_clean(fits):
        return {g: {k: v for k, v in f.items() if isinstance(v, (int, float, str))} for g, f in fits.items()}

    return clean_json({
        "campaign": "turn-table", "imurig_version": imurig.__version__,
        "settings": camp.to_dict() if camp else None, "z_bound": Z_BOUND,
        "parameters": res["parameters"],
        "all_within_bound": all(p["within_bound"] for p in res["parameters"] if p["within_bound"] is not None),
        "models": {a: {"terms": cal.results_[a].table(), "sigma_res_rad_s": cal.results_[a].sigma_res,
                       "R_adj": cal.results_[a].R_adj} for a in AXES},
        "steps": {"rate_rad_s": res["rate"].tolist(), "rounds": res["windows"].segments["rounds"].tolist(),
                  "mount": [str(m) for m in res["windows"].segments["mount"]]},
        "timer_study": strip(ts), "arm_study": strip(arm),
        "simona": None if not simona else {"real": simona_clean(simona["real"]),
                                           "virtual": simona_clean(simona["virtual"]),
                                           "real_rounds_s": simona["real_rounds"],
                                           "virtual_rounds_s": simona["virtual_rounds"]},
        "seed_published": published_figures()["turn_table"],
        "timing": timing, "files": files, "n_samples": rec.n if n is None else n, "n_steps": rec.n_segments,
    })
