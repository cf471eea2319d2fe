"""Fit of the Delft 2005 preset's day-time sizes to the seed's Table 4.2 by simulating its protocol.

Tab. 4.2 (seed 4.3.2): the residual sigma of the calibration program on the raw 15 s data (every
100 Hz sample a row) and on the per-position medians, before the y line's junction box was
repaired (y: 0.3685 raw, 0.3695 median) and with the basement pump running (x, z: 0.024 raw,
0.003 median). The seed does not say which positions; the simulator takes its standard campaign
(theta 0-90 deg in 10 deg x 12 phi x 2 mountings, n = 240 positions), the linear model (p = 4),
by day (10:00, pump on), 100 Hz means of 1 kHz conversions.

As for Tab. 4.3 (:mod:`imurig.montecarlo.delft_fit`), the expected variance per axis a and
statistic k (raw, median) is a sum of independent terms

    E[sigma_k,a^2] = F_k,a + S_k,a w^2 + P_k,a s^2 + A_k,a o^2

w: the table's setting-error width [arcmin], s: the pump vibration's rms [m/s^2] (effect
``building_vibration``), o: the y contact's offset [V] (effect ``persistent_cable_fault``, open half
the time, 60 s mean dwell); F, S, P, A measured on the simulator at zero and at a reference size with
common random numbers. Weights: a residual sigma from n = 240 positions with p = 4 has relative SE
1 / sqrt(2 (n - p)) = 0.046; the raw sigma is given the same (the vibration is fresh at each
position, so the positions, not the samples, are its independent units).
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from scipy.optimize import least_squares

from imurig.calibration.preprocess import segment_statistic
from imurig.calibration.tilt_reference import tilt_table_reference
from imurig.kernel.random_streams import child_generator, child_seed_sequence
from imurig.kernel.site import Site
from imurig.montecarlo.tilt import PHI_12, THETA_SEED, TILT_TABLE
from imurig.montecarlo.tilt_rig import static_rig
from imurig.sensors.effects.building_vibration import PumpVibration
from imurig.sensors.effects.persistent_cable_fault import PersistentCableFault

N_POS, N_PAR = 240, 4
REL_SE = 1.0 / math.sqrt(2 * (N_POS - N_PAR))
PROTOCOL = {"theta_deg": list(THETA_SEED), "phi_deg": list(PHI_12), "mounts": ["z_down", "z_up"],
            "start_time": "2005-06-14T10:00:00+02:00", "model": "linear", "people": True}
REF = {"w": 2.0, "s": 0.03, "o": 0.05}
#: the design's labs. The pump's mean direction is drawn per lab (``building_vibration``), which moves one
#: lab's raw x : z split by ~12 % (its expectation is isotropic); with 2 labs the design's pump terms P_x, P_z
#: were 0.40, 0.71 (that draw's split, chi^2 26.9 on 3 dof); 8 labs bring the design's Monte-Carlo error of
#: P to ~4 %, below the seed's relative SE of 4.6 %.
DESIGN_SEEDS = tuple(range(1, 9))


def seed_table(pub: dict) -> np.ndarray:
    """(2, 3) [raw, median] x axes of ``published_figures()['table_4_2']``."""
    return np.array([pub["raw_sigma"], pub["median_sigma"]], float)


def simulate_sigmas(w_arcmin: float, pump_rms: float, offset_V: float, seed: int, effects: tuple = ()) -> np.ndarray:
    """(2, 3) residual sigma [raw, median] x axes of Tab. 4.2's protocol with these sizes (module doc)."""
    p = TILT_TABLE.validate({**PROTOCOL, "setting_resolution_arcmin": w_arcmin})
    ss = np.random.SeedSequence(seed)
    errors, survey, lab = TILT_TABLE.draw_lab(p, ss)
    eff = tuple(effects) + ((PersistentCableFault(enabled=True, channel="acc_y", offset_V=offset_V),)
                            if offset_V > 0 else ())
    lab = replace(lab, pump=PumpVibration(enabled=pump_rms > 0, rms_m_s2=max(pump_rms, 0.0)), effects=eff)
    rig = static_rig(p, errors, survey, child_generator(ss, "run/rig"), Site())
    rig.meta["averaged_logging"] = True
    rec = lab.measure(rig, child_seed_sequence(ss, "run/sensor-chain"))
    return raw_and_median_sigmas(rec)


def raw_and_median_sigmas(rec) -> np.ndarray:
    """std(ddof=1) of the linear model's residuals per axis, on every sample and on per-position medians."""
    names = ["acc_x", "acc_y", "acc_z"]
    ref, _, _ = tilt_table_reference(rec)
    V_med = segment_statistic(rec, names, "median")
    idx = [np.arange(sl.start, sl.stop) for sl in rec.segment_slices()]
    pos = np.concatenate([np.full(i.size, k) for k, i in enumerate(idx)])
    V_raw = np.column_stack([rec.channels[n][np.concatenate(idx)] for n in names])
    out = np.empty((2, 3))
    for k, (V, R) in enumerate(((V_raw, ref[pos]), (V_med, ref))):
        X = np.column_stack([np.ones(len(V)), V])
        beta, *_ = np.linalg.lstsq(X, R, rcond=None)
        out[k] = np.std(R - X @ beta, axis=0, ddof=1)
    return out


def design(seeds=DESIGN_SEEDS) -> dict:
    """F, and S, P, A per unit squared size, each (2, 3), averaged over ``seeds``."""
    terms = {"F": [], "S": [], "P": [], "A": []}
    for sd in seeds:
        f0 = simulate_sigmas(0.0, 0.0, 0.0, sd) ** 2
        terms["F"].append(f0)
        terms["S"].append((simulate_sigmas(REF["w"], 0.0, 0.0, sd) ** 2 - f0) / REF["w"] ** 2)
        terms["P"].append((simulate_sigmas(0.0, REF["s"], 0.0, sd) ** 2 - f0) / REF["s"] ** 2)
        terms["A"].append((simulate_sigmas(0.0, 0.0, REF["o"], sd) ** 2 - f0) / REF["o"] ** 2)
    return {k: np.maximum(np.mean(v, 0), 0.0) for k, v in terms.items()}


def model_sigmas(theta, d: dict) -> np.ndarray:
    w, s, o = theta
    return np.sqrt(d["F"] + d["S"] * w ** 2 + d["P"] * s ** 2 + d["A"] * o ** 2)


def fit(table: np.ndarray, d: dict) -> dict:
    """Weighted least squares of the (2, 3) ``table``; sizes (w arcmin, pump rms m/s^2, offset V) with SEs."""
    se = REL_SE * table
    res = least_squares(lambda th: ((model_sigmas(th, d) - table) / se).ravel(), x0=[1.0, 0.03, 0.07],
                        bounds=([0.0, 0.0, 0.0], [60.0, 1.0, 1.0]), x_scale=[1.0, 0.01, 0.01])
    cov = np.linalg.pinv(res.jac.T @ res.jac)
    sd = np.sqrt(np.diag(cov))
    z = (model_sigmas(res.x, d) - table) / se
    keys = ("setting_error_arcmin", "pump_rms_m_s2", "cable_offset_V")
    return {"sizes": {k: {"value": float(v), "se": float(e)} for k, v, e in zip(keys, res.x, sd)},
            "chi2": float(np.sum(z ** 2)), "dof": int(table.size - 3), "z": z.tolist(),
            "model": model_sigmas(res.x, d).tolist(), "correlation": (cov / np.outer(sd, sd)).tolist()}
