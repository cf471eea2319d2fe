"""Seed Fig. 4.19 and the markdown table of the SIMONA gyro calibration (:mod:`imurig.calibration.simona`)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from imurig.calibration.simona import GYROS, SEED_CONCLUSION, SimonaCalibration
from imurig.kernel.recording import Recording, atomic_write


# --------------------------------------------------------------------------- plot
def _limits(values, seed_lo: float, seed_hi: float, pad: float = 0.05) -> tuple[float, float]:
    """The seed's axis range, widened (with a margin) only if the data leave it."""
    v = np.concatenate([np.ravel(x) for x in values])
    lo, hi = float(np.min(v)), float(np.max(v))
    span = max(hi - lo, seed_hi - seed_lo)
    return (min(seed_lo, lo - pad * span) if lo < seed_lo else seed_lo,
            max(seed_hi, hi + pad * span) if hi > seed_hi else seed_hi)


def plot_fig_4_19(out_png, real: Recording, virtual: Recording | None = None, gyro: str = "p",
                  rows=None, overwrite: bool = True) -> Path:
    """Reproduce seed Fig. 4.19 for one gyro: rate vs output voltage with the own ("Actual")
    and the manufacturer's (6 mV/(deg/s)) linear calibration, then the residuals of each.

    With ``virtual`` (a row recording in the same format) the figure is a 3x2 grid: left
    "real (seed appendix B)", right "virtual twin", sharing axis limits. Axis limits follow
    the seed (own residuals +-0.2 deg/s, manufacturer residuals 0..8 deg/s) and widen only
    if data fall outside. The PNG is written to a temporary file and renamed, so no partial
    file is left on error. Returns the path.
    """
    import matplotlib  # lazy: matplotlib only when a figure is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if gyro not in GYROS:
        raise ValueError(f"gyro must be one of {GYROS}, got {gyro!r}")
    G = gyro.upper()
    cols = [("real (seed appendix B)", SimonaCalibration(rows).fit(real).summary_[gyro])]
    if virtual is not None:
        cols.append(("virtual twin", SimonaCalibration(rows).fit(virtual).summary_[gyro]))
    vmax = max(float(np.max(f["voltage_V"])) for _, f in cols)
    xlim = (min(0.0, min(float(np.min(f["voltage_V"])) for _, f in cols)), vmax * 1.05)
    rate_lim = _limits([f["reference_rate_dps"] for _, f in cols] + [f["manufacturer_rate_dps"] for _, f in cols],
                       0.0, 80.0)
    own_lim = _limits([f["residuals_dps"] for _, f in cols], -0.2, 0.2)
    mfr_lim = _limits([f["manufacturer_residuals_dps"] for _, f in cols], 0.0, 8.0)

    fig, axs = plt.subplots(3, len(cols), figsize=(5.2 * len(cols), 8.0), squeeze=False)
    xl = f"{G}-Gyro Output / V"
    for j, (title, f) in enumerate(cols):
        V, ref = f["voltage_V"], f["reference_rate_dps"]
        vv = np.linspace(xlim[0], xlim[1], 2)
        a = axs[0, j]
        a.plot(vv, f["beta0_dps"] + f["beta1_dps_per_V"] * vv, "C0-", lw=1.2,
               label=f"Actual ({f['scale_mV_per_dps']:.3f} mV/°/s)")
        a.plot(V, ref, "C0o", ms=4, mfc="none", label="measured (Table B.1 rows)")
        a.plot(vv, vv / (f["manufacturer_scale_mV_per_dps"] * 1e-3), "C3--", lw=1.2,
               label=f"Manufacturer ({f['manufacturer_scale_mV_per_dps']:.3g} mV/°/s)")
        a.set(xlim=xlim, ylim=rate_lim, title=title, xlabel=xl)
        a.legend(loc="upper left", fontsize=8)
        a = axs[1, j]
        a.axhline(0.0, color="0.5", lw=0.6, label="zero")
        a.plot(V, f["residuals_dps"], "C0o-", ms=4, mfc="none", lw=0.6,
               label=f"σ_res = {f['sigma_res_dps']:.3f} °/s")
        a.set(xlim=xlim, ylim=own_lim, xlabel=xl)
        a.legend(loc="lower left", fontsize=8)
        a = axs[2, j]
        a.plot(V, f["manufacturer_residuals_dps"], "C3o-", ms=4, mfc="none", lw=0.6,
               label=f"max |res| = {f['manufacturer_max_abs_dps']:.2f} °/s")
        a.set(xlim=xlim, ylim=mfr_lim, xlabel=xl)
        a.legend(loc="upper left", fontsize=8)
        for a in axs[:, j]:
            a.grid(alpha=0.3)
        if j == 0:
            axs[0, 0].set_ylabel(f"Rotation Rate {G}-Gyro / °/s")
            axs[1, 0].set_ylabel("Residuals actual\ncalibration / °/s")
            axs[2, 0].set_ylabel("Residuals manufacturer\ncalibration / °/s")
    fig.suptitle(f"SIMONA IMU {G}-gyro calibration (cf. seed Fig. 4.19)", fontsize=11)
    fig.tight_layout()
    try:
        return atomic_write(Path(out_png), lambda tmp: fig.savefig(tmp, format="png", dpi=110), overwrite)
    finally:
        plt.close(fig)


# ----------------------------------------------------------------------- markdown
def _pm(v: float, se: float, digits: int = 3) -> str:
    return f"{v:.{digits}f} ± {se:.{digits}f}"


def simona_markdown(real_fit: dict, virtual_fit: dict | None = None) -> str:
    """Markdown table of :attr:`SimonaCalibration.summary_` (real beside virtual if given) and one
    sentence comparing own and manufacturer residuals with the seed's conclusion."""
    srcs = [("real", real_fit)] + ([("virtual", virtual_fit)] if virtual_fit is not None else [])
    quantities = [
        ("own scale factor, mV/(°/s)", lambda f: _pm(f["scale_mV_per_dps"], f["scale_se_mV_per_dps"], 4)),
        ("β0 (rate at 0 V), °/s", lambda f: _pm(f["beta0_dps"], f["beta0_se_dps"], 3)),
        ("σ_res own, °/s", lambda f: f"{f['sigma_res_dps']:.3f}"),
        ("max \\|own res.\\|, °/s", lambda f: f"{f['max_abs_residual_dps']:.3f}"),
        ("max \\|manufacturer res.\\|, °/s", lambda f: f"{f['manufacturer_max_abs_dps']:.2f}"),
    ]
    header = ["gyro"] + [f"{q} ({s})" if len(srcs) > 1 else q for q, _ in quantities for s, _ in srcs]
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    for g in GYROS:
        cells = [g.upper()] + [fn(fit[g]) for _, fn in quantities for _, fit in srcs]
        lines.append("| " + " | ".join(cells) + " |")
    sentences = []
    for s, fit in srcs:
        ratio = min(fit[g]["manufacturer_max_abs_dps"] / fit[g]["max_abs_residual_dps"] for g in GYROS)
        own = max(fit[g]["max_abs_residual_dps"] for g in GYROS)
        mfr = max(fit[g]["manufacturer_max_abs_dps"] for g in GYROS)
        sentences.append(f"{s}: own-calibration residuals reach at most {own:.3f} °/s against {mfr:.2f} °/s "
                         f"for the manufacturer's 6 mV/(°/s) (at least {ratio:.0f}× smaller for every gyro)")
    all_ok = all(min(fit[g]["manufacturer_max_abs_dps"] / fit[g]["max_abs_residual_dps"] for g in GYROS) >= 10
                 for _, fit in srcs)
    verdict = "which agrees with" if all_ok else "which does not clearly reproduce"
    return ("\n".join(lines) + "\n\n" + "; ".join(sentences)
            + f", {verdict} the seed's conclusion: \"{SEED_CONCLUSION}\".\n")

