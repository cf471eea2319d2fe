"""Diagnosis of a thermal-chamber recording (seed 4.5: two cycles, six attitudes per step).

The twin is the seed's temperature model without hysteresis: per temperature step the
six-position accelerometer bias b_i (m/s^2) and the gyro bias (rad/s, Earth rate removed)
against the sensor's temperature reading, dT = T - 298.15 K,

    b(T) = c0 + c1 dT + c2 dT^2 + c3 dT^3        (accelerometers)
    b(T) = c0 + c1 dT                            (gyros)

Candidate effect per channel:

- ``temperature_hysteresis``: the column s = +1/2 on steps reached by heating, -1/2 by
  cooling; its amplitude H is the gap between the branches (the play-operator hysteresis
  of the sensor chain, :func:`imurig.sensors.thermal.hysteresis_state`).

A ``time_drift`` candidate (bias linear in the step's mid-time: ageing, turn-on settling) was
removed: the sensor chain has no such mechanism, so it could be neither simulated nor checked
against a truth, and it fired falsely (gyro_p, seed 109 of the hysteresis case). A drift that is
really there shows as a structured residual (``unexplained``: lag-1 autocorrelation of the
step residuals, taken in time order).
"""
from __future__ import annotations

import numpy as np

from imurig.calibration.thermal import _design, step_table, term_names
from imurig.diagnose.engine import ar1_covariance, select_effects
from imurig.kernel.recording import Recording
from imurig.sensors.effects import ThermalView, for_view


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
        view = ThermalView(channel=name, unit=unit, branch=s)
        lib = [c for cls in for_view(ThermalView.kind) for c in cls().candidates(view)]
        # successive steps share the thermal lag: their errors are correlated (the null study gave 16
        # false findings in 360 channel tests at alpha 0.01 with white errors); test on AR(1)-whitened
        # residuals, phi from the nominal fit (benchmarks/bench_diagnose.py --fdr)
        cov = ar1_covariance(y, X0)
        d = select_effects(y, X0, term_names(order, False), lib, rng, alpha=alpha, n_sim=n_sim, cov=cov)
        # for the report: the fit step by step (AR(1)-whitened, the engine's space) and the step-bias
        # residuals before/after in the channel's own unit (y - X b: the engine's residuals are whitened)
        from imurig.reports.diagnosis import effect_steps

        st = effect_steps(y, X0, term_names(order, False), lib, d, cov=cov)
        out["channels"][name] = {**d.to_dict(), "fit_steps": st["steps"], "residuals": {
            "temperature_K": np.asarray(T, float).tolist(), "heating": (s > 0).tolist(), "mid_time_h": mid_h.tolist(),
            "before": st["resid_before"].tolist(), "after": st["resid_after"].tolist(), "unit": unit,
            "recording": np.asarray(y, float).tolist(), "twin": (y - st["resid_before"]).tolist(),
            "corrected_twin": (y - st["resid_after"]).tolist(),
            "convention": "residual = recording (six-position step bias) - twin (temperature polynomial)"}}
    return out
