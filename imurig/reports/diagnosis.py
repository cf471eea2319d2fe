"""`imurig diagnose`: report folder with report.md, diagnosis.json, figures and an .rrd that
overlays the recording, the nominal twin and the corrected twin."""
from __future__ import annotations

import numpy as np

from imurig.diagnose.rate_table import SEED_SAYS, diagnose_rate_rows
from imurig.kernel.errors import RecordingError
from imurig.kernel.recording import Recording
from imurig.kernel.outputs import OutputFolder, clean_json
from imurig.reports.common import md_table


def effect_steps(y: np.ndarray, X0: np.ndarray, names0: list, candidates: list, diag, cov: np.ndarray | None = None,
                 weights: np.ndarray | None = None) -> dict:
    """The fit before and after each accepted effect, for the report.

    Rebuilds the engine's final model (:func:`imurig.diagnose.engine.select_effects`) step by
    step: the nominal design X0 (m, p0), then each accepted effect's columns C_k(theta_k) in the
    order accepted, each at its final scan value. Every fit is made in the space the engine
    tests in (whitened by the Cholesky factor of ``cov`` and by sqrt(``weights``), as the engine
    does), so sigma_res, R^2adj, BIC and AIC are the engine's. Per step: those statistics, the
    residual RMS in the observable's own units (unwhitened, y - X b), the sequential share of
    the nominal residual SS the effect removes, (SS_{k-1} - SS_k) / SS_0 (the shares sum to
    1 - SS_after / SS_0), and its unique share in the final model, (SS_without_k - SS_final) / SS_0.

    Returns {"steps": [...], "resid_before": (m,), "resid_after": (m,) unwhitened,
    "columns": {effect: C_k (m, k)}, "coef": {term: estimate} of the final fit}.
    """
    import scipy.linalg

    from imurig.calibration.regression import fit_ols

    y = np.asarray(y, float)
    L = np.linalg.cholesky(0.5 * (cov + cov.T)) if cov is not None else None
    sw = np.sqrt(np.asarray(weights, float)) if weights is not None else None

    def W(A):
        A = np.asarray(A, float)
        if L is not None:
            A = scipy.linalg.solve_triangular(L, A, lower=True)
        if sw is not None:
            A = A * (sw if A.ndim == 1 else sw[:, None])
        return A

    lookup = {c.name: c for c in candidates}
    yw = W(y)
    X, names = np.asarray(X0, float), list(names0)
    blocks, cols = [X], {}
    for f in diag.findings:
        C = lookup[f.name].design(f.theta)
        cols[f.name] = C
        blocks.append(C)
        names += [f"{f.name}:{p}" for p in lookup[f.name].param_names][: C.shape[1]]
    fits, designs = [], []
    for k in range(len(blocks)):
        Xk = np.column_stack(blocks[:k + 1])
        fits.append(fit_ols(W(Xk), yw, names[:Xk.shape[1]]))
        designs.append(Xk)
    ss0, ssf = fits[0].ss_res, fits[-1].ss_res
    steps = []
    for k, (fr, Xk) in enumerate(zip(fits, designs)):
        r = y - Xk @ fr.coef_
        st = {"after_effect": None if k == 0 else diag.findings[k - 1].name, "sigma_res": fr.sigma_res,
              "r2_adj": fr.r2_adj, "bic": fr.bic, "aic": fr.aic, "n": fr.n, "p": fr.p, "ss_res": fr.ss_res,
              "residual_rms": float(np.sqrt(np.mean(r**2))),
              "variance_share": 0.0 if k == 0 else float((fits[k - 1].ss_res - fr.ss_res) / ss0)}
        if k:
            keep = [b for i, b in enumerate(blocks) if i != k]
            Xo = np.column_stack(keep)
            ro = W(y) - W(Xo) @ np.linalg.lstsq(W(Xo), yw, rcond=None)[0]
            st["unique_variance_share"] = float((ro @ ro - ssf) / ss0)
        steps.append(st)
    return {"steps": steps, "resid_before": y - designs[0] @ fits[0].coef_,
            "resid_after": y - designs[-1] @ fits[-1].coef_, "columns": cols,
            "coef": dict(zip(fits[-1].names, map(float, fits[-1].coef_)))}


#: the twin options each kind of recording understands (``meta["diagnose_twin"]``, ``--twin-model``...)
TWIN_OPTIONS = {"tilt_table": {"twin_model", "dynamics", "skew_in_twin"}, "turn_table": {"earth_rate"},
                "thermal": set(), "rate_table_rows": set(), "magnetometer": {"twin_model"}}


def record_kind(rec: Recording) -> str:
    """The kind of recording the diagnosis dispatches on (a key of :data:`TWIN_OPTIONS`)."""
    if rec.meta.get("rig") == "mag_rig":
        return "magnetometer"
    if rec.meta.get("rig") == "turn_table" and rec.meta.get("row_recording"):
        return "rate_table_rows"
    if {"attitude", "step", "branch"} <= set(rec.segments):
        return "thermal"
    if rec.meta.get("rig") == "turn_table" or "rate_dial" in rec.segments:
        return "turn_table"
    if rec.meta.get("rig") == "tilt_table" or {"theta", "phi"} <= set(rec.segments):
        return "tilt_table"
    raise RecordingError(f"diagnosis of '{rec.meta.get('rig', 'unknown')}' recordings is not implemented yet; "
                         "this version diagnoses tilt-table, turn-table, thermal-chamber and magnetometer "
                         "recordings and turn-table row recordings in the appendix-B format "
                         "(imurig.calibration.simona.read_simona)")


def twin_options(rec: Recording, twin: dict | None = None, **given) -> dict:
    """The twin options for ``rec``: ``twin`` (default: the recording's own ``meta["diagnose_twin"]``,
    written by ``imurig concealed write``), overridden by the ``given`` ones that are not None.
    Refuses an option or a twin model that does not fit the recording's kind (ConfigError)."""
    from imurig.kernel.errors import ConfigError

    kind = record_kind(rec)
    opts = dict(rec.meta.get("diagnose_twin") or {}) if twin is None else dict(twin)
    opts.update({k: v for k, v in given.items() if v is not None})
    unknown = set(opts) - TWIN_OPTIONS[kind]
    if unknown:
        flags = {"twin_model": "--twin-model", "earth_rate": "--twin-without-earth-rate"}
        raise ConfigError(f"twin option(s) {', '.join(flags.get(k, k) for k in sorted(unknown))} do not apply to a "
                          f"{kind.replace('_', '-')} recording; it takes "
                          + (", ".join(sorted(flags.get(k, k) for k in TWIN_OPTIONS[kind])) or "no twin options"))
    if "twin_model" in opts:
        if kind == "magnetometer":
            from imurig.diagnose.magnetometer import TWIN_MODELS
        else:
            from imurig.diagnose.tilt_table import TWIN_MODELS
        if opts["twin_model"] not in TWIN_MODELS:
            raise ConfigError(f"twin model '{opts['twin_model']}' does not fit a {kind.replace('_', '-')} recording; "
                              f"choose one of {', '.join(TWIN_MODELS)}")
    return opts


def diagnose(rec: Recording, seed: int = 0, twin_model: str | None = None, earth_rate: bool | None = None,
             twin: dict | None = None) -> dict:
    """Dispatch on the recording's kind (:func:`record_kind`): tilt-table recordings (twin model
    ``twin_model``, default 'physical'; the slews too), turn-table recordings (twin with or without
    the Earth's rate), thermal-chamber recordings, turn-table row recordings (appendix B) and
    magnetometer recordings (twin 'nominal' or 'calibrated'). Options: :func:`twin_options`."""
    kind = record_kind(rec)
    o = twin_options(rec, twin, twin_model=twin_model, earth_rate=earth_rate)
    rng = np.random.default_rng(seed)
    if kind == "rate_table_rows":
        return {"kind": kind, **diagnose_rate_rows(rec, rng)}
    if kind == "thermal":
        from imurig.diagnose.thermal import diagnose_thermal

        return {"kind": kind, **diagnose_thermal(rec, rng)}
    if kind == "turn_table":
        from imurig.diagnose.turn_table import diagnose_turn_table

        return {"kind": kind, **diagnose_turn_table(rec, rng, earth_rate=o.get("earth_rate", True))}
    if kind == "magnetometer":
        from imurig.diagnose.magnetometer import diagnose_magnetometer

        return {"kind": kind, **diagnose_magnetometer(rec, rng, twin_model=o.get("twin_model", "nominal"))}
    from imurig.diagnose.tilt_table import diagnose_tilt_table

    return {"kind": kind, **diagnose_tilt_table(rec, rng, twin_model=o.get("twin_model", "physical"),
                                                dynamics=o.get("dynamics", True),
                                                skew_in_twin=o.get("skew_in_twin", True))}


def _engine_row(where: str, f: dict, seed_says: dict) -> list:
    """One report row for a finding of the selection engine."""
    ps = "; ".join(f"{p['name']} = {p['estimate']:.4g} ± {p['std_error']:.2g}" for p in f["parameters"])
    alias = f"; indistinguishable from {f['indistinguishable_from']}" if f.get("indistinguishable_from") else ""
    return [where, f["effect"], f["physics"], (f"{ps}; F = {f['statistic']:.1f} > {f['threshold']:.1f}; share "
            f"{f['variance_share'] * 100:.0f} % of the residual{alias}"), seed_says.get(f["effect"], "–")]


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
                             (f"noise up to {sc['peak_to_median_noise']:.2f}× the median at table angles "
                             f"{', '.join(f'{x:.0f}' for x in sc['angles_deg'])} deg; p = {sc['p_value']:.2g}"),
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
                     (f"{ps}; {f['scan']}; mean shortfall {d['shortfall']['mean_shortfall'] * 100:.2f} %; "
                     f"F = {f['statistic']:.1f} > {f['threshold']:.1f}"), SEED_SAYS.get(f["effect"], "–")])
    tr = d["timer_resolution"]
    rows.append(["rate (stopwatch)", tr["effect"], tr["physics"],
                 (f"residual RMS at high rates {tr['rate_residual_rms_dps_high_rates']:.3f} °/s vs "
                 f"{tr['rate_residual_rms_dps_low_rates']:.3f} °/s at low rates"), SEED_SAYS["timer_quantisation"]])
    rc = d.get("range_change_by_resolution")
    if rc:
        rows.append(["gyro voltages (display)", "instrument_range_change",
                     "the voltmeter switched to a coarser range (autoscale)",
                     (f"readings on a {rc['resolution_after_V']:g} V grid from row {rc['first_row']} on (last "
                     f"{rc['rows_after']} rows), {rc['resolution_before_V']:g} V before"),
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


def _figures(out, rec: Recording, d: dict) -> list[tuple[str, str]]:
    """Write the report's figures; returns [(file, caption)]."""
    kind = d.get("kind")
    if kind == "tilt_table":
        figs = [(_figure_tilt(out, d), "Residual sigma of the position means before and after.")]
        figs.append((_figure_tilt_positions(out, d), ("Position means: residuals before (open) and after (dots) "
                     "against the revealing variable of each accepted effect (one panel per channel and effect).")))
        if d.get("dynamic", {}).get("residuals"):
            figs.append((_figure_tilt_slews(out, d), ("Slews against the dynamic twin: residuals (20 Hz block means) "
                         "before and after in time, and against the revealing variable of the effect.")))
        return figs
    if kind == "turn_table":
        return [(_figure_tilt(out, d, key="gyros", prefix="gyro_", unit="rad/s"),
                 "Residual sigma of the whole-round means before and after (GLS-whitened)."),
                (_figure_turn(out, d), ("Whole-round means: residuals before and after against the table rate "
                 "(gyro on the table axis or not); sample noise against the table angle (slip rings)."))]
    if kind == "thermal":
        return [(_figure_tilt(out, d, key="channels", prefix="", unit="SI"),
                 "Residual sigma of the step biases before and after (AR(1)-whitened)."),
                (_figure_thermal_residuals(out, d), "Step-bias residuals before and after against the temperature.")]
    return [(_figure_rows(out, rec, d), "Rate-table rows: where, and the residuals before and after against the rate.")]


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _effect_title(ch: str, e: dict, effects: list[str] | None = None) -> str:
    names = effects if effects is not None else [f["effect"] for f in e.get("findings", [])]
    return f"{ch}: " + (", ".join(names) if names else "no effect accepted")


def _figure_tilt_positions(out, d: dict) -> str:
    """Tilt-table position means: per channel (rows) and accepted effect parameter (columns), the
    residual before (open circles) and after (dots) against that effect's column (crosstalk: the
    neighbour channel; drift: the temperature; misalignment: the other axis; nonlinearity: f^2),
    with the fitted effect term (line, on the before residual). A channel with no accepted effect
    is plotted against the elapsed time."""
    plt = _plt()
    axes = list(d["axes"])
    ncol = max([2] + [len(d["axes"][a].get("residuals", {}).get("variables", [])) for a in axes])
    fig, axs = plt.subplots(len(axes), ncol, figsize=(4.2 * ncol + 0.5, 2.9 * len(axes)), squeeze=False)
    for i, a in enumerate(axes):
        e = d["axes"][a]
        rs = e["residuals"]
        r0, r1 = np.asarray(rs["before"]) * 1e3, np.asarray(rs["after"]) * 1e3
        variables = rs["variables"] or ["time", "reading"]
        for k in range(ncol):
            ax = axs[i, k]
            if k >= len(variables):
                ax.axis("off")
                continue
            v = variables[k]
            if isinstance(v, str):  # no effect accepted: against the time and the channel's own reading
                x, xl = ((np.asarray(rs["elapsed_h"]), "time since the first position, h") if v == "time" else
                         (np.asarray(rs["reading_m_s2"]), f"indicated specific force acc_{a}, m/s²"))
                title = _effect_title(f"acc_{a}", e)
                v = None
            else:
                x, xl = np.asarray(v["values"]), f"{v['label']}, {v['unit']}"
                f = next(ff for ff in e["findings"] if ff["effect"] == v["effect"])
                pr = next(pp for pp in f["parameters"] if pp["name"].endswith(v["parameter"]))
                title = (f"acc_{a}: {v['effect']} {v['parameter']} = {pr['estimate']:.3g} ± {pr['std_error']:.2g}"
                         f" (share {f['variance_share'] * 100:.0f} %)")
            ax.plot(x, r0, "o", ms=3.5, mfc="none", label="before (nominal twin)")
            ax.plot(x, r1, ".", ms=4, label="after (effects accepted)")
            if v is not None:  # r_before - r_after = (I - H_0) C c exactly: the effects as the nominal fit leaves them
                ax.plot(x, r0 - r1, "x", ms=3.5, color="k", alpha=0.6, label="before − after: the fitted effects "
                        "left in the nominal residual")
            ax.axhline(0, color="0.6", lw=0.5)
            ax.set_xlabel(xl, fontsize=8)
            ax.set_ylabel("residual, mm/s²", fontsize=8)
            ax.set_title(title, fontsize=8)
            ax.grid(alpha=0.3)
            ax.tick_params(labelsize=7)
        axs[i, 0].legend(fontsize=6)
    fig.suptitle("Tilt-table position means: residual before and after\n(twin's reference − calibrated recording)",
                 fontsize=9)
    fig.tight_layout()
    fig.savefig(out.file("fig_residuals.png"), dpi=110)
    plt.close(fig)
    return "fig_residuals.png"


def _slew_variable(dyn: dict, j: int) -> tuple[np.ndarray, str, str]:
    """The revealing variable of axis j's slew residual: the twin's df/dt for a time delay, else
    the accepted effect's own contribution, else (no effect) df/dt. Returns (x, label, title)."""
    rs = dyn["residuals"]
    ax = "xyz"[j]
    mine = [f for f in dyn["findings"] if f["effect"] == "time_delay" and f.get("channel") == ax]
    joint = [f for f in dyn["findings"] if f.get("channel") == "acc"]
    dfdt = np.asarray(rs["df_twin_dt_m_s3"])[:, j]
    if mine:
        p = mine[0]["parameters"][0]
        return dfdt, "twin's df/dt, m/s³", (f"acc_{ax}: time_delay τ = {p['estimate'] * 1e6:.1f} ± "
                                            f"{p['std_error'] * 1e6:.1f} µs")
    if joint:
        f = joint[0]
        x = np.asarray(rs["effect_contribution_m_s2"][f["effect"]])[:, j] * 1e3
        if f["effect"] == "lever_arm":
            est = ", ".join(f"{p['estimate'] * 1e3:.2f}" for p in f["parameters"])
            se = ", ".join(f"{p['std_error'] * 1e3:.2f}" for p in f["parameters"])
            ps = f"dr = ({est}) ± ({se}) mm"
        else:
            ps = ", ".join(f"{p['name'].split(':')[-1]} = {p['estimate']:.3g} ± {p['std_error']:.1g}"
                           for p in f["parameters"])
        return x, f"fitted {f['effect']} acceleration on acc_{ax}, mm/s²", f"acc_{ax}: {f['effect']} {ps}"
    return dfdt, "twin's df/dt, m/s³ (the time-delay variable)", f"acc_{ax}: no effect accepted"


def _binned(ax, x, y, color, bins: int = 15) -> None:
    """Means of y in equal-count bins of x (a thick line): the trend through the scatter."""
    if x.size < 3 * bins:
        return
    order = np.argsort(x)
    xs, ys = np.array_split(x[order], bins), np.array_split(y[order], bins)
    ax.plot([b.mean() for b in xs], [b.mean() for b in ys], "-", color=color, lw=2.2)


def _figure_tilt_slews(out, d: dict, span_s: float = 40.0) -> str:
    """Tilt-table slews: per axis, the residual (recording − twin, 20 Hz block means) before and
    after the accepted effects in time over the first ``span_s`` s of slews (left; rests shaded)
    and, for every block during a slew, against the revealing variable (right: the twin's df/dt
    for a time delay, the fitted lever-arm acceleration...), with bin means as thick lines."""
    plt = _plt()
    dyn = d["dynamic"]
    rs = dyn["residuals"]
    t = np.asarray(rs["time_s"])
    mv = np.asarray(rs["moving"], bool)
    r0, r1 = np.asarray(rs["before"]) * 1e3, np.asarray(rs["after"]) * 1e3
    t0 = t[np.flatnonzero(mv)[0]] - 2.0 if mv.any() else t[0]
    win = (t >= t0) & (t <= t0 + span_s)
    fig, axs = plt.subplots(3, 2, figsize=(11.5, 8.5), squeeze=False, gridspec_kw={"width_ratios": [1.5, 1]})
    for j, a in enumerate("xyz"):
        ax = axs[j, 0]
        tw = t[win]
        ax.fill_between(tw, 0, 1, where=~mv[win], color="0.92", transform=ax.get_xaxis_transform(), step="mid",
                        label="table at rest")
        ax.plot(tw, r0[win, j], lw=0.8, label="before (nominal dynamic twin)")
        ax.plot(tw, r1[win, j], lw=0.8, label="after (effects accepted)")
        ax.set(xlabel="time, s", ylabel="residual, mm/s²")
        ax.set_title(f"acc_{a}: residual in time, first {span_s:.0f} s of slews", fontsize=8)
        ax.grid(alpha=0.3)
        x, xl, title = _slew_variable(dyn, j)
        ax = axs[j, 1]
        ax.plot(x[mv], r0[mv, j], "o", ms=2, mfc="none", alpha=0.5, label="before")
        ax.plot(x[mv], r1[mv, j], ".", ms=2, alpha=0.5, label="after")
        _binned(ax, x[mv], r0[mv, j], "C0")
        _binned(ax, x[mv], r1[mv, j], "C1")
        ax.set(xlabel=xl, ylabel="residual, mm/s²")
        ax.set_title(title, fontsize=8)
        ax.grid(alpha=0.3)
    axs[0, 0].legend(fontsize=7, loc="upper right")
    axs[0, 1].legend(fontsize=7)
    fig.suptitle("Tilt-table slews against the dynamic twin: residual = recording − twin (20 Hz block means); "
                 "right: blocks during slews, thick lines = bin means", fontsize=9)
    fig.tight_layout()
    fig.savefig(out.file("fig_residuals_slews.png"), dpi=110)
    plt.close(fig)
    return "fig_residuals_slews.png"


DEG_H = np.degrees(1.0) * 3600.0  # rad/s -> deg/h


def _figure_turn(out, d: dict) -> str:
    """Turn table: per gyro, the whole-round-mean residual (°/h) before and after against the
    table rate (symmetric log), marked by whether the gyro is on the table axis (up: ▲, down: ▼)
    or across it (●): the Earth's rate and a g-sensitivity offset the on-axis steps only. Right:
    the sample noise against the table angle (slip rings) with the median level."""
    plt = _plt()
    gyros = list(d["gyros"])
    fig, axs = plt.subplots(len(gyros), 3, figsize=(14, 3.2 * len(gyros)), squeeze=False)
    for i, g in enumerate(gyros):
        e = d["gyros"][g]
        rs = e["residuals"]
        rate = np.degrees(np.asarray(rs["table_rate_rad_s"]))
        on = np.asarray(rs["on_axis"])
        r0, r1 = np.asarray(rs["before"]) * DEG_H, np.asarray(rs["after"]) * DEG_H
        f = e["findings"]
        ttl = _effect_title(f"gyro_{g}", e)
        if f:
            p = f[0]["parameters"][0]
            ttl += f" ({p['name'].split(':')[-1]} = {p['estimate'] * DEG_H:.3g} ± {p['std_error'] * DEG_H:.2g} °/h)"
        # left: against the revealing variable of the Earth's rate / g-sensitivity: on the axis or not
        ax = axs[i, 0]
        jit = (np.argsort(np.argsort(rate)) / max(rate.size - 1, 1) - 0.5) * 0.3
        ax.plot(on + jit - 0.04, r0, "o", ms=3.5, mfc="none", color="C0", label="before")
        ax.plot(on + jit + 0.04, r1, ".", ms=5, color="C1", label="after")
        for lev in np.unique(on):
            sel = on == lev
            ax.plot([lev - 0.2, lev + 0.2], [r0[sel].mean()] * 2, "-", color="C0", lw=2.5)
            ax.plot([lev - 0.2, lev + 0.2], [r1[sel].mean()] * 2, "-", color="C1", lw=2.5)
        ax.set_xticks([-1, 0, 1], ["on the axis,\ndown", "across\nthe axis", "on the axis,\nup"])
        ax.set_xlim(-1.5, 1.5)
        ax.axhline(0, color="0.6", lw=0.5)
        ax.set(ylabel="residual, °/h")
        ax.set_title(ttl, fontsize=8)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=6, title="bars: group means", title_fontsize=6)
        # middle: against the table rate
        ax = axs[i, 1]
        ax.plot(rate, r0, "o", ms=3.5, mfc="none", color="C0", label="before")
        ax.plot(rate, r1, ".", ms=5, color="C1", label="after")
        ax.set_xscale("symlog", linthresh=1.0)
        ax.axhline(0, color="0.6", lw=0.5)
        ax.set(xlabel="table rate, °/s", ylabel="residual, °/h")
        ax.set_title(f"gyro_{g}: whole-round means against the table rate", fontsize=8)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=6)
        ax = axs[i, 2]
        sc = e.get("scatter", {})
        if sc.get("tested"):
            nb = np.asarray(sc["noise_V_by_angle_bin"]) * 1e6
            ang = (np.arange(nb.size) + 0.5) * sc["bin_deg"]
            ax.plot(ang, nb, "o-", ms=3, label="recording")
            ax.axhline(np.median(nb), color="C1", ls="--", label="twin: the same noise at every angle")
            fs = sc.get("finding")
            ax.set_title(f"gyro_{g} sample noise: " + ("slip_ring_noise" if fs else "no effect accepted")
                         + f" (Brown-Forsythe p = {sc['p_value']:.2g})", fontsize=8)
            ax.legend(fontsize=6)
        else:
            ax.axis("off")
        ax.set(xlabel="table angle, °", ylabel="noise (robust σ), µV")
        ax.grid(alpha=0.3)
    fig.suptitle("Turn table: residual (twin's reference − calibrated recording) before and after", fontsize=9)
    fig.tight_layout()
    fig.savefig(out.file("fig_residuals.png"), dpi=110)
    plt.close(fig)
    return "fig_residuals.png"


def _figure_rows(out, rec: Recording, d: dict) -> str:
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
    """The .rrd: recording, twin and corrected twin overlaid per channel (entities
    ``signals/<channel>/<observable>/{recording,twin,corrected_twin}``) and the findings as text."""
    from imurig.reports.viz import RrdWriter, log_scalars, log_text

    summary = "# Diagnosis\n\n" + ("\n".join(f"- **{r[1]}** ({r[0]}): {r[2]}" for r in _findings_rows(d))
                                    or "No effect accepted: the recording agrees with its twin.")
    with RrdWriter(path, recording_name="diagnosis", overwrite=True) as w:
        for ent, t, series, unit in _overlays(rec, d):
            log_scalars(w, ent, t, series, {k: unit for k in series})
        log_text(w, "summary", summary)


def _overlays(rec: Recording, d: dict):
    """(entity prefix, time (n,) s, {"recording", "twin", "corrected_twin": (n,)}, unit) per channel
    and observable. Residual conventions as in each diagnosis' ``residuals``: for the tilt and
    turn tables' position and round means the twin is the reference and the recording is the
    reading through the calibration, so twin − recording = residual before and corrected twin −
    recording = residual after."""
    kind = d.get("kind")
    out = []
    if kind == "tilt_table":
        for a, e in d["axes"].items():
            rs = e["residuals"]
            y, r0, r1 = (np.asarray(rs[k]) for k in ("reference", "before", "after"))
            out.append((f"signals/acc_{a}/position_means", np.asarray(rs["elapsed_h"]) * 3600.0,
                        {"recording": y - r0, "twin": y, "corrected_twin": y - r0 + r1}, "m/s^2"))
        rs = d.get("dynamic", {}).get("residuals")
        if rs:
            t = np.asarray(rs["time_s"])
            for j, a in enumerate("xyz"):
                out.append((f"signals/acc_{a}/slews", t, {k: np.asarray(rs[k])[:, j] for k in
                                                          ("recording", "twin", "corrected_twin")}, "m/s^2"))
    elif kind == "turn_table":
        for g, e in d["gyros"].items():
            rs = e["residuals"]
            y, r0, r1 = (np.asarray(rs[k]) for k in ("reference", "before", "after"))
            out.append((f"signals/gyro_{g}/round_means", np.asarray(rs["time_s"]),
                        {"recording": y - r0, "twin": y, "corrected_twin": y - r0 + r1}, "rad/s"))
    elif kind == "thermal":
        for ch, e in d["channels"].items():
            rs = e["residuals"]
            out.append((f"signals/{ch}/step_bias", np.asarray(rs["mid_time_h"]) * 3600.0,
                        {k: np.asarray(rs[k]) for k in ("recording", "twin", "corrected_twin")}, rs["unit"]))
    elif kind == "rate_table_rows":
        rows = np.array(d["rows"])
        dial = np.degrees(np.abs(rec.channels["rate_dial"][rows]))
        rate = np.degrees(2 * np.pi / rec.channels["measured_round"][rows])
        f = d["rate_factor"]["factor"] if d.get("rate_factor") else 1.0
        out.append(("signals/rate", rec.time_s[rows], {"recording": rate, "twin": dial,
                                                        "corrected_twin": dial * f * (1 - d["shortfall"]["mean_shortfall"])},
                    "deg/s"))
    return out


def with_aic(stats: dict) -> dict:
    """``stats`` (sigma_res, r2_adj, bic, n, p) with the AIC added where it is missing: both use the
    same Gaussian log-likelihood, so AIC = BIC - p ln n + 2 p."""
    if isinstance(stats, dict) and "aic" not in stats and {"bic", "n", "p"} <= set(stats) and stats["bic"] is not None:
        stats["aic"] = float(stats["bic"] - stats["p"] * np.log(stats["n"]) + 2 * stats["p"])
    return stats


def fit_entries(d: dict) -> list[tuple[str, dict, str]]:
    """(observable, engine entry with fit_before/fit_after[/fit_steps], unit and space) per fitted
    observable of a diagnosis, AIC filled in."""
    kind = d.get("kind")
    out = []
    if kind == "tilt_table":
        out += [(f"acc_{a} position means", e, "m/s², ordinary least squares") for a, e in d["axes"].items()]
        if "fit_before" in d.get("dynamic", {}):
            out.append(("acc slews (x, y, z stacked)", d["dynamic"], ("σ_res: unit innovations (AR(1)-whitened, "
                        "nuisance projected out); RMS: m/s²")))
    elif kind == "turn_table":
        out += [(f"gyro_{g} whole-round means", e, "rad/s, GLS-whitened by the gyro noise model")
                for g, e in d["gyros"].items()]
    elif kind == "thermal":
        out += [(f"{ch} step biases", e, f"{e.get('residuals', {}).get('unit', 'SI')}, AR(1)-whitened")
                for ch, e in d["channels"].items()]
    elif kind == "magnetometer":
        out.append(("mag x, y, z block means (joint)", d["magnetometer"], "nT, ordinary least squares"))
    else:
        if "fit_before" in d.get("shortfall", {}).get("diagnosis", {}):
            out.append(("rate shortfall (stopwatch)", d["shortfall"]["diagnosis"], "relative rate, weighted"))
        if "fit_before" in d.get("voltmeter", {}):
            out.append(("gyro voltages (one voltmeter, joint)", d["voltmeter"], "V, whitened"))
        out += [(f"gyro {g} voltage", e, "V, weighted") for g, e in d.get("gyros", {}).items() if "fit_before" in e]
    for _, e, _ in out:
        with_aic(e["fit_before"])
        with_aic(e["fit_after"])
    return out


def _rms(e: dict) -> list:
    """Residual RMS before and after in the observable's own unit (the residual arrays where the
    diagnosis keeps them, else the unwhitened fit steps)."""
    rs = e.get("residuals", {})
    b, a = (rs.get(k, rs.get(k + "_V")) for k in ("before", "after"))
    if b is not None and a is not None:
        return [float(np.sqrt(np.mean(np.square(b)))), float(np.sqrt(np.mean(np.square(a))))]
    if e.get("fit_steps"):
        return [e["fit_steps"][0]["residual_rms"], e["fit_steps"][-1]["residual_rms"]]
    return ["–", "–"]


def fit_tables(d: dict) -> list[str]:
    """report.md sections: the fit before and after per observable, and step by step per effect."""
    ents = fit_entries(d)
    md = ["\n## Fit before and after\n",
          ("σ_res, R²adj, BIC and AIC in the space the effects are tested in (the unit column says which); "
          "residual RMS in the observable's own unit.\n"),
          md_table(["observable", "unit / space", "σ_res before", "σ_res after", "RMS before", "RMS after",
                    "R²adj before", "R²adj after", "BIC before", "BIC after", "AIC before", "AIC after",
                    "residual white?"],
                   [[name, unit, e["fit_before"]["sigma_res"], e["fit_after"]["sigma_res"], *_rms(e),
                     e["fit_before"]["r2_adj"], e["fit_after"]["r2_adj"], e["fit_before"]["bic"],
                     e["fit_after"]["bic"], e["fit_before"]["aic"], e["fit_after"]["aic"],
                     e.get("unexplained", {}).get("white", "–")] for name, e, unit in ents])]
    rows = []
    for name, e, _ in ents:
        fs = {f["effect"]: f for f in e.get("findings", [])}
        fs.update({f"{f['effect']}_{f['channel']}": f for f in e.get("findings", []) if len(f.get("channel", "")) == 1})
        for st in e.get("fit_steps", [])[1:]:
            f = fs.get(st["after_effect"], {})
            ps = "; ".join(f"{p['name'].split(':')[-1]} = {p['estimate']:.4g} ± {p['std_error']:.2g}"
                           for p in f.get("parameters", []))
            rows.append([name, st["after_effect"], ps, f"{st['variance_share'] * 100:.1f} %",
                         f"{st.get('unique_variance_share', 0) * 100:.1f} %", st["sigma_res"], st["residual_rms"],
                         st["r2_adj"], st["bic"], st["aic"]])
    if rows:
        md += ["\n## Each accepted effect: parameters and the fit after adding it\n",
               ("Share = the part of the nominal fit's residual sum of squares the effect removes when added in "
               "turn (the shares of one observable sum to 1 − SS_after / SS_before); unique share = what it "
               "removes from the final model. σ_res, RMS, R²adj, BIC, AIC: the fit with the effects up to this "
               "one.\n"),
               md_table(["observable", "effect added", "parameters ± SE", "share", "unique share", "σ_res",
                         "RMS", "R²adj", "BIC", "AIC"], rows)]
    return md


def _indistinguishable_notes(d: dict) -> list[str]:
    """report.md lines for the pairs the data cannot tell apart (whole record and per channel)."""
    notes = [f"- {' / '.join(n['effects'])}: {n['note']}" for n in d.get("indistinguishable", [])]
    for ch, e in (d.get("axes") or d.get("gyros") or d.get("channels") or {}).items():
        pairs = e.get("indistinguishable", [])
        notes += [f"- {ch}: {' / '.join(n['effects'])}: {n['note']}" for n in ([pairs] if isinstance(pairs, dict)
                                                                                  else pairs)]
    return ["\n## Indistinguishable here (the runner-up named, not silently dropped)\n", *notes, ""] if notes else []


def run(rec: Recording, out_dir, overwrite: bool = False, seed: int = 0, twin_model: str | None = None,
        earth_rate: bool | None = None, twin: dict | None = None) -> dict:
    """Diagnose ``rec`` and write report.md, diagnosis.json, the figures and diagnosis.rrd.

    The twin: ``twin`` (default the recording's ``meta["diagnose_twin"]``) overridden by
    ``twin_model`` / ``earth_rate`` when given (see :func:`twin_options`)."""
    if record_kind(rec) == "magnetometer":  # own report (imurig.diagnose.magnetometer)
        from imurig.diagnose.magnetometer import run as run_magnetometer

        o = twin_options(rec, twin, twin_model=twin_model, earth_rate=earth_rate)
        return run_magnetometer(rec, out_dir, overwrite, seed, o.get("twin_model", "nominal"))
    d = diagnose(rec, seed, twin_model, earth_rate, twin)
    fit_entries(d)  # AIC beside BIC
    with OutputFolder(out_dir, overwrite=overwrite) as out:
        figs = _figures(out, rec, d)
        _rrd(out.file("diagnosis.rrd"), rec, d)
        rows = _findings_rows(d)
        md = ["# Diagnosis: where the recording and its twin differ\n",
              f"Recording: {rec.meta.get('source', rec.meta.get('rig', '–'))}. Twin: {d.get('twin', '–')}.\n",
              "" if rows else "No effect accepted: the recording agrees with its twin.\n",
              "## What differs and where, the physics left out, beside what the seed says\n",
              md_table(["observable", "effect", "physics left out", "fitted / evidence", "seed"], rows) if rows else "",
              *_indistinguishable_notes(d),
              *fit_tables(d),
              ("\nAn effect is accepted only when its statistic beats the max-statistic threshold simulated "
              "under the noise model over the whole library and all scanned parameters, it improves blocked "
              "cross-validation and lowers BIC; accepted effects are re-checked given each other.\n"),
              "\n## Figures\n",
              *[f"\n![{cap}]({f})\n\n{cap}\n" for f, cap in figs],
              ("\n`diagnosis.rrd` overlays the recording, the twin and the corrected twin per channel "
              "(`signals/<channel>/<observable>/...`).\n")]
        out.write_text("report.md", "\n".join(md))
        out.write_json("diagnosis.json", clean_json(d))
    return d
