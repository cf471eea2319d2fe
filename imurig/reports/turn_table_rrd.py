"""The turn-table campaign in rerun: the table spinning, the IMU frame, the index pulses,
raw gyro volts and calibrated rates (10 Hz block means), references per step."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import rerun.blueprint as rrb

from imurig.calibration.gyro import AXES, GYRO
from imurig.kernel.recording import Recording
from imurig.rigs.mujoco_rig import load_model
from imurig.rigs.tilt_table import _quat_wxyz
from imurig.rigs.turn_table import MOUNTS, TurnTableErrors
from imurig.reports.rrd_layout import layout, readable, rig_view, series_view, summary_view, symmetric_range
from imurig.reports.tilt_table_rrd import parameter_table
from imurig.reports.display_means import (DISPLAY_HZ, Rows, block_means,  # noqa: F401 (the .rrd's names)
                                          calibrated_block_means, calibrated_means, display_step)
from imurig.reports.viz import (RrdWriter, body_path, break_gaps, log_body_poses, log_frame_axes, log_mujoco_model,
                                log_scalars, log_text)


def blueprint(model, residual_range=None) -> rrb.Blueprint:
    """Left: the table with the camera on the IMU, the index pulses, the parameter table. Right:
    measured volts, calibrated rates over the reference, residuals per step."""
    return layout(rrb.Horizontal(
        rrb.Vertical(rig_view(model, "turn table", distance_m=1.0),
                     series_view("index pulses (one per revolution)", ["/signals/pulses/**"]), summary_view(),
                     row_shares=[3, 1, 2]),
        rrb.Vertical(series_view("measured: gyro volts (10 Hz means)", ["/signals/raw/**"]),
                     series_view("calibrated (10 Hz means) over the reference per step, °/s",
                                 ["/signals/calibrated/**", "/signals/reference/**"]),
                     series_view("residuals per step (calibrated − reference)", ["/signals/residuals/**"],
                                 y_range=residual_range)),
        column_shares=[2, 3]))


def write_rrd(path, rec: Recording, res: dict, overwrite: bool = True, rows: Rows | None = None) -> None:
    """Write ``path``: the table turning (10 Hz), raw volts and calibrated rates (10 Hz block
    means), the reference rate and the residual of each step, the index pulses, the summary. ``rows``:
    the record's rows (default: those of ``rec``; the streamed campaign's ``rec`` holds its windows only).
    :func:`start_rrd` then :func:`finish_rrd` (the parts that need no fits, then those that do)."""
    started = start_rrd(path, rec, rows, overwrite)
    if started is not None:
        finish_rrd(started, rec, res)


def start_rrd(path, rec, rows: Rows | None = None, overwrite: bool = True) -> SimpleNamespace | None:
    """Open ``path`` and log what needs no fits: the table model and its poses (10 Hz), the IMU's axes,
    the raw volts (10 Hz block means), the index pulses. ``rec``: the record's metadata, truth and events
    (its rows: ``rows``, default :meth:`Rows.of` ``rec``). Returns what :func:`finish_rrd` needs (the
    writer open, without its layout), or None where the rows hold no spin angle (no file)."""
    rows = rows or Rows.of(rec)
    if rows.spin_at is None:
        return None
    model = load_model("turn_table.xml")
    k = display_step(rows, rec)
    # poses: the angle is sampled (not averaged) so the table turns smoothly in the viewer
    idx = np.concatenate([np.arange(b.start, b.stop, k) for b in rows.blocks])
    t_pose = np.concatenate([rows.time(b.start, b.stop)[::k] for b in rows.blocks])
    qpos = rows.spin_at(idx)[:, None]
    runs = rec.meta.get("runs", ["r_up"])
    tt = (rec.truth or {}).get("rig", {}).get("turn_table", {})
    e = TurnTableErrors(**{k_: v for k_, v in tt.items() if k_ in TurnTableErrors.__dataclass_fields__})
    block_of = np.searchsorted([rows.time(b.start, b.start + 1)[0] for b in rows.blocks], t_pose, side="right") - 1
    q_run = np.array([_quat_wxyz(e.wobble_rotation() @ MOUNTS[r]) for r in runs])
    mount_q = q_run[np.minimum(block_of, len(runs) - 1)]
    w = RrdWriter(path, recording_name="turn-table campaign", overwrite=overwrite, blueprint=None)
    try:
        log_mujoco_model(w, model)
        log_body_poses(w, model, t_pose, qpos, body_quat_overrides={"imu_mount": mount_q})
        log_frame_axes(w, body_path(model, model.body("imu_mount").id), length=0.15)
        t, raw = block_means(rows, list(GYRO), k)
        log_scalars(w, "signals/raw", *break_gaps(t, raw), {c: "V" for c in GYRO}, role="measured")
        for name, ev in rec.events.items():
            if name.startswith("pulse_") and ev.size:
                log_scalars(w, "signals/pulses", ev, {name: np.ones_like(ev)}, {name: "1"}, role="measured",
                            points=True)
    except BaseException:
        w.abort()
        raise
    return SimpleNamespace(writer=w, model=model, rows=rows, k=k, t=t)


def finish_rrd(started: SimpleNamespace, rec, res: dict, calibrated: dict | None = None) -> None:
    """Log what needs the fits ``res`` into the .rrd :func:`start_rrd` opened (``started``): its layout, the
    reference rate and the residual of each step, the calibrated rates (10 Hz block means: ``calibrated``,
    :func:`calibrated_means` of the rows, made here if not given), the parameter table; then close it onto
    its path."""
    w, t = started.writer, started.t
    with w:
        cal = res["main"]
        resid = {f"w_{a}": np.degrees(cal.results_[a].residuals_) for a in AXES}
        k_r, unit = readable(np.concatenate(list(resid.values())), "deg/s")
        resid = {n: v * k_r for n, v in resid.items()}
        w.send_default_blueprint(blueprint(started.model, symmetric_range(*resid.values())))
        c = calibrated if calibrated is not None else calibrated_means(started.rows, rec, cal)
        units = {f"w_{a}": "deg/s" for a in AXES}
        mid = 0.5 * (res["windows"].segments["start_s"] + res["windows"].segments["stop_s"])
        log_scalars(w, "signals/reference", mid, {f"w_{a}": np.degrees(res["reference"][:, j])
                                                  for j, a in enumerate(AXES)}, units, role="truth", points=True,
                    labels={f"w_{a}": f"w_{a} reference [deg/s]" for a in AXES})
        w_cal = {f"w_{a}": np.degrees(c[f"gyro_cal_{a}"]) for a in AXES}
        log_scalars(w, "signals/calibrated", *break_gaps(t, w_cal), units,
                    role="calibrated")
        log_scalars(w, "signals/residuals", mid, resid, {n: unit for n in resid}, role="residual", points=True)
        log_text(w, "summary", parameter_table("Turn-table gyro calibration", res["parameters"]))

