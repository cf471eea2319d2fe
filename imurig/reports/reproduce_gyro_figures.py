"""Figures of the turn-table items of ``imurig reproduce``, side by side with the seed's: imurig's residuals
drawn inside the seed's axes (the shaded band: the seed's axis limits, which enclose its data; the
dashed lines: the seed's envelope as read, limit - unit / 2). Each function draws from the item's
run (cached in :mod:`imurig.reports.reproduce_gyro`, so the item runs once) and returns the file name.
"""
from __future__ import annotations

import numpy as np

from imurig.kernel.outputs import OutputFolder
from imurig.montecarlo.delft_fit_turn import SEED, seed_values
from imurig.reports import reproduce_gyro as g

TIMER_LABEL = {"adc": "ADC as timer (1 kHz pulse channel)", "gps_mark": "GPS board as timer (mark input)",
               "hp6700": "dedicated chronometer (HP 6700)"}


def _pyplot():
    import matplotlib  # heavy: loaded when figures are drawn, not when the CLI starts

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _seed_band(ax, lo: float, hi: float, read: float | None, label: str) -> None:
    ax.axhspan(lo, hi, color="orange", alpha=0.15, label=f"seed's axis {lo:g} … {hi:g} °/s ({label})")
    if read is not None:
        ax.axhline(read, color="orange", ls="--", lw=1, label=f"seed's envelope as read, ±{read:g} °/s")
        ax.axhline(-read, color="orange", ls="--", lw=1, label="_nolegend_")
    ax.axhline(0.0, color="k", lw=0.5, label="zero")


def figure_4_20(out: OutputFolder) -> str:
    """Fig. 4.20: the r gyro's rates and its residuals per timer, imurig (preset) in the seed's axes."""
    plt = _pyplot()
    ts = g._timer_run()["timers"]
    val, _ = seed_values()
    fig, axs = plt.subplots(4, 1, figsize=(8, 9), sharex=True)
    axs[0].plot(np.arange(1, 16), ts["hp6700"]["rate_dps"], "o-", ms=3, label="imurig: reference rate (HP timer)")
    axs[0].set(ylabel="rotation rate, °/s", title="Fig. 4.20 on the Delft 2005 preset (seed: axes and envelopes)")
    axs[0].legend(fontsize=7, loc="upper left")
    for ax, (k, (fig_key, timer, lim, _)) in zip(axs[1:], [(k, s) for k, s in enumerate(SEED) if s[0] == "fig_4_20"]):
        r = np.asarray(ts[timer]["residual_dps"])
        _seed_band(ax, -lim, lim, float(val[k]), "seed")
        ax.plot(np.arange(1, r.size + 1), r, "o-", ms=3, label=f"imurig, envelope {np.max(np.abs(r)):.3f} °/s")
        ax.set(ylabel="residual, °/s", title=TIMER_LABEL[timer])
        ax.legend(fontsize=6, loc="upper left")
    axs[-1].set_xlabel("measurement (rates 1 … 500 °/s on the dial)")
    fig.tight_layout()
    fig.savefig(out.file("reproduce_fig_4_20.png"), dpi=100)
    plt.close(fig)
    return "reproduce_fig_4_20.png"


def figure_4_21(out: OutputFolder) -> str:
    """Fig. 4.21: the final calibration's residuals per gyro against the rate, in the seed's axes."""
    plt = _pyplot()
    _, cal = g._final_run()
    axes = {"p": (-0.1, 0.3), "q": (-0.2, 0.15), "r": (-0.1, 0.1)}
    fig, axs = plt.subplots(3, 1, figsize=(8, 7), sharex=True)
    for j, a in enumerate("pqr"):
        r = np.degrees(cal.results_[a].residuals_)
        w = np.degrees(np.abs(cal.reference_[:, j]))
        on = w > 1e-3
        _seed_band(axs[j], *axes[a], None, "seed")
        axs[j].plot(w[on], r[on], "o", ms=4, label=f"imurig, {a} on the table")
        axs[j].plot(np.degrees(np.abs(cal.table_rate_[~on])), r[~on], ".", ms=3, color="gray",
                    label=f"imurig, other mountings (envelope {np.max(np.abs(r)):.3f} °/s)")
        axs[j].set_ylabel(f"residual {a.upper()}-gyro, °/s")
        axs[j].legend(fontsize=6, loc="upper left")
    axs[-1].set_xlabel("rotation rate, °/s")
    axs[0].set_title("Fig. 4.21 on the Delft 2005 preset, eq. 4.39-4.41 (seed: shaded axes)")
    fig.tight_layout()
    fig.savefig(out.file("reproduce_fig_4_21.png"), dpi=100)
    plt.close(fig)
    return "reproduce_fig_4_21.png"


def figure_paper_4(out: OutputFolder) -> str:
    """Paper Fig. 4: manufacturer's (left) and own (right) residuals per gyro over the 48 samples."""
    plt = _pyplot()
    _, cal, man = g._paper_run()
    fig, axs = plt.subplots(3, 2, figsize=(9, 7), sharex=True)
    for j, a in enumerate("pqr"):
        rm = np.degrees(man[:, j])
        ro = np.degrees(cal.results_[a].residuals_)
        _seed_band(axs[j, 0], -30.0, 10.0, None, "manufacturer's")
        axs[j, 0].plot(rm, "o-", ms=3, label=f"imurig, manufacturer's ({np.max(np.abs(rm)):.2f} °/s)")
        lim = g.FIG4_OWN[a][0]
        _seed_band(axs[j, 1], -lim, lim, None, "our")
        axs[j, 1].plot(ro, "o-", ms=3, label=f"imurig, own eq. 3 ({np.max(np.abs(ro)):.3f} °/s)")
        axs[j, 0].set_ylabel(f"{a}, °/s")
        for ax in axs[j]:
            ax.legend(fontsize=6, loc="lower left")
    axs[0, 0].set_title("Manufacturer's")
    axs[0, 1].set_title("Our")
    for ax in axs[-1]:
        ax.set_xlabel("samples")
    fig.tight_layout()
    fig.savefig(out.file("reproduce_paper_fig_4.png"), dpi=100)
    plt.close(fig)
    return "reproduce_paper_fig_4.png"


FIGURES = {"fig_4_20": figure_4_20, "fig_4_21": figure_4_21, "paper_fig_4": figure_paper_4}
