"""The tilt-table campaign in rerun: the table moving, the IMU frame, raw and calibrated channels."""
from __future__ import annotations

import numpy as np

from imurig.calibration.accelerometer import ACC, AXES
from imurig.kernel.recording import Recording
from imurig.rigs.mujoco_rig import load_model
from imurig.rigs.tilt_table import MOUNTS, _quat_wxyz
from imurig.reports.viz import RrdWriter, body_path, log_body_poses, log_frame_axes, log_mujoco_model, log_scalars, log_text

DISPLAY_HZ = 10.0


def write_rrd(path, rec: Recording, res: dict, overwrite: bool = True) -> None:
    """Write ``path``: the rig at 10 Hz, raw volts and calibrated m/s^2 at 10 Hz (from the 100 Hz
    processed record), per-position medians and references as points, and a text summary."""
    rec100 = res["rec100"]
    cal = res["main"]
    model = load_model("tilt_table.xml")
    step = max(1, int(round(rec100.sample_rate_hz / DISPLAY_HZ)))
    idx = np.arange(0, rec100.n, step)
    t = rec100.time_s[idx]
    src = rec100.truth_signals if "theta_true" in rec100.truth_signals else rec100.channels
    qpos = np.stack([src["theta_true" if "theta_true" in src else "theta"][idx],
                     src["phi_true" if "phi_true" in src else "phi"][idx]], axis=1)
    # mounting per sample: the run of the next segment
    runs = rec100.meta.get("runs", ["z_up"])
    seg_run = rec100.segments.get("run", np.zeros(rec100.n_segments, int)).astype(int)
    nxt = np.clip(np.searchsorted(rec100.segments["stop_s"], t), 0, rec100.n_segments - 1)
    mount_q = np.array([_quat_wxyz(MOUNTS[runs[r]]) for r in seg_run[nxt]])
    with RrdWriter(path, recording_name="tilt-table campaign", overwrite=overwrite) as w:
        log_mujoco_model(w, model)
        log_body_poses(w, model, t, qpos, body_quat_overrides={"imu_mount": mount_q})
        imu_path = body_path(model, model.body("imu_mount").id)
        log_frame_axes(w, imu_path, length=0.15)
        log_scalars(w, "signals/raw", t, {c: rec100.channels[c][idx] for c in ACC}, {c: "V" for c in ACC})
        calibrated = cal.apply(rec100)
        log_scalars(w, "signals/calibrated", t, {f"f_{a}": calibrated.channels[f"acc_cal_{a}"][idx] for a in AXES},
                    {f"f_{a}": "m/s^2" for a in AXES})
        if rec100.truth_signals.get("f_C_x") is not None:
            log_scalars(w, "signals/calibrated/truth", t,
                        {f"f_{a}": rec100.truth_signals[f"f_C_{a}"][idx] for a in AXES},
                        {f"f_{a}": "m/s^2" for a in AXES})
        mid = 0.5 * (rec100.segments["start_s"] + rec100.segments["stop_s"])
        log_scalars(w, "signals/residuals", mid,
                    {f"res_{a}": cal.results_[a].residuals_ for a in AXES}, {f"res_{a}": "m/s^2" for a in AXES})
        lines = ["# Tilt-table calibration", "", "| parameter | injected | estimate | std. error | z |",
                 "|---|---|---|---|---|"]
        for p in res["parameters"]:
            lines.append(f"| {p['name']} | {p['injected']} | {p['estimate']:.6g} | {p['std_error']:.2g} | "
                         f"{'' if p['z'] is None else f'{p[chr(122)]:+.2f}'} |")
        log_text(w, "summary", "\n".join(lines))
