"""``imurig reproduce tab_4_7``: the seed's time budget for the accelerometer calibration (Table 4.7,
section 4.8), on the lab pace fitted to the table itself.

The pace has two sizes the seed does not print: the time to set one position by the hand wheels (beside
the 15 s dwell) and the time between the two mountings ("it is important to take some time for testing
and altering the calibration build up into account", 4.8: remounting, re-levelling, checking). Table 4.7
gives two readings that carry them, the 10 tilt angles of one mounting (120 min) and the complete
calibration (280 min), so both sizes are fitted, exactly determined:

    T_one  = n_pos (dwell + setting)                 ->  setting = T_one / n_pos - dwell
    T_full = warm-up + n_mount T_one + remount       ->  remount = T_full - warm-up - n_mount T_one

with SEs from the readings' rounding (half-width 5 min, SE 5/sqrt(3) min; the warm-up's 15 min to 0.5 min).
The rows are then the tilt campaign's schedule (:func:`imurig.montecarlo.tilt.table_47`, whose setting time
``SEED_SETTING_OVERHEAD_S`` is this fit's, checked by the tests) at those sizes: the
120 and 280 min rows are FIT TARGETS (within by construction), the warm-up and the dwell are the seed's own
settings, the 12-phi-position row (10 min) is a PREDICTION of the fitted pace.
"""
from __future__ import annotations

import math

from imurig.montecarlo.tilt import TILT_TABLE, table_47
from imurig.reports.common import published_figures
from imurig.reports.reproduce_lab import row

#: half-widths of Table 4.7's readings (min): the rounding of 120 and 280 (as the item's tolerance), the warm-up's
ROUNDING_MIN = 5.0
WARMUP_ROUNDING_MIN = 0.5


def fitted_pace(p: dict | None = None) -> dict:
    """The setting time per position (s) and the remount time (s) fitted to Table 4.7, with SEs (module doc)."""
    p = p or TILT_TABLE.default_params()
    seed = published_figures()["calibration_time"]
    n_pos, n_mount = len(p["theta_deg"]) * len(p["phi_deg"]), len(p["mounts"])
    se_r, se_w = ROUNDING_MIN / math.sqrt(3), WARMUP_ROUNDING_MIN / math.sqrt(3)
    setting_s = seed["ten_theta_angles"] * 60 / n_pos - p["dwell_s"]
    remount_min = seed["complete_twenty_angles"] - seed["warm_up"] - n_mount * seed["ten_theta_angles"]
    return {"setting_s": setting_s, "setting_se_s": se_r * 60 / n_pos, "remount_s": remount_min * 60,
            "remount_se_s": 60 * math.sqrt(se_r ** 2 * (1 + n_mount ** 2) + se_w ** 2)}


def tab_4_7() -> list[dict]:
    """Seed Table 4.7 (minutes) for the seed's schedule (10 tilt angles x 12 phi positions x 2 mountings, 15 s
    dwell) at the pace fitted to the table (module doc). Tolerance: the seed's rounding (5 min; 0.5 s for the
    dwell)."""
    p = TILT_TABLE.default_params()
    fit = fitted_pace(p)
    rows = table_47(TILT_TABLE, {**p, "remount_s": fit["remount_s"]})
    seed = published_figures()["calibration_time"]
    pace = (f"setting {fit['setting_s']:.0f} +- {fit['setting_se_s']:.1f} s per position, remount "
            f"{fit['remount_s'] / 60:.0f} +- {fit['remount_se_s'] / 60:.1f} min, both fitted to the 120- and 280-min rows")
    pairs = (("warm_up", "warm-up", "the seed's warm-up, taken as given"),
             ("twelve_phi_positions", "12 positions in the phi plane", f"PREDICTION of the fitted pace ({pace})"),
             ("ten_theta_angles", "10 tilt angles (one mounting)", f"FIT TARGET ({pace})"),
             ("complete_twenty_angles", "complete calibration (2 mountings)", f"FIT TARGET ({pace})"))
    out = [row("tab_4_7", ours, "min", seed[key], rows[ours] / 60, ROUNDING_MIN, note) for key, ours, note in pairs]
    out.append(row("tab_4_7", "acquiring time per position", "s", seed["acquire_per_position_s"],
                   rows["acquiring time per position"], 0.5, "the protocol's dwell"))
    return out
