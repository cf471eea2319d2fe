"""The magnetometer campaign in rerun: the gimbal turning the IMU; the measured field (an
ellipsoid) and the calibrated one on the IGRF sphere in field space; the components and the
field magnitude against IGRF over time, and its residual."""
from __future__ import annotations

import numpy as np
import rerun.blueprint as rrb

from imurig.campaigns.magnetometer import indicated_field, manoeuvre_mask
from imurig.kernel.recording import Recording
from imurig.reports.rrd_layout import layout, rig_view, role_color, series_view, summary_view, symmetric_range
from imurig.reports.viz import (RrdWriter, body_path, break_gaps, log_body_poses, log_frame_axes, log_mujoco_model, log_points,
                                log_scalars, log_sphere, log_text)
from imurig.rigs.mujoco_rig import load_model

UT_TO_M = 0.01  # field space drawn at 1 uT = 1 cm


def blueprint(model, residual_range=None) -> rrb.Blueprint:
    """Left: the gimbal (camera on the IMU) over field space (measured ellipsoid, calibrated
    points, IGRF sphere). Middle: measured and calibrated components. Right: |B| over the IGRF
    magnitude, its residual, the summary."""
    field = rrb.Spatial3DView(origin="field_space", name="field space (1 µT = 1 cm): measured, calibrated, IGRF",
                              eye_controls=rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital, position=[1.2, -1.2, 0.9],
                                                             look_target=[0.0, 0.0, 0.0], eye_up=[0.0, 0.0, 1.0]),
                              line_grid=rrb.LineGrid3D(visible=False))
    return layout(rrb.Horizontal(
        rrb.Vertical(rig_view(model, "magnetometer gimbal", distance_m=1.0), field),
        rrb.Vertical(series_view("measured field, nT", ["/signals/raw/**"]),
                     series_view("calibrated field components, nT",
                                 [f"/signals/calibrated/B_{a}" for a in "xyz"])),
        rrb.Vertical(series_view("calibrated |B| over the IGRF magnitude, nT",
                                 ["/signals/calibrated/norm", "/signals/truth/**"]),
                     series_view("residual |B| − IGRF, nT", ["/signals/residuals/**"], y_range=residual_range), summary_view()),
        column_shares=[2, 2, 2]))


def write_rrd(path, rec: Recording, res: dict, overwrite: bool = True) -> None:
    """The gimbal at 10 Hz; every fifth tumble sample in field space (measured and calibrated)
    with the IGRF sphere; measured and calibrated components, |B| against IGRF and |B| − IGRF."""
    model = load_model("mag_rig.xml")
    k = max(1, int(round(rec.sample_rate_hz / 10)))
    idx = np.arange(0, rec.n, k)
    ts = rec.truth_signals
    qpos = np.stack([ts["yaw"][idx], ts["pitch"][idx], ts["roll"][idx]], 1)
    m = indicated_field(rec)
    tum = manoeuvre_mask(rec, "tumble")
    t = rec.time_s[idx]
    igrf_nT = float(res["igrf"]["total_nT"])
    cal = res["ellipsoid"].apply(m)
    norm = np.linalg.norm(cal[idx], axis=1) * 1e9
    bp = blueprint(model, symmetric_range(norm - igrf_nT))
    with RrdWriter(path, recording_name="magnetometer campaign", overwrite=overwrite, blueprint=bp) as w:
        log_mujoco_model(w, model)
        log_body_poses(w, model, t, qpos)
        log_frame_axes(w, body_path(model, model.body("imu_mount").id))
        log_points(w, "field_space/measured", m[tum][::5] * 1e6 * UT_TO_M, color=role_color("measured"), radius=0.004)
        log_points(w, "field_space/calibrated", res["ellipsoid"].apply(m[tum])[::5] * 1e6 * UT_TO_M,
                   color=role_color("calibrated"), radius=0.004)
        log_sphere(w, "field_space/igrf_sphere", igrf_nT * 1e-3 * UT_TO_M, color=(120, 120, 120, 255))
        log_scalars(w, "signals/raw", *break_gaps(t, {f"m_{a}": m[idx, j] * 1e9 for j, a in enumerate("xyz")}),
                    {f"m_{a}": "nT" for a in "xyz"}, role="measured")
        log_scalars(w, "signals/truth", t, {"norm": np.full_like(t, igrf_nT)}, {"norm": "nT"}, role="truth")
        b_cal = {**{f"B_{a}": cal[idx, j] * 1e9 for j, a in enumerate("xyz")}, "norm": norm}
        log_scalars(w, "signals/calibrated", *break_gaps(t, b_cal), {n: "nT" for n in b_cal},
                    role="calibrated", colors={"norm": role_color("calibrated")})
        log_scalars(w, "signals/residuals", *break_gaps(t, {"norm": norm - igrf_nT}), {"norm": "nT"}, role="residual")
        log_text(w, "summary", "# Magnetometer calibration\n\n" + "\n".join(
            f"- heading error {k_}: RMS {v['rms']:.3f} deg, max {v['max_abs']:.3f} deg"
            for k_, v in res["heading_error_deg"].items()))
