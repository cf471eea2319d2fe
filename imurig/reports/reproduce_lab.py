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

from imurig.campaigns.turn_table import round_time_error_at, simona_virtual
from imurig.calibration.simona import read_simona
from imurig.kernel.site import Site
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




@lru_cache(maxsize=1)
def _simona():
    """The seed's Table B.1 and the virtual SIMONA experiment (default seed), made once per process."""
    return read_simona(), simona_virtual()




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




@lru_cache(maxsize=None)
def flight_study(flight: str):
    """``imurig flight --flight <flight>`` (default options), once per process: the van's ground test serves
    paper Figs. 8 and 9, the static tests Figs. 6 and 7."""
    from imurig.campaigns.flight import FlightOptions, fly   # lazy: the flight stack is only needed here

    return fly(FlightOptions(flight=flight))
