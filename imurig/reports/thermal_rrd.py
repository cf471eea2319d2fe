"""The thermal campaign in rerun: the IMU turning through its six attitudes on the positioner,
the chamber and sensor temperatures, raw channels (10 s means) and the six-position biases."""
from __future__ import annotations

import numpy as np

from imurig.reports.turn_table_rrd import block_means
from imurig.kernel.recording import Recording
from imurig.rigs.mujoco_rig import load_model
from imurig.reports.viz import RrdWriter, body_path, log_body_poses, log_frame_axes, log_mujoco_model, log_scalars, log_text


def write_rrd(path, rec: Recording, res: dict, overwrite: bool = True, display_period_s: float = 10.0) -> None:
    model = load_model("tilt_table.xml")
    k = max(1, int(round(display_period_s * rec.sample_rate_hz)))
    idx = np.arange(0, rec.n, k)
    qpos = np.stack([rec.channels["theta"][idx], rec.channels["phi"][idx]], 1)
    with RrdWriter(path, recording_name="thermal campaign", overwrite=overwrite) as w:
        log_mujoco_model(w, model)
        log_body_poses(w, model, rec.time_s[idx], qpos)
        log_frame_axes(w, body_path(model, model.body("imu_mount").id))
        temps = {n: rec.truth_signals[n] - 273.15 for n in ("T_air", "T_acc", "T_gyro", "T_box")
                 if n in rec.truth_signals}
        t = rec.time_s[idx]
        log_scalars(w, "signals/temperature", t, {n: v[idx] for n, v in temps.items()}, {n: "degC" for n in temps})
        names = [c for c in ("acc_x", "acc_y", "acc_z", "gyro_p", "gyro_q", "gyro_r", "temp_box") if c in rec.channels]
        tb, raw = block_means(rec, names, k)
        log_scalars(w, "signals/raw", tb, raw, {n: "V" for n in names})
        tab = res["table"]
        seg_t = np.array([rec.segments["stop_s"][rec.segments["step"] == s].max() for s in tab["step"]])
        log_scalars(w, "signals/calibrated/acc_bias", seg_t, {a: tab["acc_bias"][:, j] for j, a in enumerate("xyz")},
                    {a: "m/s^2" for a in "xyz"})
        log_scalars(w, "signals/calibrated/gyro_bias", seg_t,
                    {a: np.degrees(tab["gyro_bias"][:, j]) for j, a in enumerate("pqr")}, {a: "deg/s" for a in "pqr"})
        log_text(w, "summary", "# Thermal calibration\n\n" + "\n".join(
            f"- {k}: gap {v['measured_gap_m_s2']:.3e} m/s^2 (twin {v['injected_gap_m_s2']:.3e})"
            for k, v in res["hysteresis"].items()))
