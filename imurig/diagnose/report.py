"""`imurig diagnose`: report folder with report.md, diagnosis.json, figures and an .rrd that
overlays the recording, the nominal twin and the corrected twin."""
from __future__ import annotations

import numpy as np

from imurig.diagnose.rate_table import SEED_SAYS, diagnose_rate_rows
from imurig.errors import RecordingError
from imurig.recording import Recording
from imurig.report import OutputFolder, clean_json, md_table


def diagnose(rec: Recording, seed: int = 0, twin_model: str = "physical", earth_rate: bool = True) -> dict:
    """Dispatch on the recording's kind: tilt-table recordings (twin model ``twin_model``),
    turn-table recordings (twin with or without the Earth's rate) and turn-table row
    recordings (appendix B)."""
    if rec.meta.get("rig") == "turn_table" and rec.meta.get("row_recording"):
        return {"kind": "rate_table_rows", **diagnose_rate_rows(rec, np.random.default_rng(seed))}
    if {"attitude", "step", "branch"} <= set(rec.segments):
        from imurig.diagnose.thermal import diagnose_thermal

        return {"kind": "thermal", **diagnose_thermal(rec, np.random.default_rng(seed))}
    if rec.meta.get("rig") == "turn_table" or "rate_dial" in rec.segments:
        from imurig.diagnose.turn_table import diagnose_turn_table

        return {"kind": "turn_table", **diagnose_turn_table(rec, np.random.default_rng(seed), earth_rate=earth_rate)}
    if rec.meta.get("rig") == "tilt_table" or {"theta", "phi"} <= set(rec.segments):
        from imurig.diagnose.tilt_table import diagnose_tilt_table

        return {"kind": "tilt_table", **diagnose_tilt_table(rec, np.random.default_rng(seed), twin_model=twin_model,
                                                            dynamics=True)}
    raise RecordingError(f"diagnosis of '{rec.meta.get('rig', 'unknown')}' recordings is not implemented yet; "
                         "this version diagnoses tilt-table and turn-table recordings and turn-table row "
                         "recordings in the "
                         "appendix-B format (imurig.calibration.simona.read_simona)")


def _engine_row(where: str, f: dict, seed_says: dict) -> list:
    """One report row for a finding of the selection engine."""
    ps = "; ".join(f"{p['name']} = {p['estimate']:.4g} ± {p['std_error']:.2g}" for p in f["parameters"])
    alias = f"; indistinguishable from {f['indistinguishable_from']}" if f.get("indistinguishable_from") else ""
    return [where, f["effect"], f["physics"], f"{ps}; F = {f['statistic']:.1f} > {f['threshold']:.1f}; share "
            f"{f['variance_share'] * 100:.0f} % of the residual{alias}", seed_says.get(f["effect"], "–")]


def _findings_rows(d: dict) -> list[list]:
    if d.get("kind") == "magnetometer":
        from imurig.diagnose.magnetometer import findings_rows

        return findings_rows(d)
    rows = []
    if d.get("kind") == "thermal":
        return [_engine_row(f"{ch} six-position bias per step", f, SEED_SAYS_TURN)
                for ch, e in d["channels"].items() for f in e["findings"]]
    if d.get("kind") == "turn_table":
        for g, e in d["gyros"].items():
            rows += [_engine_row(f"gyro_{g} whole-round means", f, SEED_SAYS_TURN) for f in e["findings"]]
            sc = e.get("scatter", {}).get("finding")
            if sc:
                rows.append([f"gyro_{g} sample noise", sc["effect"], sc["physics"],
                             f"noise up to {sc['peak_to_median_noise']:.2f}× the median at table angles "
                             f"{', '.join(f'{x:.0f}' for x in sc['angles_deg'])} deg; p = {sc['p_value']:.2g}",
                             SEED_SAYS_TURN.get(sc["effect"], "–")])
        return rows
    if d.get("kind") == "tilt_table":
        for a, e in d["axes"].items():
            rows += [_engine_row(f"acc_{a} position means", f, SEED_SAYS_TILT) for f in e["findings"]]
            for k in ("finding_spikes", "finding_vibration"):
                if k in e["scatter"]:
                    f = e["scatter"][k]
                    ev = ", ".join(f"{kk} = {vv}" for kk, vv in f.items() if kk not in ("effect", "physics"))
                    rows.append([f"acc_{a} scatter", f["effect"], f["physics"], ev, SEED_SAYS_TILT.get(f["effect"], "–")])
        for f in d.get("dynamic", {}).get("findings", []):
            where = "all accelerometers" if f["channel"] == "acc" else f"acc_{f['channel']}"
            rows.append(_engine_row(f"{where}, slews against the dynamic twin", f, SEED_SAYS_TILT))
        return rows
    if d.get("rate_factor"):
        rf = d["rate_factor"]
        rows.append(["rate (stopwatch)", "mains_rate_factor", rf["physics"],
                     f"mean measured/dial {rf['mean_ratio']:.4f} ± {rf['mean_ratio_se']:.4f}; factor {rf['factor']:.4f}",
                     SEED_SAYS["mains_rate_factor"]])
    for f in d["shortfall"]["diagnosis"]["findings"]:
        ps = "; ".join(f"{p['name']} = {p['estimate']:.4g} ± {p['std_error']:.2g}" for p in f["parameters"])
        rows.append(["rate (stopwatch)", f["effect"], f["physics"],
                     f"{ps}; {f['scan']}; mean shortfall {d['shortfall']['mean_shortfall'] * 100:.2f} %; "
                     f"F = {f['statistic']:.1f} > {f['threshold']:.1f}", SEED_SAYS.get(f["effect"], "–")])
    tr = d["timer_resolution"]
    rows.append(["rate (stopwatch)", tr["effect"], tr["physics"],
                 f"residual RMS at high rates {tr['rate_residual_rms_dps_high_rates']:.3f} °/s vs "
                 f"{tr['rate_residual_rms_dps_low_rates']:.3f} °/s at low rates", SEED_SAYS["timer_quantisation"]])
    rc = d.get("range_change_by_resolution")
    if rc:
        rows.append(["gyro voltages (display)", "instrument_range_change",
                     "the voltmeter switched to a coarser range (autoscale)",
                     f"readings on a {rc['resolution_after_V']:g} V grid from row {rc['first_row']} on (last "
                     f"{rc['rows_after']} rows), {rc['resolution_before_V']:g} V before",
                     SEED_SAYS["instrument_range_change"]])
    for f in d.get("voltmeter", {}).get("findings", []):
        ps = "; ".join(f"{p['name']} = {p['estimate']:.4g} ± {p['std_error']:.2g}" for p in f["parameters"])
        where = f"from row {d['voltmeter']['range_change_row']}; " if f["effect"] == "instrument_range_change" else ""
        rows.append(["all gyro voltages (one voltmeter)", f["effect"], f["physics"],
                     f"{where}{ps}; F = {f['statistic']:.1f} > {f['threshold']:.1f}", SEED_SAYS.get(f["effect"], "–")])
    for g, e in d["gyros"].items():
        for f in e["findings"]:
            ps = "; ".join(f"{p['name']} = {p['estimate']:.4g} ± {p['std_error']:.2g}" for p in f["parameters"])
            rows.append([f"gyro {g} voltage", f["effect"], f["physics"],
                         f"{ps}; F = {f['statistic']:.1f} > {f['threshold']:.1f}"
                         + (f"; indistinguishable from {f['indistinguishable_from']}" if f["indistinguishable_from"] else ""),
                         SEED_SAYS.get(f["effect"], "–")])
    return rows


SEED_SAYS_TILT = {
    "adc_crosstalk": "4.3.4: coupling of an ADC channel to the next one; lower multiplexing frequency cured it",
    "building_vibration": "4.3.3: a hydraulic pump in the basement shook the building by day",
    "cable_fault_spikes": "4.3.3: peaks in the y channel from the junction-box connector",
    "temperature_drift": "4.5: temperature changes bias and scale",
    "cross_coupling": "4.3.5: cross terms a_x a_z kept in the final models",
    "time_delay": "4.3.4: at 20 kHz 'the time between the first channel to be sampled and the last is "
                  "16 / 20000 Hz = 0.0008 s' (multiplexer skew)",
    "lever_arm": "– (the tilt table is used at rest in the seed)",
    "wrong_local_gravity": "4.3.2: g0 = 9.81242231 m/s^2 'determined exactly by the geodetic institute'",
}


SEED_SAYS_TURN = {
    "earth_rate_left_out": "4.4.2: the Earth's rate (15 deg/h) adds to the table rate along the vertical axis",
    "g_sensitivity": "– (not examined in the seed)",
    "temperature_hysteresis": "4.5: the heating and cooling branches differ (hysteresis)",
    "slip_ring_noise": "4.4.3, Fig. 4.16: noise from the slip rings, depending on the table angle",
    "time_drift": "–",
}


def _figure(out, rec: Recording, d: dict) -> str:
    if d.get("kind") == "tilt_table":
        return _figure_tilt(out, d)
    if d.get("kind") == "turn_table":
        return _figure_tilt(out, d, key="gyros", prefix="gyro_", unit="rad/s")
    if d.get("kind") == "thermal":
        _figure_tilt(out, d, key="channels", prefix="", unit="SI")
        return _figure_thermal_residuals(out, d)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = np.array(d["rows"])
    dial = np.degrees(np.abs(rec.channels["rate_dial"][rows]))
    rate = np.degrees(2 * np.pi / rec.channels["measured_round"][rows])
    fig, axs = plt.subplots(3, 2, figsize=(10, 10.5))
    _rate_residual_panels(axs[2], d)
    axs[0, 0].plot(dial, (rate / dial - 1) * 100, "o", label="recording vs twin (rate = dial)")
    if d.get("rate_factor"):
        f = d["rate_factor"]["factor"]
        axs[0, 0].plot(dial, (rate / (f * dial) - 1) * 100, "s", mfc="none", label=f"vs twin × {f:.4f} (mains factor)")
        after = d["shortfall"]["diagnosis"]
        if after["findings"]:
            axs[0, 0].axhline(0, color="k", lw=0.5)
    axs[0, 0].set(xscale="log", xlabel="dial rate, °/s", ylabel="rate mismatch, %", title="Where: the rate")
    axs[0, 0].legend(fontsize=7)
    axs[0, 0].grid(alpha=0.3)
    sh = d["shortfall"]["diagnosis"]
    axs[0, 1].axis("off")
    axs[0, 1].text(0, 1, "Findings\n" + "\n".join(f"• {r[1]}: {r[3][:70]}" for r in _findings_rows(d)),
                   va="top", fontsize=7, family="monospace", wrap=True)
    V = rec.channels.get("gyro_p")
    if V is not None:
        Vr = V[rows]
        X = np.column_stack([np.ones_like(rate), rate])
        res0 = Vr - X @ np.linalg.lstsq(X, Vr, rcond=None)[0]
        axs[1, 0].plot(rows, res0 * 1e3, "o-", label="gyro p: linear fit residual")
        rc = d.get("range_change_by_resolution")
        if rc:
            axs[1, 0].axvline(rc["first_row"] - 0.5, color="r", ls="--", label="range change (display grid)")
        axs[1, 0].set(xlabel="row", ylabel="residual, mV", title="Where: gyro p against the stopwatch rate")
        axs[1, 0].legend(fontsize=7)
        axs[1, 0].grid(alpha=0.3)
        g = d["gyros"].get("p", {})
        axs[1, 1].bar(["before", "after"], [g.get("fit_before", {}).get("sigma_res", np.nan) * 1e3,
                                              g.get("fit_after", {}).get("sigma_res", np.nan) * 1e3])
        axs[1, 1].set(ylabel="σ_res, mV", title="Gyro p fit before and after the effects")
    axs[1, 1].grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out.file("fig_diagnosis.png"), dpi=110)
    plt.close(fig)
    _ = sh
    return "fig_diagnosis.png"


def _rate_residual_panels(axs, d: dict) -> None:
    """Rate rows: residuals before and after the effects against the revealing variable, the rate.
    Left: relative rate mismatch d (nominal: constant shortfall) with the timer test's noise bands
    (+-2 sigma: table setting only, and setting plus the fitted round-time error sigma_T / T).
    Right: gyro p voltage against the stopwatch rate (nominal: linear)."""
    rs = d["shortfall"].get("residuals")
    if rs:
        r = np.array(rs["rate_dps"])
        axs[0].plot(r, np.array(rs["before"]) * 100, "o", mfc="none", label="before (constant shortfall)")
        axs[0].plot(r, np.array(rs["after"]) * 100, ".", label="after (effects found)")
        te = d["timer_resolution"].get("test")
        if te:
            rr = np.geomspace(r.min(), r.max(), 100)
            T = 360.0 / rr
            s0 = te["setting_sigma"]
            s1 = np.sqrt(s0**2 + te["sigma_T2_s2"] / T**2)
            axs[0].plot(rr, 2 * s0 * 100 * np.ones_like(rr), "k:", lw=0.8, label="±2σ table setting")
            axs[0].plot(rr, -2 * s0 * 100 * np.ones_like(rr), "k:", lw=0.8)
            lab = (f"±2σ with timer σ_T = {te['sigma_T_s'] * 1e3:.1f} ms (LR {te['statistic']:.1f} vs "
                   f"{te['threshold']:.1f})")
            axs[0].plot(rr, 2 * s1 * 100, "r--", lw=0.8, label=lab)
            axs[0].plot(rr, -2 * s1 * 100, "r--", lw=0.8)
        axs[0].set(xscale="log", xlabel="measured rate, °/s", ylabel="rate residual, %",
                   title="Rate residual before/after vs rate")
        axs[0].legend(fontsize=6)
        axs[0].grid(alpha=0.3)
    g = d.get("gyros", {}).get("p", {}).get("residuals")
    if g:
        axs[1].plot(g["rate_dps"], np.array(g["before_V"]) * 1e3, "o", mfc="none", label="before (bias + scale)")
        axs[1].plot(g["rate_dps"], np.array(g["after_V"]) * 1e3, ".", label="after (gyro p's own effects)")
        axs[1].set(xscale="log", xlabel="measured rate, °/s", ylabel="residual, mV",
                   title="Gyro p voltage residual before/after vs rate")
        axs[1].legend(fontsize=7)
        axs[1].grid(alpha=0.3)


def _figure_thermal_residuals(out, d: dict) -> str:
    """Thermal: each channel's step-bias residual before and after against the temperature, heating
    steps filled and cooling steps open (the hysteresis gap shows as two branches)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    chans = [c for c, e in d["channels"].items() if "residuals" in e]
    fig, axs = plt.subplots(2, 3, figsize=(11, 6), squeeze=False)
    for ax, ch in zip(axs.ravel(), chans):
        rs = d["channels"][ch]["residuals"]
        T = np.array(rs["temperature_K"]) - 273.15
        up = np.array(rs["heating"], bool)
        for arr, mk, lab in ((np.array(rs["before"]), "o", "before"), (np.array(rs["after"]), "s", "after")):
            ax.plot(T[up], arr[up], mk, ms=4, label=f"{lab}, heating")
            ax.plot(T[~up], arr[~up], mk, ms=4, mfc="none", label=f"{lab}, cooling")
        names = ", ".join(f["effect"] for f in d["channels"][ch]["findings"]) or "nothing found"
        ax.set(xlabel="sensor temperature, °C", ylabel=f"residual, {rs['unit']}", title=f"{ch}: {names}")
        ax.title.set_fontsize(8)
        ax.grid(alpha=0.3)
    for ax in axs.ravel()[len(chans):]:
        ax.axis("off")
    if chans:
        axs.ravel()[0].legend(fontsize=6)
    fig.suptitle("Step-bias residuals before/after vs temperature (twin: polynomial, no hysteresis)", fontsize=9)
    fig.tight_layout()
    fig.savefig(out.file("fig_residuals.png"), dpi=110)
    plt.close(fig)
    return "fig_residuals.png"


def _figure_tilt(out, d: dict, key: str = "axes", prefix: str = "acc_", unit: str = "m/s²") -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 3.5))
    axes = list(d[key])
    before = [d[key][a]["fit_before"]["sigma_res"] for a in axes]
    after = [d[key][a]["fit_after"]["sigma_res"] for a in axes]
    xx = np.arange(len(axes))
    ax.bar(xx - 0.2, before, 0.4, label="nominal model")
    ax.bar(xx + 0.2, after, 0.4, label="with the effects found")
    ax.set_xticks(xx, [f"{prefix}{a}" for a in axes])
    ax.set(ylabel=f"σ_res of segment means, {unit}" + (" (whitened)" if key == "gyros" else ""),
           title="Fit before and after")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out.file("fig_diagnosis.png"), dpi=110)
    plt.close(fig)
    return "fig_diagnosis.png"


def _rrd(path, rec: Recording, d: dict):
    if d.get("kind") in ("tilt_table", "turn_table", "thermal"):
        from imurig.viz import RrdWriter, log_text

        with RrdWriter(path, recording_name="diagnosis", overwrite=True) as w:
            log_text(w, "summary", "# Diagnosis\n\n" + "\n".join(f"- **{r[1]}** ({r[0]}): {r[2]}"
                                                                     for r in _findings_rows(d)))
        return
    from imurig.viz import RrdWriter, log_scalars, log_text

    rows = np.array(d["rows"])
    dial = np.degrees(np.abs(rec.channels["rate_dial"][rows]))
    rate = np.degrees(2 * np.pi / rec.channels["measured_round"][rows])
    f = d["rate_factor"]["factor"] if d.get("rate_factor") else 1.0
    t = rec.time_s[rows]
    with RrdWriter(path, recording_name="diagnosis", overwrite=True) as w:
        log_scalars(w, "signals/rate/recording", t, {"rate": rate}, {"rate": "deg/s"})
        log_scalars(w, "signals/rate/twin", t, {"rate": dial}, {"rate": "deg/s"})
        mean_short = d["shortfall"]["mean_shortfall"]
        log_scalars(w, "signals/rate/corrected_twin", t, {"rate": dial * f * (1 - mean_short)}, {"rate": "deg/s"})
        log_text(w, "summary", "# Diagnosis\n\n" + "\n".join(f"- **{r[1]}** ({r[0]}): {r[2]}" for r in _findings_rows(d)))


def run(rec: Recording, out_dir, overwrite: bool = False, seed: int = 0, twin_model: str = "physical",
        earth_rate: bool = True) -> dict:
    if rec.meta.get("rig") == "mag_rig":  # magnetometer recordings: own report (imurig.diagnose.magnetometer)
        from imurig.diagnose.magnetometer import TWIN_MODELS, run as run_magnetometer

        return run_magnetometer(rec, out_dir, overwrite, seed, twin_model if twin_model in TWIN_MODELS else "nominal")
    d = diagnose(rec, seed, twin_model, earth_rate)
    with OutputFolder(out_dir, overwrite=overwrite) as out:
        fig = _figure(out, rec, d)
        _rrd(out.file("diagnosis.rrd"), rec, d)
        rows = _findings_rows(d)
        md = ["# Diagnosis: where the recording and its twin differ\n",
              f"Recording: {rec.meta.get('source', rec.meta.get('rig', '–'))}. Twin: {d.get('twin', '–')}.\n",
              "" if _findings_rows(d) else "No effect passed the thresholds: the recording agrees with its twin.\n",
              "## Findings, beside what the seed says\n",
              md_table(["observable", "effect", "physics left out", "fitted / evidence", "seed"], rows),
              "\n## Fit before and after\n",
              md_table(["channel", "σ_res before", "σ_res after", "R²adj before", "R²adj after", "BIC before",
                        "BIC after", "residual white?"],
                       [[g, e["fit_before"]["sigma_res"], e["fit_after"]["sigma_res"], e["fit_before"]["r2_adj"],
                         e["fit_after"]["r2_adj"], e["fit_before"]["bic"], e["fit_after"]["bic"],
                         e["unexplained"]["white"]] for g, e in (d.get("gyros") or d.get("axes") or d.get("channels")).items()]),
              "\nAn effect is accepted only when its statistic beats the max-statistic threshold simulated "
              "under the noise model over the whole library and all scanned parameters, it improves blocked "
              "cross-validation and lowers BIC; accepted effects are re-checked given each other.\n",
              f"\n![diagnosis]({fig})\n" + ("\n![fit before and after](fig_diagnosis.png)\n"
                                             if fig != "fig_diagnosis.png" else "")]
        out.write_text("report.md", "\n".join(md))
        out.write_json("diagnosis.json", clean_json(d))
    return d
