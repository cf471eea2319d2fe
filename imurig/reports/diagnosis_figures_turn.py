"""The turn-table, thermal-chamber and rate-table-row diagnoses' figures: residuals before and
after against the revealing variable (the table rate, on the axis or not, the table angle; the
temperature by branch; the rate)."""
from __future__ import annotations

import numpy as np

from imurig.kernel.recording import Recording
from imurig.reports.diagnosis_figures import effect_title, pyplot


DEG_H = np.degrees(1.0) * 3600.0  # rad/s -> deg/h


def figure_turn(out, d: dict) -> str:
    """Turn table: per gyro, the whole-round-mean residual (°/h) before and after against the
    table rate (symmetric log), marked by whether the gyro is on the table axis (up: ▲, down: ▼)
    or across it (●): the Earth's rate and a g-sensitivity offset the on-axis steps only. Right:
    the sample noise against the table angle (slip rings) with the median level."""
    plt = pyplot()
    gyros = list(d["gyros"])
    fig, axs = plt.subplots(len(gyros), 3, figsize=(14, 3.2 * len(gyros)), squeeze=False)
    for i, g in enumerate(gyros):
        e = d["gyros"][g]
        rs = e["residuals"]
        rate = np.degrees(np.asarray(rs["table_rate_rad_s"]))
        on = np.asarray(rs["on_axis"])
        r0, r1 = np.asarray(rs["before"]) * DEG_H, np.asarray(rs["after"]) * DEG_H
        f = e["findings"]
        ttl = effect_title(f"gyro_{g}", e)
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
            ax.plot([lev - 0.2, lev + 0.2], [r0[sel].mean()] * 2, "-", color="C0", lw=2.5,
                    label="before, group mean")
            ax.plot([lev - 0.2, lev + 0.2], [r1[sel].mean()] * 2, "-", color="C1", lw=2.5,
                    label="after, group mean")
        ax.set_xticks([-1, 0, 1], ["on the axis,\ndown", "across\nthe axis", "on the axis,\nup"])
        ax.set_xlim(-1.5, 1.5)
        ax.axhline(0, color="0.6", lw=0.5, label="zero")
        ax.set(ylabel="residual, °/h")
        ax.set_title(ttl, fontsize=8)
        ax.grid(alpha=0.3)
        by_label = dict(zip(*reversed(ax.get_legend_handles_labels())))  # one entry per label
        ax.legend(by_label.values(), by_label.keys(), fontsize=6, title="bars: group means", title_fontsize=6)
        # middle: against the table rate
        ax = axs[i, 1]
        ax.plot(rate, r0, "o", ms=3.5, mfc="none", color="C0", label="before")
        ax.plot(rate, r1, ".", ms=5, color="C1", label="after")
        ax.set_xscale("symlog", linthresh=1.0)
        ax.axhline(0, color="0.6", lw=0.5, label="zero")
        ax.legend(fontsize=6)
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


def figure_rows(out, rec: Recording, d: dict, findings: list[list]) -> str:
    """Rate-table rows: where (the rate, gyro p against the stopwatch rate), the report rows
    ``findings`` as text, and the residuals before and after against the rate."""
    plt = pyplot()
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
            axs[0, 0].axhline(0, color="k", lw=0.5, label="zero")
    axs[0, 0].set(xscale="log", xlabel="dial rate, °/s", ylabel="rate mismatch, %", title="Where: the rate")
    axs[0, 0].legend(fontsize=7)
    axs[0, 0].grid(alpha=0.3)
    axs[0, 1].axis("off")
    axs[0, 1].text(0, 1, "Findings\n" + "\n".join(f"• {r[1]}: {r[3][:70]}" for r in findings),
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
                                              g.get("fit_after", {}).get("sigma_res", np.nan) * 1e3],
                      label="σ_res of the fit")
        axs[1, 1].legend(fontsize=7)
        axs[1, 1].set(ylabel="σ_res, mV", title="Gyro p fit before and after the effects")
    axs[1, 1].grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out.file("fig_diagnosis.png"), dpi=110)
    plt.close(fig)
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
            axs[0].plot(rr, -2 * s0 * 100 * np.ones_like(rr), "k:", lw=0.8, label="−2σ table setting")
            lab = (f"±2σ with timer σ_T = {te['sigma_T_s'] * 1e3:.1f} ms (LR {te['statistic']:.1f} vs "
                   f"{te['threshold']:.1f})")
            axs[0].plot(rr, 2 * s1 * 100, "r--", lw=0.8, label=lab)
            axs[0].plot(rr, -2 * s1 * 100, "r--", lw=0.8, label="−2σ with the timer")
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


def figure_thermal_residuals(out, d: dict) -> str:
    """Thermal: each channel's step-bias residual before and after against the temperature, heating
    steps filled and cooling steps open (the hysteresis gap shows as two branches)."""
    plt = pyplot()
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
