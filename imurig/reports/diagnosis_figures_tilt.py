"""The tilt-table diagnosis' figures: the position means' residuals before and after against the
revealing variable of each accepted effect, and the slews' residuals against the dynamic twin."""
from __future__ import annotations

import numpy as np

from imurig.reports.diagnosis_figures import effect_title, pyplot


def figure_tilt_positions(out, d: dict) -> str:
    """Tilt-table position means: per channel (rows) and accepted effect parameter (columns), the
    residual before (open circles) and after (dots) against that effect's column (crosstalk: the
    neighbour channel; drift: the temperature; misalignment: the other axis; nonlinearity: f^2),
    with the fitted effect term (line, on the before residual). A channel with no accepted effect
    is plotted against the elapsed time."""
    plt = pyplot()
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
                title = effect_title(f"acc_{a}", e)
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
            ax.axhline(0, color="0.6", lw=0.5, label="zero")
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


def _binned(ax, x, y, color, bins: int = 15, label: str = "bin means") -> None:
    """Means of y in equal-count bins of x (a thick line): the trend through the scatter."""
    if x.size < 3 * bins:
        return
    order = np.argsort(x)
    xs, ys = np.array_split(x[order], bins), np.array_split(y[order], bins)
    ax.plot([b.mean() for b in xs], [b.mean() for b in ys], "-", color=color, lw=2.2, label=label)


def figure_tilt_slews(out, d: dict, span_s: float = 40.0) -> str:
    """Tilt-table slews: per axis, the residual (recording − twin, 20 Hz block means) before and
    after the accepted effects in time over the first ``span_s`` s of slews (left; rests shaded)
    and, for every block during a slew, against the revealing variable (right: the twin's df/dt
    for a time delay, the fitted lever-arm acceleration...), with bin means as thick lines."""
    plt = pyplot()
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
        _binned(ax, x[mv], r0[mv, j], "C0", label="before, bin means")
        _binned(ax, x[mv], r1[mv, j], "C1", label="after, bin means")
        ax.set(xlabel=xl, ylabel="residual, mm/s²")
        ax.set_title(title, fontsize=8)
        ax.grid(alpha=0.3)
    for ax in axs.flat:
        ax.legend(fontsize=6, loc="upper right")
    fig.suptitle("Tilt-table slews against the dynamic twin: residual = recording − twin (20 Hz block means); "
                 "right: blocks during slews, thick lines = bin means", fontsize=9)
    fig.tight_layout()
    fig.savefig(out.file("fig_residuals_slews.png"), dpi=110)
    plt.close(fig)
    return "fig_residuals_slews.png"
