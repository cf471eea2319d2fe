"""Fit of the Delft 2005 preset's turn-table sizes to the residual envelopes of Figs. 4.20-4.21.

The published numbers (six): the residual envelope max_i |r_i| (deg/s) of the r gyro's calibration
over the 15 rates of 4.4.3 timed by the ADC, the GPS board's mark input and the HP 6700 (Fig. 4.20),
and of the p, q and r gyros' final calibration, eq. 4.39-4.41, HP timer (Fig. 4.21). The seed
prints no numbers: each envelope is read off the figure's axis, whose limit encloses the data, as
``limit - unit / 2`` with the reading's standard error ``unit / sqrt(12)`` (``unit``: the tick
spacing between the limit and 0, or the limit's last digit where the axis has no inner tick:
such limits were set by hand to the data). :data:`SEED`.

The sizes (three), each a seed-documented disturbance within its physical bound (:data:`BOUNDS`):

* ``sf_sigma``: the gyros' steady-state scale-factor instability (effect
  ``gyro_scale_instability``; datasheet A.2 "SF stability 0.03 %"),
* ``gps_jitter_s``: the GPS board's mark-input jitter (4.4.3: its clock "reaches a higher accuracy
  than the time measurement with the ADC card"),
* ``slip_density_V_rtHz``: the slip rings' contact noise density on every line (4.4.1, Fig. 4.16).

The model of the simulator. A step i (true rate Omega_i, n_i whole rounds of T_i seconds, from the
protocol and the table's slip) carries independent errors of the window mean with variance

    v_i = N^2 / T_i + b^2 g(T_i, tau_b)                 gyro ARW and bias instability (quiet lab)
        + Omega_i^2 sf_sigma^2 g(T_i, tau_sf)           scale-factor instability (own-axis rows)
        + d^2 <P^2> / (2 T_i) / S^2                      slip-ring noise, density d, profile P
        + Omega_i^2 var(dT) / T_i^2                      the timer's round-time error

g(T, tau) = (2 tau / T)(1 - (tau / T)(1 - e^(-T/tau))) (a Gauss-Markov process' window mean), S the
gyro's 6 mV/(deg/s), var(dT) = 2 (q^2/12 + jitter^2) (q: 1 ms for the ADC's 1 kHz samples, 1 us for
the GPS board and the HP counter). The residuals are r = (I - H) e with H the hat matrix of the
fit's design (Fig. 4.20: 1, V, V^2 of the r gyro; Fig. 4.21: eq. 4.39-4.41's excited terms); the
expected envelope E max |r| and its scatter come from M fixed normal draws (common random numbers,
smooth in the sizes). The sizes are the weighted least squares of Fig. 4.20's three envelopes with
weights 1 / (reading^2 + scatter^2); standard errors from (J' W J)^-1; pairs with |correlation| > 0.9
are the sizes the figures cannot separate. The fit is in the squared sizes (the variances are linear in
them); a size gets its SE by the delta method and a two-SE upper limit sqrt(x + 2 se_x). Fig. 4.21's envelopes (0.075-0.25 deg/s) lie beyond what
any sizes within the bounds give (the record's ``envelopes_at_upper_bounds``): a joint fit of all
six (``joint_fit_all_six``, kept in the record) only drags the scale-factor size up against Fig.
4.20's HP envelope, so Fig. 4.21 is a check, not a fitted target. ``python -m imurig.montecarlo.delft_fit_turn`` writes
assets/delft_2005_turn_fit.json; the slow test checks the model against the simulator.
"""
from __future__ import annotations

import json
import math
import sys
import time
from functools import lru_cache
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

from imurig.campaigns.turn_table import TIMER_STUDY_RATES_DPS
from imurig.rigs.turn_table import AXIS_OF_MOUNT, TurnTableErrors, TurnTableProtocol
from imurig.sensors.effects.gyro_noise import GyroNoise
from imurig.sensors.effects.gyro_scale_instability import DATASHEET_SIGMA, GyroScaleInstability
from imurig.sensors.effects.slip_rings import SlipRingNoise
from imurig.kernel.units import DEG

NAMES = ("sf_sigma", "gps_jitter_s", "slip_density_V_rtHz")
#: the figures' envelopes: (quantity, axis limit, reading unit), deg/s
SEED = (("fig_4_20", "adc", 0.1, 0.05), ("fig_4_20", "gps_mark", 0.06, 0.01), ("fig_4_20", "hp6700", 0.03, 0.01),
        ("fig_4_21", "p", 0.3, 0.1), ("fig_4_21", "q", 0.2, 0.1), ("fig_4_21", "r", 0.1, 0.05))
TIMER_Q_S = {"adc": 1e-3, "gps_mark": 1e-6, "hp6700": 1e-6}
GYRO_V_PER_DPS = 6e-3
#: Fig. 4.16: a slip-ring line's samples (1 kHz, 100 deg/s) span 3.02-3.08 V: 6 sigma <= 0.06 V at the worst spot
FIG_4_16_PEAK_SIGMA_V = 0.01
#: timer study (4.4.3) and final calibration (4.4.4) protocols as the campaigns run them
TIMER_PROTOCOL = TurnTableProtocol(dial_rates_dps=TIMER_STUDY_RATES_DPS, directions=(1,), mounts=("r_up",),
                                   min_window_s=3.0)
FINAL_PROTOCOL = TurnTableProtocol()
N_DRAWS = 4000
#: the preset's fit: Fig. 4.20's three envelopes (Fig. 4.21 is out of reach within the bounds: :func:`main`)
FIT_USES = (0, 1, 2)
#: the sizes fitted; the slip rings' density cannot be told from the scale factor by these figures (a
#: three-size fit's correlation is -1.00, the record's ``three_size_fit``): it stays at the quiet lab's
#: 20 uV per 1 kHz sample, and the scale factor takes the common part
FREE = ("sf_sigma", "gps_jitter_s")
FIXED = {"slip_density_V_rtHz": 20e-6 / math.sqrt(500.0)}


@lru_cache(maxsize=1)
def slip_profile_mean_sq() -> tuple[float, float]:
    """(<P^2> over a round, max P) of the slip rings' angle profile (the quiet lab's rough spots)."""
    s = SlipRingNoise()
    P = s.profile(np.linspace(0, 2 * np.pi, 7200, endpoint=False))
    return float(np.mean(P**2)), float(np.max(P))


def bounds() -> dict:
    """Physical bounds (lower, upper, source) of the three sizes."""
    _, pmax = slip_profile_mean_sq()
    return {"sf_sigma": (0.0, DATASHEET_SIGMA, "VG941-3AM datasheet (A.2): SF stability (steady state) 0.03 %"),
            "gps_jitter_s": (0.0, 1e-3 / math.sqrt(12), "4.4.3: the GPS board times better than the ADC, whose "
                             "1 ms samples give 1 ms / sqrt(12) per edge"),
            "slip_density_V_rtHz": (0.0, FIG_4_16_PEAK_SIGMA_V / pmax / math.sqrt(500.0),
                                    "Fig. 4.16: at the worst spot a 1 kHz sample's sigma <= 0.01 V (the trace spans "
                                    "0.06 V); density = sigma / (P_max sqrt(500 Hz))")}


def steps(proto: TurnTableProtocol) -> list[tuple[str, float, float]]:
    """(mount, signed true rate deg/s, whole-round window s) per step, as the table and round_windows give them:
    n = max(min_rounds, ceil(min_window / T_round)) rounds."""
    e = TurnTableErrors()
    out = []
    for st in proto.steps():
        w = float(e.true_rate_dps(st.dial_dps))
        T_round = 360.0 / abs(w)
        n = max(proto.min_rounds, math.ceil(proto.min_window_s / T_round - 1e-9))
        out.append((st.mount, w, n * T_round))
    return out


def _hat_complement(X: np.ndarray) -> np.ndarray:
    X = X[:, np.any(np.abs(X) > 1e-12, axis=0)]
    return np.eye(X.shape[0]) - X @ np.linalg.pinv(X)


def structure() -> dict:
    """The two experiments' rates, windows and projections (sizes-independent)."""
    ts = steps(TIMER_PROTOCOL)
    w = np.array([s[1] for s in ts])
    fin = steps(FINAL_PROTOCOL)
    W = np.zeros((len(fin), 3))
    for i, (m, r, _) in enumerate(fin):
        j, sgn = AXIS_OF_MOUNT[m]
        W[i, j] = sgn * r
    cols = [np.ones(len(fin))] + [W[:, j] for j in range(3)] + [W[:, j] ** 2 for j in range(3)] + \
           [W[:, 0] * W[:, 1], W[:, 0] * W[:, 2], W[:, 1] * W[:, 2]]
    return {"timer_rate_dps": w, "timer_window_s": np.array([s[2] for s in ts]),
            "timer_Q": _hat_complement(np.column_stack([np.ones_like(w), w, w**2])),
            "final_rates_dps": W, "final_window_s": np.array([s[2] for s in fin]),
            "final_Q": _hat_complement(np.column_stack(cols))}


def step_variances(theta, rate_dps, window_s, timer: str | None) -> np.ndarray:
    """v_i (deg/s)^2 of each step's window mean (module doc); ``timer`` None: a row whose reference is 0."""
    sf, jit, dens = theta
    gn = GyroNoise()
    T = np.asarray(window_s, float)
    w = np.asarray(rate_dps, float)
    quiet = (gn.arw_rad_s_per_sqrt_hz / DEG) ** 2 / T + (gn.bias_instability_rad_s / DEG) ** 2 * \
        GyroScaleInstability(sigma=1.0, tau_s=gn.bias_instability_tau_s).window_variance(T)
    v = quiet + w**2 * GyroScaleInstability(sigma=sf).window_variance(T)
    v = v + dens**2 * slip_profile_mean_sq()[0] / (2 * T) / GYRO_V_PER_DPS**2
    if timer is not None:
        q = TIMER_Q_S[timer]
        j = jit if timer == "gps_mark" else 0.0
        v = v + w**2 * 2 * (q**2 / 12 + j**2) / T**2
    return v


def envelopes(theta, st: dict | None = None, n_draws: int = N_DRAWS) -> tuple[np.ndarray, np.ndarray]:
    """(mean, sd) of the six envelopes of :data:`SEED` at sizes ``theta`` (deg/s)."""
    st = st or structure()
    z = np.random.default_rng(20050).standard_normal((n_draws, st["final_Q"].shape[0]))
    mean, sd = [], []
    for fig, key, _, _ in SEED:
        if fig == "fig_4_20":
            v = step_variances(theta, st["timer_rate_dps"], st["timer_window_s"], key)
            Q = st["timer_Q"]
        else:
            j = "pqr".index(key)
            w = st["final_rates_dps"][:, j]
            own = np.abs(w) > 0
            v = np.where(own, step_variances(theta, w, st["final_window_s"], "hp6700"),
                         step_variances(theta, np.zeros_like(w), st["final_window_s"], None))
            Q = st["final_Q"]
        r = (z[:, :v.size] * np.sqrt(v)) @ Q.T
        env = np.max(np.abs(r), axis=1)
        mean.append(env.mean())
        sd.append(env.std(ddof=1))
    return np.array(mean), np.array(sd)


def seed_values() -> tuple[np.ndarray, np.ndarray]:
    """(value, reading standard error) of the six envelopes: limit - unit/2, unit / sqrt(12)."""
    lim = np.array([s[2] for s in SEED])
    unit = np.array([s[3] for s in SEED])
    return lim - unit / 2, unit / math.sqrt(12)


def fit(target: np.ndarray | None = None, reading_se: np.ndarray | None = None, st: dict | None = None,
        use=FIT_USES, free=FREE, n_draws: int = N_DRAWS) -> dict:
    """Weighted least squares of the envelopes ``use`` (indices into :data:`SEED`; module doc) in the sizes
    ``free`` (the others at :data:`FIXED`), two passes (the weights' scatter at the first pass's sizes).
    ``target``: the six envelopes (default the seed's)."""
    st = st or structure()
    if target is None:
        target, reading_se = seed_values()
    use = np.asarray(use)
    b = bounds()
    k_free = [NAMES.index(k) for k in free]
    # the variances are linear in the squared sizes: fit x = size^2 (the Jacobian stays regular at 0)
    hi = np.array([b[k][1] for k in free]) ** 2
    full = np.array([FIXED.get(k, 0.0) for k in NAMES]) ** 2

    def sizes(xf):
        y = full.copy()
        y[k_free] = xf
        return np.sqrt(y)

    x = hi / 16
    for _ in range(2):
        se = np.sqrt(reading_se**2 + envelopes(sizes(x), st, n_draws)[1] ** 2)
        res = least_squares(lambda u: ((envelopes(sizes(u * hi), st, n_draws)[0] - target) / se)[use], x0=x / hi,
                            bounds=(np.zeros(len(free)), np.ones(len(free))), diff_step=1e-3)
        x = res.x * hi
    J = res.jac / hi
    cov = np.linalg.pinv(J.T @ J)
    sx = np.sqrt(np.diag(cov))
    corr = cov / np.outer(np.where(sx > 0, sx, 1), np.where(sx > 0, sx, 1))
    theta = np.sqrt(x)
    # size +- SE by the delta method (none at 0) and the two-SE upper limit sqrt(x + 2 se_x)
    sd = np.where(theta > 0, sx / (2 * np.where(theta > 0, theta, 1)), np.nan)
    model, scatter = envelopes(sizes(x), st, n_draws)
    z = (model - target) / se
    at_bound = [free[k] for k in range(len(free)) if x[k] >= hi[k] * (1 - 1e-6) or x[k] <= 1e-12 * hi[k]]
    inseparable = [[free[a], free[c]] for a in range(len(free)) for c in range(a + 1, len(free))
                   if abs(corr[a, c]) > 0.9]
    out = {k: {"value": float(theta[i]), "se": None if np.isnan(sd[i]) else float(sd[i]),
               "two_se_upper": float(np.sqrt(x[i] + 2 * sx[i])), "square": float(x[i]), "square_se": float(sx[i]),
               "fitted": True} for i, k in enumerate(free)}
    out.update({k: {"value": FIXED[k], "se": None, "fitted": False} for k in NAMES if k not in free})
    return {"sizes": out, "model": model.tolist(), "scatter": scatter.tolist(), "target": np.asarray(target).tolist(),
            "se": se.tolist(), "z": z.tolist(), "used": [int(i) for i in use], "chi2": float(np.sum(z[use] ** 2)),
            "dof": int(use.size - len(free)), "correlation": corr.tolist(), "at_bound": at_bound,
            "inseparable": inseparable,
            "bounds": {k: {"lower": b[k][0], "upper": b[k][1], "source": b[k][2]} for k in NAMES}}


def main(out: Path | None = None) -> dict:
    """Fit and write the record (assets/delft_2005_turn_fit.json by default)."""
    t0 = time.perf_counter()
    st = structure()
    rec = fit(st=st)
    rec["joint_fit_all_six"] = fit(st=st, use=tuple(range(len(SEED))))
    rec["three_size_fit"] = fit(st=st, free=NAMES)
    hi = [bounds()[k][1] for k in NAMES]
    rec["envelopes_at_upper_bounds"] = envelopes(hi, st)[0].tolist()
    rec["quantities"] = [f"{s[0]} {s[1]}" for s in SEED]
    rec["seed_axis"] = [{"limit": s[2], "unit": s[3]} for s in SEED]
    rec["run_s"] = time.perf_counter() - t0
    path = out or Path(__file__).resolve().parents[2] / "assets" / "delft_2005_turn_fit.json"
    path.write_text(json.dumps(rec, indent=1) + "\n")
    return rec


if __name__ == "__main__":
    r = main(Path(sys.argv[1]) if len(sys.argv) > 1 else None)
    print(json.dumps({k: r[k] for k in ("sizes", "model", "target", "z", "chi2", "at_bound", "inseparable",
                                        "run_s")}, indent=1))
