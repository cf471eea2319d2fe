"""The Delft 2005 preset's van (paper section 4.3): the route's ramp angle fitted to the paper's Fig. 9 pitch
extent (the fit: :mod:`imurig.montecarlo.delft_fit_van`, record assets/delft_2005_van_fit.json; this module
only reads it). The van's fluxgate is the magnetometer campaign's preset one
(:func:`imurig.campaigns.magnetometer.delft_2005_fluxgate`)."""
from __future__ import annotations

from imurig.campaigns.delft_2005 import fit_record
from imurig.flights.van import VanPlan, default_van_phases

FIT_ASSET = "delft_2005_van_fit.json"
RAMP_SEED_SAYS = ("paper 4.3: 'At the end of the run, the van was parked for some seconds in a small ramp, as can be "
                  "seen by the increase in the pitch angle' (Fig. 9: pitch inside -5..0 deg, 1-deg ticks)")


def fitted_van_sizes() -> dict:
    """The van fit's record (Fig. 9's pitch extent)."""
    return fit_record(FIT_ASSET, "imurig.montecarlo.delft_fit_van")


def delft_2005_van_plan(rate_hz: float = 100.0) -> VanPlan:
    """The default route with the ramp at the fitted angle."""
    return VanPlan(phases=default_van_phases(fitted_van_sizes()["ramp_angle_deg"]), rate_hz=rate_hz)


def describe() -> list[dict]:
    """One row per fitted size: value, SE, source, bound."""
    r = fitted_van_sizes()
    return [{"effect": "van route: the final ramp's angle", "size": f"{r['ramp_angle_deg']:.2f} deg", "fitted": True,
             "se": r["se_deg"], "seed_says": RAMP_SEED_SAYS,
             "bound": f"{r['bounds_deg'][0]:g} < angle <= {r['bounds_deg'][1]:g} deg (the van plan's limit)"}]
