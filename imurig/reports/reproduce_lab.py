"""Items of ``imurig reproduce`` from the lab's site, its turn table and its time budget.

Each function returns the rows of :func:`imurig.reports.reproduce._row` form
``{item, quantity, unit, seed, imurig, tolerance, verdict, note}``. Tolerances come from the
seed's own precision (the digits it printed) or its scatter (the standard error of what it
measured), combined with imurig's own standard error where imurig's value is itself an estimate:

    tolerance = 2 sqrt(se_seed^2 + se_imurig^2)      (a two-sided 95 % band of the difference)
"""
from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from imurig.campaigns.turn_table import round_time_error_at, simona_virtual
from imurig.calibration.simona import GYROS, SimonaCalibration, read_simona
from imurig.kernel.site import Site
from imurig.montecarlo.tilt import TILT_TABLE, table_47
from imurig.reports.common import published_figures

#: WGS-84 normal gravity (Somigliana), its free-air gradient [1/s^2], for the site check
WGS84_GE, WGS84_K, WGS84_E2 = 9.7803253359, 0.00193185265241, 0.00669437999013
FREE_AIR_GRADIENT = 3.086e-6


def row(item, quantity, unit, seed, value, tolerance, note="") -> dict:
    """One compared quantity; verdict 'within' when |imurig - seed| <= tolerance."""
    verdict = "within" if abs(value - seed) <= tolerance else "outside"
    return {"item": item, "quantity": quantity, "unit": unit, "seed": float(seed), "imurig": float(value),
            "tolerance": float(tolerance), "verdict": verdict, "note": note}


def normal_gravity(latitude_deg: float, altitude_m: float = 0.0) -> float:
    """WGS-84 normal gravity on the ellipsoid (Somigliana's closed form) less the free-air term [m/s^2]:

        g = g_e (1 + k sin^2 lat) / sqrt(1 - e^2 sin^2 lat) - 3.086e-6 h
    """
    s2 = math.sin(math.radians(latitude_deg)) ** 2
    return WGS84_GE * (1 + WGS84_K * s2) / math.sqrt(1 - WGS84_E2 * s2) - FREE_AIR_GRADIENT * altitude_m


def site_gravity() -> list[dict]:
    """The local gravity of seed section 4.3.1 (9.81242231 m/s^2, from the geodetic institute) against
    WGS-84 normal gravity at the lab. The report gives no coordinates: the tolerance is normal
    gravity's spread over Delft (52.00 +- 0.02 deg N, 0-20 m above the ellipsoid's local geoid height
    of ~45 m is absorbed in the spread below), i.e. half the range over that box."""
    site = Site()
    lats = (site.latitude_deg - 0.02, site.latitude_deg + 0.02)
    alts = (0.0, 20.0)
    vals = [normal_gravity(la, h) for la in lats for h in alts]
    g = normal_gravity(site.latitude_deg, 0.0)
    tol = 0.5 * (max(vals) - min(vals))
    seed = published_figures()["site"]["local_gravity_m_s2"]
    return [row("site_gravity", "local gravity", "m/s^2", seed, g, tol,
                "WGS-84 normal gravity (Somigliana) at the lab; tolerance: its spread over the lab's unknown "
                "latitude (+-0.02 deg) and height (0-20 m); local anomalies are left out")]


def timer_resolution() -> list[dict]:
    """Seed 4.4.2: the angle error of one timed round at 500 deg/s, for a 1 us and a 1 ms clock
    (``round_time_error_at``: the angle the table turns in one clock step). Tolerance: half the last
    digit the seed printed."""
    out = []
    for res, seed, tol in ((1e-6, 0.0005, 0.00005), (1e-3, 0.5, 0.05)):
        e = round_time_error_at(500.0, res)
        out.append(row("timer_resolution", f"angle error per round, {res:g} s clock at 500 deg/s", "deg", seed,
                       e["angle_error_deg"], tol, "closed form: rate x clock step"))
    return out


def _sigma_se(sigma: float, dof: int) -> float:
    """Sampling standard error of a residual standard deviation with ``dof`` degrees of freedom."""
    return sigma / math.sqrt(2 * dof)


@lru_cache(maxsize=1)
def _simona():
    """The seed's Table B.1 and the virtual SIMONA experiment (default seed), made once per process."""
    return read_simona(), simona_virtual()


def fig_4_19() -> list[dict]:
    """The SIMONA quick calibration (seed appendix B, Fig. 4.19). The seed's values are the project's
    fit of the seed's own Table B.1; imurig's are the same fit of the virtual SIMONA experiment
    (virtual C181 with its mains factor and slip, stopwatch printed to 0.01 s, autoscaling voltmeter).
    Compared: each gyro's own-calibration residual sigma (what the figure's middle panel shows)."""
    real, virt = (SimonaCalibration().fit(r).summary_ for r in _simona())
    out = []
    for g in GYROS:
        s_r, s_v = real[g]["sigma_res_dps"], virt[g]["sigma_res_dps"]
        dof_r, dof_v = len(real[g]["rows"]) - 2, len(virt[g]["rows"]) - 2
        tol = 2 * math.hypot(_sigma_se(s_r, dof_r), _sigma_se(s_v, dof_v))
        out.append(row("fig_4_19", f"{g} gyro own-calibration residual sigma", "deg/s", s_r, s_v, tol,
                       f"manufacturer's residuals reach {real[g]['manufacturer_max_abs_dps']:.1f} (seed data) and "
                       f"{virt[g]['manufacturer_max_abs_dps']:.1f} deg/s (virtual); the virtual gyros' 5.44 mV/(deg/s) "
                       "is set from Table B.1"))
    return out


def b_1_round_times() -> list[dict]:
    """Seed appendix B, Table B.1: the measured round times exceed 360 deg / (5/6 dial) by 1-8 %. The
    quantity: the mean excess over the timed rows, seed data against the virtual table."""
    out = []
    vals = []
    for rec in _simona():
        c = rec.channels
        m = c["measured_round"] > 0
        excess = c["measured_round"][m] / c["expected_round"][m] - 1
        vals.append((100 * excess.mean(), 100 * excess.std(ddof=1) / math.sqrt(excess.size)))
    (seed, se_s), (ours, se_o) = vals
    out.append(row("b_1_round_times", "mean round-time excess over 360 deg/(5/6 dial)", "%", seed, ours,
                   2 * math.hypot(se_s, se_o), "tolerance: 2 x the combined standard error of the two row means"))
    return out


def tab_4_7() -> list[dict]:
    """Seed Table 4.7, the time needed for the accelerometer calibration (minutes), for the seed's
    schedule (10 tilt angles x 12 phi positions x 2 mountings, 15 s dwell). The rows follow the lab's
    pace: 15 s dwell plus 45 s to set a position by the hand wheels, a number taken from the seed's
    own 120-minute row (so that row agrees by construction). Tolerance: the seed's rounding (5 min)."""
    p = TILT_TABLE.default_params()
    rows = table_47(TILT_TABLE, p)
    seed = published_figures()["calibration_time"]
    pairs = (("warm_up", "warm-up", 1 / 60), ("twelve_phi_positions", "12 positions in the phi plane", 1 / 60),
             ("ten_theta_angles", "10 tilt angles (one mounting)", 1 / 60),
             ("complete_twenty_angles", "complete calibration (2 mountings)", 1 / 60))
    out = []
    for key, ours, scale in pairs:
        note = "by construction (45 s per position from this row)" if key == "ten_theta_angles" else (
            "the seed's warm-up, taken as given" if key == "warm_up" else "lab pace: 15 s dwell + 45 s setting")
        out.append(row("tab_4_7", ours, "min", seed[key], rows[ours] * scale, 5.0, note))
    out.append(row("tab_4_7", "acquiring time per position", "s", seed["acquire_per_position_s"],
                   rows["acquiring time per position"], 0.5, "the protocol's dwell"))
    return out


@lru_cache(maxsize=None)
def flight_study(flight: str):
    """``imurig flight --flight <flight>`` (default options), once per process: the van's ground test serves
    paper Figs. 8 and 9, the static tests Figs. 6 and 7."""
    from imurig.campaigns.flight import FlightOptions, fly   # lazy: the flight stack is only needed here

    return fly(FlightOptions(flight=flight))


def paper_fig_8() -> list[dict]:
    """Paper Fig. 8, the van's ground test (section 4.3): the heading from the magnetometer changes by
    ~10 deg when the manufacturer's calibration is replaced by the own off-line calibration.

    Run: ``imurig flight --flight van`` (the van driven in MuJoCo, the flight's IMU drawn from the
    default seed). The quantity: the mean |psi_manufacturer - psi_own| of the compass heading (the
    fluxgate levelled with the true roll and pitch, IGRF declination), once per second while the van
    moves faster than 3 m/s, with the datasheet (manufacturer) conversion against the own
    two-step ellipsoid calibration. Tolerance: half the 5-deg tick spacing of the figure's
    residual axis, which is all the precision the figure gives."""
    from imurig.campaigns.flight import declination_model   # lazy: the flight stack
    from imurig.campaigns.flight_filter import compass_heading
    from imurig.flights import earth

    st = flight_study("van")
    tr = st.truth
    i = np.arange(0, tr.n, max(1, round(tr.rate_hz)))
    i = i[np.linalg.norm(tr.v_N[i, :2], axis=1) > 3.0]
    decl = declination_model(tr)
    psi = {k: compass_heading(tr, st.runs[k][2], decl, i) for k in ("uncalibrated", "calibrated")}
    d = np.abs(earth.wrap_pi(psi["uncalibrated"] - psi["calibrated"]))
    return [row("paper_fig_8", "compass heading change, manufacturer -> own calibration (mean, moving)", "deg",
                published_figures()["magnetometer"]["heading_bias_corrected_deg"], math.degrees(d.mean()), 2.5,
                f"van ground test, {i.size} s moving; tolerance: half the figure's 5-deg tick spacing")]
