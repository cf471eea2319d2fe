"""The Delft 2005 van's ramp angle fitted to the paper's Fig. 9 (section 4.3), record
assets/delft_2005_van_fit.json (``python -m imurig.montecarlo.delft_fit_van``).

The paper: "At the end of the run, the van was parked for some seconds in a small ramp, as can be seen by
the increase in the pitch angle" -- no angle. Fig. 9's pitch axis (-5..0 deg, 1-deg ticks) encloses the
run's pitch, so its extent max - min lies within one tick of the 5-deg span: the reading 4 deg, uniform
over +-1 deg, SE 1 / sqrt(3) deg (as the preset's other axis readings, :mod:`imurig.campaigns.delft_2005_imu`).

The simulator: the van's ground test (:func:`imurig.flights.van.simulate_van`, the default route with the
ramp at angle a), statistic e(a) = the true pitch's extent over the run (the filter's estimate follows the
true pitch to ~0.02 deg on this run). e(a) is flat while the ramp stays below the acceleration squat of the
straight runs and rises with slope ~1 above it; the fit solves e(a) = reading by the secant method from
a = 1 and 5 deg, SE(a) = SE(reading) / e'(a). One reading, one size: exactly determined (no chi^2).

What the figure cannot separate: the ramp from the other pitch excursions of the run, the braking dive
(-2.85 deg: the van model's suspension and its 0.9 mu tyres at 14 m/s, neither given by the paper) and the
squat; the fit keeps those as the van model predicts them. Bound: 0 < a <= 15 deg (the van plan's limit;
"small" gives no number).
"""
from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from imurig.flights import earth
from imurig.flights.van import VanPlan, default_van_phases, simulate_van

#: Fig. 9's pitch extent: (reading, half-width) in deg (module doc)
FIG9_PITCH_EXTENT_DEG = (4.0, 1.0)
RAMP_BOUNDS_DEG = (0.0, 15.0)


def pitch_extent_deg(ramp_angle_deg: float, rate_hz: float = 100.0) -> float:
    """e(a): max - min of the van's true pitch (deg) over the default route with the ramp at ``ramp_angle_deg``."""
    tr = simulate_van(VanPlan(phases=default_van_phases(ramp_angle_deg), rate_hz=rate_hz))
    _r, p, _y = earth.euler_from_q(tr.q_NB)
    return float(np.degrees(np.ptp(p)))


def fit(start=(1.0, 5.0), iterations: int = 4, tol_deg: float = 0.01) -> dict:
    """The ramp angle with e(a) = the reading (secant from ``start``), its SE and the runs (module doc)."""
    reading, half = FIG9_PITCH_EXTENT_DEG
    se_reading = half / math.sqrt(3.0)
    runs = [(a, pitch_extent_deg(a)) for a in start]
    for _ in range(iterations):
        (a0, e0), (a1, e1) = runs[-2], runs[-1]
        a2 = float(np.clip(a1 + (reading - e1) * (a1 - a0) / (e1 - e0), *RAMP_BOUNDS_DEG))
        runs.append((a2, pitch_extent_deg(a2)))
        if abs(runs[-1][1] - reading) < tol_deg:
            break
    (a0, e0), (a1, e1) = sorted(runs[-2:])
    slope = (e1 - e0) / (a1 - a0)
    a, e = runs[-1]
    return {"ramp_angle_deg": a, "se_deg": se_reading / slope, "slope": slope, "extent_at_fit_deg": e,
            "reading_deg": reading, "reading_se_deg": se_reading, "runs": [list(r) for r in runs],
            "bounds_deg": list(RAMP_BOUNDS_DEG), "within_bounds": bool(RAMP_BOUNDS_DEG[0] < a <= RAMP_BOUNDS_DEG[1]),
            "inseparable": "the ramp from the braking dive and the acceleration squat (the van model's own)"}


def main(out: Path | None = None) -> dict:
    """Fit and write the record (assets/delft_2005_van_fit.json by default)."""
    t0 = time.perf_counter()
    rec = fit()
    rec["run_s"] = time.perf_counter() - t0
    path = out or Path(__file__).resolve().parents[2] / "assets" / "delft_2005_van_fit.json"
    path.write_text(json.dumps(rec, indent=1) + "\n")
    return rec


if __name__ == "__main__":
    print(json.dumps(main(Path(sys.argv[1]) if len(sys.argv) > 1 else None), indent=1))
