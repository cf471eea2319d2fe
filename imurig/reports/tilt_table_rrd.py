"""The tilt-table campaign in rerun: the table moving, the IMU frame, raw and calibrated channels."""
from __future__ import annotations

import numpy as np
import rerun.blueprint as rrb

from imurig.calibration.accelerometer import ACC, AXES
from imurig.kernel.recording import Recording
from imurig.rigs.mujoco_rig import load_model
from imurig.rigs.tilt_table import MOUNTS, _quat_wxyz
from imurig.reports.rrd_layout import layout, readable, rig_view, series_view, summary_view, symmetric_range
from imurig.reports.display_means import DISPLAY_HZ   # the .rrds' display rate, one value
from imurig.reports.viz import (RrdWriter, body_path, break_gaps, log_body_poses, log_frame_axes, log_mujoco_model,
                                log_scalars, log_text)

#: the specific-force series' units (truth and calibrated)
F_UNITS = {f"f_{a}": "m/s^2" for a in AXES}


def blueprint(model, residual_range=None) -> rrb.Blueprint:
    """Left: the table with the camera on the IMU, the parameter table below. Right: measured
    volts, calibrated specific force over the truth, and the per-position residuals (y axis
    ``residual_range``)."""
    return layout(rrb.Horizontal(
        rrb.Vertical(rig_view(model, "tilt table", distance_m=0.8), summary_view(), row_shares=[3, 2]),
        rrb.Vertical(series_view("measured: accelerometer volts", ["/signals/raw/**"]),
                     series_view("calibrated over truth: specific force, m/s²",
                                 ["/signals/calibrated/**", "/signals/truth/**"]),
                     series_view("residuals per position (calibrated − reference)", ["/signals/residuals/**"],
                                 y_range=residual_range)),
        column_shares=[2, 3]))


def write_rrd(path, rec: Recording, res: dict, overwrite: bool = True) -> None:
    """Write ``path``: the rig at 10 Hz, raw volts and calibrated m/s^2 at 10 Hz (from the 100 Hz
    processed record ``res["rec100"]``), per-position medians and references as points, and a text
    summary: :func:`start_rrd` (the record) then :func:`finish_rrd` (the fits ``res``)."""
    finish_rrd(start_rrd(path, res["rec100"], overwrite), res)


def _display_index(rec100: Recording) -> np.ndarray:
    return np.arange(0, rec100.n, max(1, int(round(rec100.sample_rate_hz / DISPLAY_HZ))))


def start_rrd(path, rec100: Recording, overwrite: bool = True) -> RrdWriter:
    """Open ``path`` and log what needs no fits: the table model and its poses, the IMU's axes, the raw
    volts and the truth at 10 Hz (its layout, which shows the fits' residuals, is sent by
    :func:`finish_rrd`). Returns the open writer (:meth:`RrdWriter.abort` it if no fits come)."""
    model = load_model("tilt_table.xml")
    idx = _display_index(rec100)
    t = rec100.time_s[idx]
    src = rec100.truth_signals if "theta_true" in rec100.truth_signals else rec100.channels
    qpos = np.stack([src["theta_true" if "theta_true" in src else "theta"][idx],
                     src["phi_true" if "phi_true" in src else "phi"][idx]], axis=1)
    # mounting per sample: the run of the next segment
    runs = rec100.meta.get("runs", ["z_up"])
    seg_run = rec100.segments.get("run", np.zeros(rec100.n_segments, int)).astype(int)
    nxt = np.clip(np.searchsorted(rec100.segments["stop_s"], t), 0, rec100.n_segments - 1)
    mount_q = np.array([_quat_wxyz(MOUNTS[r]) for r in runs])[seg_run[nxt]]   # each run's, per sample
    w = RrdWriter(path, recording_name="tilt-table campaign", overwrite=overwrite, blueprint=None)
    try:
        log_mujoco_model(w, model)
        log_body_poses(w, model, t, qpos, body_quat_overrides={"imu_mount": mount_q})
        imu_path = body_path(model, model.body("imu_mount").id)
        log_frame_axes(w, imu_path, length=0.15)
        log_scalars(w, "signals/raw", *break_gaps(t, {c: rec100.channels[c][idx] for c in ACC}), {c: "V" for c in ACC},
                    role="measured")
        if rec100.truth_signals.get("f_C_x") is not None:  # before the calibrated: drawn wide, underneath
            truth = {f"f_{a}": rec100.truth_signals[f"f_C_{a}"][idx] for a in AXES}
            log_scalars(w, "signals/truth", *break_gaps(t, truth), F_UNITS, role="truth")
    except BaseException:
        w.abort()
        raise
    return w


def finish_rrd(w: RrdWriter, res: dict) -> None:
    """Log the fits ``res`` (``main``: the calibration, ``parameters``, ``rec100``) into the writer
    :func:`start_rrd` opened: the layout (its residual axis from them), the calibrated specific force,
    the per-position residuals, the parameter table; then close it onto its path."""
    with w:
        rec100, cal = res["rec100"], res["main"]
        idx = _display_index(rec100)
        t = rec100.time_s[idx]
        resid = {f"f_{a}": cal.results_[a].residuals_ for a in AXES}
        k, unit = readable(np.concatenate(list(resid.values())), "m/s^2")
        resid = {n: v * k for n, v in resid.items()}
        w.send_default_blueprint(blueprint(load_model("tilt_table.xml"), symmetric_range(*resid.values())))
        calibrated = cal.apply(rec100)
        f_cal = {f"f_{a}": calibrated.channels[f"acc_cal_{a}"][idx] for a in AXES}
        log_scalars(w, "signals/calibrated", *break_gaps(t, f_cal),
                    F_UNITS, role="calibrated")
        mid = 0.5 * (rec100.segments["start_s"] + rec100.segments["stop_s"])
        log_scalars(w, "signals/residuals", mid, resid, {n: unit for n in resid}, role="residual", points=True)
        log_text(w, "summary", parameter_table("Tilt-table calibration", res["parameters"]))


def parameter_table(title: str, parameters) -> str:
    """The parameter table (markdown): injected, estimate, standard error, z (– where absent)."""
    def g(v, spec):
        return "–" if v is None else format(v, spec)

    lines = [f"# {title}", "", "| parameter | injected | estimate | std. error | z |", "|---|---|---|---|---|"]
    lines += [f"| {p['name']} | {g(p.get('injected'), '.6g')} | {g(p.get('estimate'), '.6g')} | "
              f"{g(p.get('std_error'), '.2g')} | {g(p.get('z'), '+.2f')} |" for p in parameters]
    return "\n".join(lines)
