"""Fit of the virtual C181's once-per-round rate ripple to Table B.1's scatter about a quadratic calibration.

The published number: the residual variance of the seed's SIMONA gyros about a quadratic calibration
omega_ref = b0 + b1 V + b2 V^2 over Table B.1's 25 rows (the random part: the table's nonlinearity k2 is
taken up by b2), pooled over the three gyros: s2 = (s_p^2 + s_q^2 + s_r^2) / 3, s_k^2 = r_k' r_k / (25 - 3).

The size (one): the table's relative once-per-round rate ripple a (``TurnTableErrors.ripple``; rate
Omega (1 + a sin(theta + phi))), which the virtual SIMONA's voltmeter reads for 0.2 s at a random moment
of the timed round. The seed documents no ripple (4.4.1: the ball-and-disc rate changer "eliminates all
extra movements except the linear rate changing movement desired"); the quiet lab's 1e-3 was a project
choice. Bound: a >= 0, no upper bound printed by the seed.

The model of the simulator (:func:`imurig.campaigns.turn_table.simona_virtual`), row by row, the
experiment's other parts as the quiet lab has them (nothing else is fitted here):

    omega_ref,i = 360 / round(T_i, 2),  T_i = 360 / |Omega_i|          stopwatch printed to 0.01 s
    w_i = |Omega_i| (1 + a rho_i sin psi_i) + n_i                     the 0.2 s reading, psi ~ U(0, 2 pi)
    V_ik = q_r round((g_r S (w_i + k2_k w_i^2) + e_r) / q_r)          autoscaling voltmeter, range r(|V|)

Omega_i the table's true rate (dial x 5/6 less the slip, times 1 + the dial setting error), rho_i =
sinc of the angle the table turns in the 0.2 s reading (the ripple's window mean), n_i the gyros' ARW and
bias instability over 0.2 s, S 5.44 mV/(deg/s), k2_k Table B.1's (:func:`table_b1_gyro_k2`), g_r, q_r, e_r
the voltmeter's gain, display step and noise per range. The three gyros share the stopwatch and the
reading moment (one table), not the voltmeter's noise and rounding. The expected s2 and its scatter over
labs come from :data:`N_DRAWS` fixed draws (common random numbers: smooth in a); a^2 solves E s2(a^2) =
the seed's s2, its SE is the scatter of s2 over labs divided by dE s2 / d(a^2) (delta method), and the
two-SE upper limit is sqrt(a^2 + 2 se(a^2)). The test checks the model against the simulator.
``python -m imurig.montecarlo.delft_fit_simona`` writes assets/delft_2005_simona_fit.json.
"""
from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path

import numpy as np
from scipy.optimize import brentq

from imurig.calibration.simona import GYROS, SimonaCalibration, read_simona
from imurig.campaigns.delft_2005_imu import table_b1_gyro_k2
from imurig.campaigns.turn_table import SimonaSetup
from imurig.sensors.effects.gyro_noise import GyroNoise

N_DRAWS = 4000
#: the fit's statistic: degrees of freedom of one gyro's quadratic calibration over Table B.1's rows
N_ROWS, N_COEF = 25, 3
BOUND_SOURCE = ("none printed: the seed documents no ripple (4.4.1: the rate changer 'eliminates all extra movements "
                "except the linear rate changing movement desired'); a >= 0")
FIT_ASSET = "delft_2005_simona_fit.json"


def quadratic_residual_variance(V: np.ndarray, w: np.ndarray) -> np.ndarray:
    """r'r / (n - 3) of w = b0 + b1 V + b2 V^2 by least squares, over the last axis (batched: V, w (..., n))."""
    X = np.stack([np.ones_like(V), V, V**2], axis=-1)
    b = np.linalg.solve(np.swapaxes(X, -1, -2) @ X, (np.swapaxes(X, -1, -2) @ w[..., None]))[..., 0]
    r = w - (X @ b[..., None])[..., 0]
    return np.sum(r**2, axis=-1) / (w.shape[-1] - N_COEF)


def seed_statistic() -> dict:
    """Table B.1's s_k (deg/s) about a quadratic per gyro and the pooled s2 ((deg/s)^2)."""
    s = SimonaCalibration().fit(read_simona()).summary_
    v = {g: float(quadratic_residual_variance(np.asarray(s[g]["voltage_V"]), np.asarray(s[g]["reference_rate_dps"])))
         for g in GYROS}
    return {"sigma_dps": {g: math.sqrt(v[g]) for g in GYROS}, "pooled_s2": float(np.mean(list(v.values())))}


def structure(setup: SimonaSetup | None = None, n_draws: int = N_DRAWS, seed: int = 20051) -> dict:
    """The experiment's rows and the fixed draws (independent of a): true rates, stopwatch references,
    the ripple's window factor and phase, the gyros' noise, the voltmeter's noise (module doc)."""
    s = setup or SimonaSetup()
    e = s.table
    rng = np.random.default_rng(seed)
    dial = np.asarray(s.dial_dps, float)
    Om = np.abs(e.true_rate_dps(dial, rng.normal(0.0, e.dial_setting_error, (n_draws, dial.size))))
    T = 360.0 / Om
    ref = 360.0 / np.round(T, s.printed_round_decimals if s.printed_round_decimals is not None else 6)
    turn = np.radians(Om) * s.voltmeter.integration_s                     # angle turned while reading (rad)
    rho = np.sinc(turn / (2 * np.pi))                                     # sin(x/2) / (x/2)
    gn = GyroNoise()
    sd_noise = math.degrees(math.hypot(gn.arw_rad_s_per_sqrt_hz / math.sqrt(s.voltmeter.integration_s),
                                       gn.bias_instability_rad_s))
    z = lambda *shape: rng.standard_normal(shape)  # noqa: E731
    # row 0: the table at rest (reference 0); rows 1..: the dial settings
    pad = lambda x: np.concatenate([np.zeros((n_draws, 1)), x], axis=1)  # noqa: E731
    return {"rate_dps": pad(Om), "ref_dps": pad(ref), "rho": pad(rho),
            "sin_psi": pad(np.sin(rng.uniform(0, 2 * np.pi, Om.shape))), "noise_dps": sd_noise * z(n_draws, 1 + dial.size),
            "volt_z": z(n_draws, 3, 1 + dial.size), "setup": s}


def pooled_s2(a: float, st: dict) -> np.ndarray:
    """(n_draws,) pooled variance about a quadratic at ripple ``a`` (module doc); also per gyro in ``[:, k]``."""
    s = st["setup"]
    vm = s.voltmeter
    k2 = table_b1_gyro_k2()
    w = st["rate_dps"] * (1 + a * st["rho"] * st["sin_psi"]) + st["noise_dps"]
    out = []
    for k, g in enumerate(GYROS):
        v = s.scale_mV_per_dps * 1e-3 * (w + k2[g]["value_per_dps"] * w**2)
        r = np.minimum(np.searchsorted(np.asarray(vm.limits_V), np.abs(v), side="right"), len(vm.limits_V) - 1)
        q, gain, sd = (np.asarray(x)[r] for x in (vm.resolution_V, vm.gain, vm.noise_V))
        V = np.round((gain * v + sd * st["volt_z"][:, k]) / q) * q
        out.append(quadratic_residual_variance(V, st["ref_dps"]))
    per = np.stack(out, axis=1)
    return np.column_stack([per.mean(axis=1), per])


def fit(st: dict | None = None, target: float | None = None, a_max: float = 1e-2) -> dict:
    """a (relative ripple) with its SE and two-SE upper limit from the pooled s2 (module doc)."""
    st = st or structure()
    seed = seed_statistic()
    target = seed["pooled_s2"] if target is None else target
    mean = lambda a: float(pooled_s2(a, st)[:, 0].mean())  # noqa: E731
    h = 1e-4
    if mean(0.0) >= target:
        x = 0.0
    else:
        a_hat = brentq(lambda a: mean(a) - target, 0.0, a_max, xtol=1e-9)
        x = a_hat**2
    s2 = pooled_s2(math.sqrt(x), st)
    slope = (mean(math.sqrt(x + h**2)) - mean(math.sqrt(x))) / h**2       # dE s2 / d(a^2)
    sd_s2 = float(s2[:, 0].std(ddof=1))
    se_x = sd_s2 / slope
    a = math.sqrt(x)
    per_mean, per_sd = s2[:, 1:].mean(axis=0), s2[:, 1:].std(axis=0, ddof=1)
    sig = {g: seed["sigma_dps"][g] for g in GYROS}
    return {"sizes": {"table_ripple": {
                "value": a, "se": se_x / (2 * a) if a > 0 else None, "square": x, "square_se": se_x,
                "two_se_upper": math.sqrt(x + 2 * se_x), "at_bound": x == 0.0,
                "bound": {"lower": 0.0, "upper": None, "source": BOUND_SOURCE}}},
            "target_pooled_s2": target, "model_pooled_s2": float(s2[:, 0].mean()), "scatter_pooled_s2": sd_s2,
            "slope_per_a2": slope, "model_pooled_s2_at_quiet_1e-3": mean(1e-3),
            "model_pooled_s2_at_0": mean(0.0),
            "seed_sigma_dps": sig,
            "model_sigma_dps": {g: float(math.sqrt(per_mean[k])) for k, g in enumerate(GYROS)},
            "z_per_gyro_s2": {g: float((sig[g] ** 2 - per_mean[k]) / per_sd[k]) for k, g in enumerate(GYROS)},
            "n_draws": int(s2.shape[0])}


def main(out: Path | None = None) -> dict:
    """Fit and write the record (assets/delft_2005_simona_fit.json by default)."""
    t0 = time.perf_counter()
    rec = fit()
    rec["run_s"] = time.perf_counter() - t0
    path = out or Path(__file__).resolve().parents[2] / "assets" / FIT_ASSET
    path.write_text(json.dumps(rec, indent=1) + "\n")
    return rec


if __name__ == "__main__":
    print(json.dumps(main(Path(sys.argv[1]) if len(sys.argv) > 1 else None), indent=1))
