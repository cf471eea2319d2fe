"""Diagnosis of a thermal-chamber recording (seed 4.5: two cycles, six attitudes per step).

The twin is the seed's temperature model without hysteresis: per temperature step the
six-position accelerometer bias b_i (m/s^2) and the gyro bias (rad/s, Earth rate removed)
against the sensor's temperature reading, dT = T - 298.15 K,

    b(T) = c0 + c1 dT + c2 dT^2 + c3 dT^3        (accelerometers)
    b(T) = c0 + c1 dT                            (gyros)

Candidate effects per channel:

- ``temperature_hysteresis``: the column s = +1/2 on steps reached by heating, -1/2 by
  cooling; its amplitude H is the gap between the branches (the play-operator hysteresis
  of the sensor chain, :func:`imurig.sensors.thermal.hysteresis_state`);
- ``time_drift``: a drift in the order the steps were taken (ageing, turn-on settling), the
  column being the step's mid-time in hours.
"""
from __future__ import annotations

import numpy as np

from imurig.calibration.thermal import _design, step_table, term_names
from imurig.diagnose.engine import Candidate, select_effects
from imurig.recording import Recording


def diagnose_thermal(rec: Recording, rng: np.random.Generator, alpha: float = 0.01, n_sim: int = 300) -> dict:
    """Diagnose the per-step biases of a thermal recording against the no-hysteresis twin."""
    table = step_table(rec)
    s = np.where(table["branch"] == "up", 0.5, -0.5)
    seg = rec.segments
    mid_h = np.array([0.5 * (seg["start_s"][seg["step"] == k].min() + seg["stop_s"][seg["step"] == k].max())
                      for k in table["step"]]) / 3600.0
    out = {"twin": "bias polynomial in the sensor temperature (order 3 accelerometers, 1 gyros), no hysteresis",
           "channels": {}}
    series = []
    if "acc_bias" in table:
        series += [(f"acc_{a}", table["acc_bias"][:, j], table["T_acc"][:, j], 3, "m/s^2") for j, a in enumerate("xyz")]
    if "gyro_bias" in table:
        series += [(f"gyro_{a}", table["gyro_bias"][:, j], table["T_box"], 1, "rad/s") for j, a in enumerate("pqr")]
    for name, y, T, order, unit in series:
        X0 = _design(T, order)
        lib = [Candidate("temperature_hysteresis", f"{name}'s bias depends on whether the temperature was reached "
                         f"by heating or by cooling (hysteresis gap between the branches, {unit})", ("H",),
                         lambda _, c=s: c),
               Candidate("time_drift", f"{name}'s bias drifts in time, independently of the temperature "
                         f"({unit} per hour)", ("drift",), lambda _, c=mid_h - mid_h.mean(): c)]
        d = select_effects(y, X0, term_names(order, False), lib, rng, alpha=alpha, n_sim=n_sim)
        out["channels"][name] = d.to_dict()
    return out
