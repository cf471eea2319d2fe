"""The flight in rerun: the routes (truth, GPS fixes, the filter uncalibrated and calibrated) in
a local east-north-up frame, and each run's attitude, heading and position errors with their
3σ envelopes and the NEES."""
from __future__ import annotations

import numpy as np
import rerun.blueprint as rrb

from imurig.flights import earth as E
from imurig.reports.rrd_layout import layout, role_color, series_view, summary_view
from imurig.reports.viz import RrdWriter, log_points, log_scalars, log_text

RUN_ROLE = {"uncalibrated": "uncalibrated", "calibrated": "calibrated"}


def blueprint(run_names) -> rrb.Blueprint:
    """Left: the routes in 3-D over the summary. Right: attitude errors, heading error with ±3σ,
    position error with 3σ, NEES; each run in its own colour."""
    def paths(*series):
        return [f"/errors/{r}/{s}" for r in run_names for s in series]

    routes = rrb.Spatial3DView(origin="world", name="routes (m, east-north-up from the start): truth grey, GPS "
                               "orange, filter uncalibrated red, calibrated blue", line_grid=rrb.LineGrid3D(visible=False))
    return layout(rrb.Horizontal(
        rrb.Vertical(routes, summary_view(), row_shares=[3, 2]),
        rrb.Vertical(series_view("roll and pitch errors, °", paths("roll_err_deg", "pitch_err_deg")),
                     series_view("heading error and its 3σ, °", paths("heading_err_deg", "heading_3sigma_deg")),
                     series_view("position error and its 3σ, m", paths("pos_err_m", "pos_3sigma_m")),
                     series_view("NEES", paths("nees"))),
        column_shares=[2, 3]))


def write_rrd(folder, truth, runs, gps, text: str):
    """flight.rrd: the routes (truth, GPS, both filters) and the errors with their 3σ."""
    with RrdWriter(folder.file("flight.rrd"), overwrite=True, blueprint=blueprint(list(runs))) as w:
        lat0, lon0, h0 = truth.lat_rad[0], truth.lon_rad[0], truth.h_m[0]
        sub = slice(None, None, max(1, int(truth.rate_hz)))
        d_true = E.ned_from_geodetic(truth.lat_rad[sub], truth.lon_rad[sub], truth.h_m[sub], lat0, lon0, h0)
        log_points(w, "world/truth_route", d_true * [1, 1, -1], color=role_color("truth", 2), radius=2.0)
        d_gps = E.ned_from_geodetic(gps.lat_rad, gps.lon_rad, gps.h_m, lat0, lon0, h0)
        log_points(w, "world/gps_fixes", d_gps * [1, 1, -1], color=role_color("measured", 1), radius=3.0)
        for name, (res, err, _) in runs.items():
            role = RUN_ROLE.get(name, "estimate")
            ss = slice(None, None, max(1, int(res.meta["nav_rate_hz"])))
            d = E.ned_from_geodetic(res.lat_rad[ss], res.lon_rad[ss], res.h_m[ss], lat0, lon0, h0)
            log_points(w, f"world/ekf_{name}", d * [1, 1, -1], color=role_color(role), radius=1.5)
            t = res.time_s[ss]
            dark, mid, light = (role_color(role, i) for i in range(3))
            log_scalars(w, f"errors/{name}", t, {
                "roll_err_deg": np.degrees(err["roll_rad"][ss]), "pitch_err_deg": np.degrees(err["pitch_rad"][ss]),
                "heading_err_deg": np.degrees(err["heading_rad"][ss]),
                "heading_3sigma_deg": 3 * np.degrees(np.sqrt(res.P_diag[ss, 8])),
                "pos_err_m": np.linalg.norm(err["pos_N_m"][ss], axis=1),
                "pos_3sigma_m": 3 * np.sqrt(res.P_diag[ss, 0:3].sum(axis=1)), "nees": err["nees"][ss]},
                {"roll_err_deg": "deg", "pitch_err_deg": "deg", "heading_err_deg": "deg", "heading_3sigma_deg": "deg",
                 "pos_err_m": "m", "pos_3sigma_m": "m"},
                role=role, colors={"roll_err_deg": dark, "pitch_err_deg": light, "heading_err_deg": dark,
                                   "heading_3sigma_deg": light, "pos_err_m": dark, "pos_3sigma_m": light, "nees": dark})
        log_text(w, "summary", text)
