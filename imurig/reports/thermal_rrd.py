"""The thermal campaign in rerun: the IMU turning through its six attitudes on the positioner,
the chamber and sensor temperatures, raw channels (10 s means), the six-position biases per step
beside the twin's, and the residuals of the temperature model per step."""
from __future__ import annotations

import numpy as np
import rerun.blueprint as rrb

from imurig.kernel.recording import Recording
from imurig.reports.rrd_layout import layout, readable, rig_view, series_view, summary_view, symmetric_range
from imurig.reports.display_means import block_means
from imurig.reports.viz import (RrdWriter, body_path, break_gaps, log_body_poses, log_frame_axes, log_mujoco_model,
                                log_scalars, log_text)
from imurig.rigs.mujoco_rig import load_model


def blueprint(model, residual_ranges=None) -> rrb.Blueprint:
    """Left: the positioner with the camera on the IMU, the temperatures, the summary. Middle:
    measured volts, accelerometer and gyro biases per step (estimate over twin). Right: the
    residuals of the temperature model per step (y axes ``residual_ranges`` {kind: range})."""
    rr_ = residual_ranges or {}
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
                                 ["/signals/residuals/acc_bias/**"], y_range=rr_.get("acc_bias")),
                     series_view("gyro bias residual (step − temperature model)",
                                 ["/signals/residuals/gyro_bias/**"], y_range=rr_.get("gyro_bias"))),
        column_shares=[2, 3, 2]))


def _residuals(res: dict, n_steps: int) -> dict[str, tuple[dict, str]]:
    """{kind: ({axis: residual per step, scaled}, unit)} of the temperature model's fits."""
    fit = res["fit"].results_
    out = {}
    for kind, axes, scale, unit in (("acc_bias", "xyz", 1.0, "m/s^2"), ("gyro_bias", "pqr", np.degrees(1.0), "deg/s")):
        series = {a: fit[f"{kind}_{a}"].residuals_ * scale for a in axes if f"{kind}_{a}" in fit}
        if series and all(v.shape == (n_steps,) for v in series.values()):
            k, u = readable(np.concatenate(list(series.values())), unit)
            out[kind] = ({a: v * k for a, v in series.items()}, u)
    return out


def _biases(w, prefix: str, seg_t, tab: dict, role: str) -> None:
    log_scalars(w, f"{prefix}/acc_bias", seg_t, {a: tab["acc_bias"][:, j] for j, a in enumerate("xyz")},
                {a: "m/s^2" for a in "xyz"}, role=role, points=True)
    log_scalars(w, f"{prefix}/gyro_bias", seg_t, {a: np.degrees(tab["gyro_bias"][:, j]) for j, a in enumerate("pqr")},
                {a: "deg/s" for a in "pqr"}, role=role, points=True)


def write_rrd(path, rec: Recording, res: dict, overwrite: bool = True, display_period_s: float = 10.0) -> None:
    """Write ``path``: the positioner (10 s), temperatures, raw 10 s means, the biases per step
    (estimate and twin), the temperature model's residuals per step, the hysteresis gaps."""
    model = load_model("tilt_table.xml")
    k = max(1, int(round(display_period_s * rec.sample_rate_hz)))
    idx = np.arange(0, rec.n, k)
    qpos = np.stack([rec.channels["theta"][idx], rec.channels["phi"][idx]], 1)
    tab = res["table"]
    resid = _residuals(res, len(tab["step"]))
    bp = blueprint(model, {kind: symmetric_range(*series.values()) for kind, (series, _u) in resid.items()})
    with RrdWriter(path, recording_name="thermal campaign", overwrite=overwrite, blueprint=bp) as w:
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
        log_scalars(w, "signals/raw", *break_gaps(tb, raw), {n: "V" for n in names}, role="measured")
        seg_t = np.array([rec.segments["stop_s"][rec.segments["step"] == s].max() for s in tab["step"]])
        _biases(w, "signals/calibrated", seg_t, tab, "calibrated")
        if "twin_table" in res:
            _biases(w, "signals/twin", seg_t, res["twin_table"], "twin")
        for kind, (series, u) in resid.items():
            log_scalars(w, f"signals/residuals/{kind}", seg_t, series, {a: u for a in series}, role="residual",
                        points=True)
        log_text(w, "summary", "# Thermal calibration\n\n" + "\n".join(
            f"- {k}: gap {v['measured_gap_m_s2']:.3e} m/s^2 (twin "
            f"{'–' if v['injected_gap_m_s2'] is None else format(v['injected_gap_m_s2'], '.3e')})"
            for k, v in res["hysteresis"].items()))
