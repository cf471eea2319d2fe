"""The thermal campaign in rerun: the IMU turning through its six attitudes on the positioner,
the chamber and sensor temperatures, raw channels (10 s means), the six-position biases per step
beside the twin's, and the residuals of the temperature model per step."""
from __future__ import annotations

import numpy as np
import rerun.blueprint as rrb

from imurig.kernel.recording import Recording
from imurig.reports.rrd_layout import layout, readable, rig_view, series_view, summary_view
from imurig.reports.turn_table_rrd import block_means
from imurig.reports.viz import RrdWriter, body_path, log_body_poses, log_frame_axes, log_mujoco_model, log_scalars, log_text
from imurig.rigs.mujoco_rig import load_model


def blueprint(model) -> rrb.Blueprint:
    """Left: the positioner with the camera on the IMU, the temperatures, the summary. Middle:
    measured volts, accelerometer and gyro biases per step (estimate over twin). Right: the
    residuals of the temperature model per step."""
    return layout(rrb.Horizontal(
        rrb.Vertical(rig_view(model, "thermal chamber positioner", distance_m=0.8),
                     series_view("temperatures (truth), °C", ["/signals/temperature/**"]), summary_view(),
                     row_shares=[3, 2, 2]),
        rrb.Vertical(series_view("measured: channel volts (10 s means)", ["/signals/raw/**"]),
                     series_view("accelerometer bias per step, m/s²", ["/signals/calibrated/acc_bias/**",
                                                                       "/signals/twin/acc_bias/**"]),
                     series_view("gyro bias per step, °/s", ["/signals/calibrated/gyro_bias/**",
                                                             "/signals/twin/gyro_bias/**"])),
        rrb.Vertical(series_view("accelerometer bias residual (step − temperature model)",
                                 ["/signals/residuals/acc_bias/**"]),
                     series_view("gyro bias residual (step − temperature model)",
                                 ["/signals/residuals/gyro_bias/**"])),
        column_shares=[2, 3, 2]))


def _biases(w, prefix: str, seg_t, tab: dict, role: str) -> None:
    log_scalars(w, f"{prefix}/acc_bias", seg_t, {a: tab["acc_bias"][:, j] for j, a in enumerate("xyz")},
                {a: "m/s^2" for a in "xyz"}, role=role, points=True)
    log_scalars(w, f"{prefix}/gyro_bias", seg_t, {a: np.degrees(tab["gyro_bias"][:, j]) for j, a in enumerate("pqr")},
                {a: "deg/s" for a in "pqr"}, role=role, points=True)


def write_rrd(path, rec: Recording, res: dict, overwrite: bool = True, display_period_s: float = 10.0) -> None:
    model = load_model("tilt_table.xml")
    k = max(1, int(round(display_period_s * rec.sample_rate_hz)))
    idx = np.arange(0, rec.n, k)
    qpos = np.stack([rec.channels["theta"][idx], rec.channels["phi"][idx]], 1)
    with RrdWriter(path, recording_name="thermal campaign", overwrite=overwrite, blueprint=blueprint(model)) as w:
        log_mujoco_model(w, model)
        log_body_poses(w, model, rec.time_s[idx], qpos)
        log_frame_axes(w, body_path(model, model.body("imu_mount").id))
        temps = {n: rec.truth_signals[n] - 273.15 for n in ("T_air", "T_acc", "T_gyro", "T_box")
                 if n in rec.truth_signals}
        t = rec.time_s[idx]
        log_scalars(w, "signals/temperature", t, {n: v[idx] for n, v in temps.items()}, {n: "degC" for n in temps},
                    role="truth")
        names = [c for c in ("acc_x", "acc_y", "acc_z", "gyro_p", "gyro_q", "gyro_r", "temp_box") if c in rec.channels]
        tb, raw = block_means(rec, names, k)
        log_scalars(w, "signals/raw", tb, raw, {n: "V" for n in names}, role="measured")
        tab = res["table"]
        seg_t = np.array([rec.segments["stop_s"][rec.segments["step"] == s].max() for s in tab["step"]])
        _biases(w, "signals/calibrated", seg_t, tab, "calibrated")
        if "twin_table" in res:
            _biases(w, "signals/twin", seg_t, res["twin_table"], "twin")
        fit = res["fit"].results_
        for kind, axes, scale, unit in (("acc_bias", "xyz", 1.0, "m/s^2"), ("gyro_bias", "pqr", np.degrees(1.0), "deg/s")):
            series = {a: fit[f"{kind}_{a}"].residuals_ * scale for a in axes if f"{kind}_{a}" in fit}
            if series and all(v.shape == seg_t.shape for v in series.values()):
                k_r, u = readable(np.concatenate(list(series.values())), unit)
                log_scalars(w, f"signals/residuals/{kind}", seg_t, {a: v * k_r for a, v in series.items()},
                            {a: u for a in series}, role="residual", points=True)
        log_text(w, "summary", "# Thermal calibration\n\n" + "\n".join(
            f"- {k}: gap {v['measured_gap_m_s2']:.3e} m/s^2 (twin {v['injected_gap_m_s2']:.3e})"
            for k, v in res["hysteresis"].items()))
