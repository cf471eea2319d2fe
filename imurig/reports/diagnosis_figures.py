"""The diagnosis report's figures, shared parts: matplotlib, panel titles and the bars of the fit
before and after. The figures of each rig: :mod:`imurig.reports.diagnosis_figures_tilt` and
:mod:`imurig.reports.diagnosis_figures_turn`."""
from __future__ import annotations

import numpy as np


def pyplot():
    """matplotlib.pyplot on the Agg backend (imported when a figure is drawn)."""
    import matplotlib  # lazy: matplotlib only when a report is written

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def effect_title(ch: str, e: dict, effects: list[str] | None = None) -> str:
    names = effects if effects is not None else [f["effect"] for f in e.get("findings", [])]
    return f"{ch}: " + (", ".join(names) if names else "no effect accepted")


def figure_fit_before_after(out, d: dict, key: str = "axes", prefix: str = "acc_", unit: str = "m/s²") -> str:
    """Bars of each channel's residual sigma before and after the accepted effects (fig_diagnosis.png)."""
    plt = pyplot()
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
