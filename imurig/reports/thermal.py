"""Run the thermal campaign and write its report folder (report.md, summary.json,
thermal_calibration.json, recording.h5, campaign.rrd, figures)."""
from __future__ import annotations

import time

import numpy as np

import imurig
from imurig.calibration.thermal import T0
from imurig.campaigns.thermal import Z_BOUND, ThermalCampaign, analyse
from imurig.reports.tilt_table import peak_rss_bytes
from imurig.kernel.progress import StageBar
from imurig.kernel.recording import Recording
from imurig.kernel.outputs import OutputFolder, clean_json
from imurig.reports.common import md_figures_and_run, md_table, save_products


def _figs(out, rec: Recording, res: dict) -> dict:
    import matplotlib  # heavy: loaded when figures are drawn, not when the CLI starts

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figs = {}
    # Fig 4.22: raw temperature-sensor output through the profile
    fig, ax = plt.subplots(figsize=(8, 3.5))
    k = max(1, rec.n // 20000)
    ax.plot(rec.channels["temp_box"][::k], lw=0.6, label="temp_box")
    ax.plot(rec.channels["temp_acc_x"][::k], lw=0.6, label="temp_acc_x")
    ax.set(xlabel=f"samples (every {k}th at {rec.sample_rate_hz:g} Hz)", ylabel="V",
           title="Raw temperature-sensor output during the thermal calibration (cf. seed Fig. 4.22)")
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out.file("fig_4_22_temperature.png"), dpi=110)
    plt.close(fig)
    figs["temperature"] = "fig_4_22_temperature.png"
    tab, fit = res["table"], res["fit"]
    up = tab["branch"] == "up"
    for kind, keys, temps, unit, scale in (
            ("gyro", [("gyro_bias", j, a) for j, a in enumerate("pqr")], lambda j: tab["T_box"], "°/s",
             180 / np.pi),
            ("acc", [("acc_bias", j, a) for j, a in enumerate("xyz")], lambda j: tab["T_acc"][:, j], "m/s²", 1.0)):
        fig, axs = plt.subplots(3, 1, figsize=(8, 8), sharex=True)
        for ax, (key, j, a) in zip(axs, keys):
            T = temps(j) - 273.15
            y = tab[key][:, j] * scale
            ax.plot(T[up], y[up], "o", mfc="none", label="heating branch")
            ax.plot(T[~up], y[~up], "s", mfc="none", label="cooling branch")
            Tg = np.linspace(T.min(), T.max(), 200) + 273.15
            for h, ls in ((0.5, "-"), (-0.5, "--")):
                ax.plot(Tg - 273.15, fit.predict(f"{key}_{a}", Tg, h) * scale, "r" + ls, lw=1,
                        label=f"fit, {'heating' if h > 0 else 'cooling'}")
            ax.set_ylabel(f"{key.split('_')[0]} {a} bias, {unit}")
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7)
        axs[-1].set_xlabel("temperature-sensor reading, °C")
        name = "fig_4_23_gyro_bias.png" if kind == "gyro" else "fig_acc_bias_temperature.png"
        axs[0].set_title("Gyro bias vs box temperature, two cycles (cf. seed Fig. 4.23)" if kind == "gyro" else
                         "Accelerometer bias vs own temperature sensor, two cycles (third-order fit + hysteresis)")
        fig.tight_layout()
        fig.savefig(out.file(name), dpi=110)
        plt.close(fig)
        figs[kind] = name
    return figs


def _report(camp, rec, res, figs, timing) -> str:
    L = [f"# Thermal calibration — imurig {imurig.__version__}\n"]
    p = camp.profile if camp else None
    if p:
        L.append(f"Profile: {p.low_C:g} … {p.high_C:g} °C in {p.step_C:g} °C steps, {p.cycles} cycles, soak "
                 f"{p.soak_s / 60:g} min, six attitudes × {p.attitude_dwell_s:g} s per step; {rec.n:,} samples at "
                 f"{p.sample_rate_hz:g} Hz ({rec.time_s[-1] / 3600:.1f} h). Seed {camp.seed}.\n")
    L.append("## Coefficients against the noise-free twin\n")
    L.append("Bias (and accelerometer scale) per step from the six attitudes, fitted against the sensor's own "
             "temperature reading (dT = T − 25 °C): third order for the accelerometers, first order for the "
             "gyros (seed 4.5), plus a hysteresis term (+½ heating, −½ cooling) whose coefficient is the gap "
             "between the branches. 'Injected' is the same fit on the true sensors' noise-free output. "
             f"Bound |z| ≤ {Z_BOUND:g}.\n")
    L.append(md_table(["coefficient", "unit", "injected (twin)", "estimate", "std. error", "z", "within bound"],
                      [[c["name"], c["unit"], c["injected"], c["estimate"], c["std_error"], c["z"], c["within_bound"]]
                       for c in res["coefficients"]]))
    L.append("\n## Hysteresis (two cycles)\n")
    L.append(md_table(["channel", "measured gap heating − cooling", "twin gap", "injected hysteresis"],
                      [[k, v["measured_gap_m_s2"], v["injected_gap_m_s2"], v["injected_hysteresis_m_s2"]]
                       for k, v in res["hysteresis"].items()]))
    L.append("\n## What the correction buys\n")
    L.append("Spread (std over all steps) of the six-position bias before and after the thermal correction "
             "(which is applied before the least-squares calibration):\n")
    L.append(md_table(["channel", "before", "after"],
                      [[k, *[v for v in d.values()]] for k, d in res["spread"].items()]))
    L.append(md_figures_and_run(figs, ("temperature", "acc", "gyro"), timing))
    return "\n".join(L)


def thermal_calibration_dict(res: dict) -> dict:
    """The fitted temperature models, to correct recordings before the least-squares calibration."""
    return {"kind": "imurig.thermal_models", "version": 1, "reference_temperature_K": T0,
            "equation": "q(T) = sum_k coef_k dT^k + coef_h h, dT = T_sensor - T0, h = +1/2 heating, -1/2 cooling",
            "models": {k: {"terms": r.names, "coef": r.coef_.tolist(), "std_error": r.std_error_.tolist(),
                           "temperature_sensor": "temp_box" if k.startswith("gyro") else f"temp_acc_{k[-1]}"}
                       for k, r in res["fit"].results_.items()}}


#: each stage's share of the default campaign's time (estimated from one run on 2 cores): the bar's ETA
STAGE_SHARES = {"simulate": 60, "analyse": 10, "outputs": 28, "report": 2}


def run(camp: ThermalCampaign, out_dir, overwrite=False, rrd=True, save_recording=True) -> dict:
    out = OutputFolder(out_dir, overwrite=overwrite)
    with out:  # committed on success, removed on any error
        with StageBar(STAGE_SHARES, STAGE_SHARES, "thermal campaign") as stage:
            t0 = time.perf_counter()
            stage("simulate")
            rec = camp.simulate()
            t_sim = time.perf_counter() - t0
            stage("analyse")
            res = analyse(rec)
            stage("outputs")
            figs = _figs(out, rec, res)
            out.write_json("thermal_calibration.json", thermal_calibration_dict(res))
            files = {"report": "report.md", "summary": "summary.json", "calibration": "thermal_calibration.json",
                     **{f"figure_{k}": v for k, v in figs.items()}}
            from imurig.reports.thermal_rrd import write_rrd  # rerun: heavy, loaded for the .rrd only

            files.update(save_products(out, rec, res, write_rrd, save_recording, rrd))
            stage("report")
            timing = {"simulate_s": round(t_sim, 2), "total_s": round(time.perf_counter() - t0, 2),
                      "samples": rec.n, "simulated_hours": round(rec.time_s[-1] / 3600, 2),
                      "peak_rss_MB": round(peak_rss_bytes() / 2**20, 1)}
            summary = clean_json({
                "campaign": "thermal", "imurig_version": imurig.__version__, "settings": camp.to_dict(),
                "z_bound": Z_BOUND, "parameters": res["coefficients"],
                "all_within_bound": all(c["within_bound"] for c in res["coefficients"] if c["within_bound"] is not None),
                "hysteresis": res["hysteresis"], "spread": res["spread"],
                "steps": {"T_set_K": res["table"]["T_set"].tolist(), "branch": res["table"]["branch"].tolist(),
                          "cycle": res["table"]["cycle"].tolist()},
                "timing": timing, "files": files})
            out.write_json("summary.json", summary)
            out.write_text("report.md", _report(camp, rec, res, figs, timing))
    return summary
