"""The magnetometer diagnosis' report: report.md, diagnosis.json, fig_diagnosis.png and an .rrd
that overlays the recording, the nominal twin and the corrected twin (1-s block means, nT).
The diagnosis itself: :mod:`imurig.diagnose.magnetometer`."""
from __future__ import annotations

import numpy as np

from imurig.diagnose.magnetometer import AXES, diagnose_magnetometer
from imurig.diagnose.summary import summarise
from imurig.kernel.recording import Recording
from imurig.kernel.outputs import OutputFolder, clean_json
from imurig.reports.common import md_table
from imurig.reports.diagnosis_figures import pyplot
from imurig.reports.diagnosis_tables import fit_tables


SEED_SAYS = {
    "hard_iron": "4.6, eq. 4.45-4.47: hard iron shifts the circle's centre",
    "soft_iron": "4.6, eq. 4.48-4.51: soft iron and scale factors stretch the circle into an ellipse",
    "misalignment": "4.6, Fig. 4.24: misalignment / soft iron rotate the ellipse's axes",
    "local_field_anomaly": "4.7 / paper 4.3: the calibration assumes the IGRF field at the site",
    "temperature_drift": "4.5: temperature changes bias and scale",
}


def findings_rows(d: dict) -> list[list]:
    """Report rows: observable, effect, physics, fitted/evidence, what the seed says."""
    rows = []
    for f in d["magnetometer"]["findings"]:
        ps = "; ".join(f"{p['name']} = {p['estimate']:.4g} ± {p['std_error']:.2g}" for p in f["parameters"])
        alias = f"; indistinguishable from {f['indistinguishable_from']}" if f.get("indistinguishable_from") else ""
        ev = (f"{ps}; F = {f['statistic']:.1f} > {f['threshold']:.1f}; share {f['variance_share'] * 100:.0f} % "
              f"of the residual{alias}")
        rows.append(["mag x, y, z block means (joint)", f["effect"], f["physics"], ev, SEED_SAYS.get(f["effect"], "–")])
    u = d.get("unexplained_finding")
    if u:
        ev = "; ".join(f"{a}: rms/noise " + ", ".join(f"{k} {v:.2f}" for k, v in w.items())
                       for a, w in u["rms_over_noise_by_manoeuvre"].items())
        rows.append(["mag residual after the fit", u["effect"], u["physics"], ev, "–"])
    return rows


def _figure(out, d: dict) -> str:
    """Per axis the block-mean residual against the nominal twin and against the corrected twin."""
    plt = pyplot()
    s = d["series"]
    t = np.asarray(s["time_s"])
    rec_, tw, cor = (np.asarray(s[k]) for k in ("recording_nT", "twin_nT", "corrected_twin_nT"))
    fig, axs = plt.subplots(3, 2, figsize=(11, 8), sharex=True)
    for j, a in enumerate(AXES):
        axs[j, 0].plot(t, rec_[:, j] - tw[:, j], ".", ms=2, label="recording − nominal twin")
        axs[j, 0].set(ylabel=f"mag_{a} residual, nT")
        axs[j, 1].plot(t, rec_[:, j] - cor[:, j], ".", ms=2, color="C1", label="recording − corrected twin")
        sb = d["noise"]["block_sigma_predicted_nT"][j]
        axs[j, 1].axhspan(-2 * sb, 2 * sb, color="0.85", zorder=0, label="±2σ noise model")
        axs[j, 0].grid(alpha=0.3)
        axs[j, 1].grid(alpha=0.3)
    axs[0, 0].set_title("recording − nominal twin")
    axs[0, 1].set_title("recording − corrected twin (effects found)")
    for ax in axs.ravel():
        ax.legend(fontsize=7, loc="upper right")
    axs[2, 0].set_xlabel("time, s")
    axs[2, 1].set_xlabel("time, s")
    fig.tight_layout()
    fig.savefig(out.file("fig_diagnosis.png"), dpi=110)
    plt.close(fig)
    return "fig_diagnosis.png"


def _rrd(path, d: dict):
    """The .rrd (imurig.reports.diagnosis_rrd): per axis ``signals/mag_<a>/field/{recording,
    twin,corrected_twin}`` in nT and their residuals."""
    from imurig.reports.diagnosis_rrd import write  # lazy: rerun only when a report is written

    s = d["series"]
    t = np.asarray(s["time_s"])
    v = {name: np.asarray(s[key]) for key, name in (("recording_nT", "recording"), ("twin_nT", "twin"),
                                                     ("corrected_twin_nT", "corrected_twin"))}
    overlays = [(f"signals/mag_{a}/field", t, {k: x[:, j] for k, x in v.items()}, "nT") for j, a in enumerate(AXES)]
    write(path, overlays, "# Diagnosis\n\n" + ("\n".join(f"- **{r[1]}**: {r[2]}" for r in findings_rows(d))
                                                 or "No effect accepted: the recording agrees with its twin."))


def run(rec: Recording, out_dir, overwrite: bool = False, seed: int = 0, twin_model: str = "nominal") -> dict:
    """Diagnose ``rec`` and write report.md, diagnosis.json, fig_diagnosis.png, diagnosis.rrd."""
    d = {"kind": "magnetometer", **diagnose_magnetometer(rec, np.random.default_rng(seed), twin_model=twin_model)}
    with OutputFolder(out_dir, overwrite=overwrite) as out:
        fig = _figure(out, d)
        _rrd(out.file("diagnosis.rrd"), d)
        rows = findings_rows(d)
        e = d["magnetometer"]
        md = ["# Diagnosis: where the magnetometer recording and its twin differ\n",
              f"Recording: {rec.meta.get('source', rec.meta.get('rig', '–'))}. Twin: {d['twin']}.\n",
              "" if rows else "No effect passed the thresholds: the recording agrees with its twin.\n",
              "## Findings, beside what the seed says\n",
              md_table(["observable", "effect", "physics left out", "fitted / evidence", "seed"], rows) if rows else "",
              "\n## Indistinguishable\n",
              "\n".join(f"- {' / '.join(n['effects'])}: {n['note']}" for n in d["indistinguishable"]),
              "\n## Fit before and after (1-s block means)\n",
              md_table(["axis", "σ before, nT", "σ after, nT", "σ noise model, nT"],
                       [[a, v["sigma_before_nT"], v["sigma_after_nT"], v["sigma_predicted_nT"]]
                        for a, v in d["per_axis"].items()]),
              (f"\nJoint: R²adj {e['fit_before']['r2_adj']:.6f} → {e['fit_after']['r2_adj']:.6f}, BIC "
               f"{e['fit_before']['bic']:.1f} → {e['fit_after']['bic']:.1f}.\n"),
              *fit_tables(d),
              "\n## Where: residual RMS per manoeuvre (nT, before → after)\n",
              md_table(["manoeuvre"] + [f"mag_{a}" for a in AXES],
                       [[mn] + [f"{v[a]['rms_before_nT']:.3g} → {v[a]['rms_after_nT']:.3g}" for a in AXES]
                        for mn, v in d["locate"].items()]),
              ("\nAn effect is accepted only when its statistic beats the max-statistic threshold simulated under "
               "the noise model over the whole library, it improves blocked cross-validation and lowers BIC. "
               "The residual left is then checked against the noise model (variance, whiteness); a failure is "
               "reported as an unexplained structured residual.\n"),
              f"\n![diagnosis]({fig})\n"]
        out.write_text("report.md", "\n".join(md))
        d.update(summarise(d))  # the rig-free top level (docs/diagnosis-json.md)
        out.write_json("diagnosis.json", clean_json(d))
    return d
