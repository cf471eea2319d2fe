"""`imurig flight`: the report of the flight study (:mod:`imurig.campaigns.flight`): the flight
flown with the IMU uncalibrated and calibrated on the virtual rigs, side by side as paper
Figs. 6-8, errors and consistency, report.md, summary.json and flight.rrd.
"""
from __future__ import annotations

import numpy as np

from imurig.campaigns.flight import FILTER_VARIANTS, FlightOptions, FlightStudy, fly
from imurig.flights import earth as E
from imurig.kernel.outputs import OutputFolder
from imurig.reports.common import md_table, published_figures

COLOURS = {"uncalibrated": "tab:red", "calibrated": "tab:blue"}


def open_folder(out, overwrite: bool = False) -> OutputFolder:
    """The report folder, written atomically; refuses an existing ``out`` unless ``overwrite``
    (checked before anything is flown)."""
    return OutputFolder(out, overwrite=overwrite)


def run(out, opt: FlightOptions, overwrite: bool = False) -> dict:
    """The whole job: fly the study and write its report into ``out`` atomically. Returns the summary."""
    opt.validate()
    with open_folder(out, overwrite) as folder:
        return write_report(folder, fly(opt))


def write_report(folder: OutputFolder, study: FlightStudy) -> dict:
    """Figures, report.md, flight.rrd and summary.json of ``study`` into ``folder``; returns the summary."""
    write_products(folder, study.truth, study.runs, study.gps, study.summary)
    folder.write_json("summary.json", study.summary)
    return study.summary


def write_products(folder, truth, runs, gps, summary):
    """Figures (paper Figs. 6-8 analogues, errors, consistency), report.md and flight.rrd."""
    fig_static_roll_pitch(folder, truth, runs)
    fig_bias_estimates(folder, runs)
    fig_heading_vs_track(folder, runs, gps)
    fig_errors_consistency(folder, runs)
    text = report_text(summary)
    folder.write_text("report.md", text)
    write_rrd(folder, truth, runs, gps, text)


def _pyplot():
    import matplotlib  # lazy: matplotlib is loaded only when figures are drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _figure_legend(fig, ax) -> None:
    """One legend for the whole figure (every panel draws the same runs), above the panels."""
    handles, labels = ax.get_legend_handles_labels()
    fig.legend(handles, labels, loc="upper center", ncol=len(labels), fontsize=8, bbox_to_anchor=(0.5, 0.955))


def fig_static_roll_pitch(folder, truth, runs):
    """Fig. 6: roll and pitch in the static phases (or the first minute on the ground)."""
    plt, col = _pyplot(), COLOURS
    static = [p for p in truth.phases if p[0].startswith("static")] or [("start", truth.time_s[0],
                                                                          truth.time_s[0] + 60.0)]
    fig, ax = plt.subplots(len(static), 2, figsize=(10, 2.6 * len(static)), squeeze=False)
    for i, (nm, a, b) in enumerate(static):
        for name, (res, err, _) in runs.items():
            m = (res.time_s >= a) & (res.time_s < b)
            r, p_, _y = E.euler_from_q(res.q_NB[m])
            ax[i, 0].plot(res.time_s[m], np.degrees(r), color=col[name], label=name)
            ax[i, 1].plot(res.time_s[m], np.degrees(p_), color=col[name], label=name)
        idx = (truth.time_s >= a) & (truth.time_s < b)
        rt, pt, _ = E.euler_from_q(truth.q_NB[idx])
        ax[i, 0].plot(truth.time_s[idx], np.degrees(rt), "k--", label="truth")
        ax[i, 1].plot(truth.time_s[idx], np.degrees(pt), "k--", label="truth")
        ax[i, 0].set_ylabel(f"roll, deg\n{nm}", fontsize=7)
        ax[i, 1].set_ylabel("pitch, deg")
    ax[-1, 0].set_xlabel("time, s")
    ax[-1, 1].set_xlabel("time, s")
    ax[0, 0].set_title("roll", fontsize=9)
    ax[0, 1].set_title("pitch", fontsize=9)
    _figure_legend(fig, ax[0, 0])
    fig.suptitle("Estimated roll and pitch in the static tests (cf. paper Fig. 6)")
    fig.tight_layout(rect=(0, 0, 1, 0.93))
    fig.savefig(folder.file("fig6_static_roll_pitch.png"), dpi=90)
    plt.close(fig)


def fig_bias_estimates(folder, runs):
    """Fig. 7: the accelerometer and gyro bias estimates of both runs."""
    plt, col = _pyplot(), COLOURS
    fig, ax = plt.subplots(3, 2, figsize=(10, 7), sharex=True)
    for name, (res, _, _) in runs.items():
        for j in range(3):
            ax[j, 0].plot(res.time_s, res.acc_bias_m_s2[:, j], color=col[name], label=name)
            ax[j, 1].plot(res.time_s, np.degrees(res.gyro_bias_rad_s[:, j]), color=col[name], label=name)
    for j, a in enumerate("XYZ"):
        ax[j, 0].set_ylabel(f"{a} acc. bias, m/s²")
        ax[j, 1].set_ylabel(f"{'pqr'[j]} gyro bias, deg/s")
    _figure_legend(fig, ax[0, 0])
    fig.suptitle("Accelerometer and gyro bias estimates before/after calibration (cf. paper Fig. 7)")
    fig.tight_layout(rect=(0, 0, 1, 0.93))
    fig.savefig(folder.file("fig7_bias_estimates.png"), dpi=90)
    plt.close(fig)


def fig_heading_vs_track(folder, runs, gps):
    """Fig. 8: heading against the GPS track where moving."""
    plt, col = _pyplot(), COLOURS
    v = np.asarray(gps.v_N, float)
    track = np.degrees(np.arctan2(v[:, 1], v[:, 0])) % 360
    moving = np.hypot(v[:, 0], v[:, 1]) > 3.0
    fig, ax = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    ax[0].plot(gps.time_s, track, ".", ms=2, color="k", label="GPS track")
    for name, (res, _, _) in runs.items():
        y = np.degrees(E.euler_from_q(res.q_NB)[2]) % 360
        ax[0].plot(res.time_s, y, color=col[name], lw=0.8, label=f"LC {name}")
        yi = np.interp(gps.time_s, res.time_s, np.unwrap(np.radians(y)))
        resid = np.degrees(E.wrap_pi(yi - np.radians(track)))
        ax[1].plot(gps.time_s[moving], resid[moving], ".", ms=2, color=col[name], label=f"LC {name} − GPS track")
    ax[0].set_ylabel("heading, deg")
    ax[1].set_ylabel("residual, deg")
    ax[1].set_xlabel("time, s")
    ax[0].legend(fontsize=7)
    ax[1].legend(fontsize=7)
    fig.suptitle("Heading against GPS track (cf. paper Fig. 8; GPS track only where moving > 3 m/s)")
    fig.tight_layout()
    fig.savefig(folder.file("fig8_heading_vs_track.png"), dpi=90)
    plt.close(fig)


def fig_errors_consistency(folder, runs):
    """Attitude, heading (with 3σ), position errors and NEES of both runs; every panel's legend
    names every line."""
    plt, col = _pyplot(), COLOURS
    fig, ax = plt.subplots(4, 1, figsize=(10, 9), sharex=True)
    for name, (res, err, _) in runs.items():
        ax[0].plot(res.time_s, np.degrees(err["roll_rad"]), color=col[name], lw=0.7, label=f"roll {name}")
        ax[0].plot(res.time_s, np.degrees(err["pitch_rad"]), color=col[name], lw=0.7, ls=":", label=f"pitch {name}")
        ax[1].plot(res.time_s, np.degrees(err["heading_rad"]), color=col[name], lw=0.7, label=f"heading {name}")
        ax[1].plot(res.time_s, 3 * np.degrees(np.sqrt(res.P_diag[:, 8])), color=col[name], lw=0.5, ls="--",
                   label=f"3σ {name}")
        ax[2].plot(res.time_s, np.linalg.norm(err["pos_N_m"], axis=1), color=col[name], lw=0.7, label=name)
        ax[3].semilogy(res.time_s, np.maximum(err["nees"], 1e-3), color=col[name], lw=0.5, label=name)
    ax[3].axhline(9, color="k", lw=0.5, label="9 (its mean for a consistent filter)")
    ax[0].set_ylabel("roll/pitch err, deg")
    ax[1].set_ylabel("heading err, deg")
    ax[2].set_ylabel("position err, m")
    ax[3].set_ylabel("NEES (9 dof)")
    ax[3].set_xlabel("time, s")
    for a in ax:
        a.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(folder.file("fig_errors_consistency.png"), dpi=90)
    plt.close(fig)


def filter_states_text(summary: dict) -> str:
    """The report's sentence on the filter: its variant and, per run, the number and names of its states."""
    n, names = summary["n_states"], summary["states"]
    head = f"Filter `{summary['filter']}` ({FILTER_VARIANTS[summary['filter']]})."
    if names["uncalibrated"] == names["calibrated"]:
        return f"{head}\nFilter states, both runs ({n['calibrated']}): {', '.join(names['calibrated'])}."
    return "\n".join([head] + [f"Filter states, {k} run ({n[k]}): {', '.join(names[k])}." for k in names])


def report_text(summary: dict) -> str:
    """report.md of the flight study."""
    pub = published_figures().get("magnetometer", {}).get("heading_bias_corrected_deg", 10)
    rows = []
    for k in summary["runs"]["calibrated"]:
        rows.append([k, f"{summary['runs']['uncalibrated'][k]:.4g}", f"{summary['runs']['calibrated'][k]:.4g}"])
    text = f"""# imurig flight — loosely coupled GPS/INS, uncalibrated vs calibrated IMU

Flight: `{summary['flight']}` ({summary['vehicle']}), {summary['duration_s']:.0f} s, IMU {summary['imu_rate_hz']:g} Hz,
navigation {summary['nav_rate_hz']:g} Hz, GPS: {summary['gps_mode']}.
{filter_states_text(summary)}
Errors are RMS against truth after the first 60 s.

{md_table(['quantity', 'uncalibrated', 'calibrated'], rows)}

Real-time factor of the filter: {summary['real_time_factor']:.1f}x ({summary['filter_wall_s']:.1f} s for two runs).

- `fig6_static_roll_pitch.png`: roll and pitch in the static phases (paper Fig. 6).
- `fig7_bias_estimates.png`: bias states before/after calibration (paper Fig. 7).
- `fig8_heading_vs_track.png`: heading vs GPS track; the paper removed a ~{pub} deg heading bias with
  its magnetometer calibration (Fig. 8). Here the uncalibrated run uses the fluxgate's nominal
  conversion (hard and soft iron left in: magnetometer heading error {summary['runs']['uncalibrated']['mag_heading_rms_deg']:.2f} deg RMS);
  the calibrated run the ellipsoid fit of a 120 s virtual-rig tumble of the same fluxgate
  ({summary['runs']['calibrated']['mag_heading_rms_deg']:.3f} deg RMS).
- `fig_errors_consistency.png`: attitude, heading (with 3σ), position errors and NEES.
- `flight.rrd`: open with `rerun flight.rrd`.

![fig6](fig6_static_roll_pitch.png)
![fig7](fig7_bias_estimates.png)
![fig8](fig8_heading_vs_track.png)
![errors](fig_errors_consistency.png)
"""
    return text


def write_rrd(folder, truth, runs, gps, text: str):
    """flight.rrd (imurig.reports.flight_rrd): the routes and the errors with their 3σ."""
    from imurig.reports.flight_rrd import write_rrd as _write  # lazy: rerun is loaded only when the .rrd is written

    _write(folder, truth, runs, gps, text)

