"""The seed's own accelerometer unit (Tab. 4.6 inverted) on the Delft 2005 preset: which part of it the tilt items
fitted to Tabs. 4.3-4.5 allow (docs/reproduce.md, "Paper Fig. 3: the seed's own unit").

Tab. 4.6's final model A = X(u) beta maps the manufacturer's reading u to the reference; its affine part (scale,
bias, misalignment) is absorbed by any model with the linear terms, its squares and product are not. The study
runs, for the drawn unit, the whole Tab. 4.6 unit and its affine part (:func:`imurig.campaigns.delft_2005_imu.
accelerometer_unit`), at the preset's fitted sizes:

* Tab. 4.3's protocol at 50 kHz (no grounded slot), the linear model's sigma per axis (rms over labs), against the
  seed's with its SE sigma / 8;
* the final campaign (Tabs. 4.4-4.5's sizes): the linear and cross models' sigma (rms over labs), and per mounting
  (120 positions, paper Fig. 3's "120 samples") the own (physical) model's residual envelope and sigma, and the
  manufacturer's envelope max |A - u|;
* noise-free, the whole unit's linear sigma on Tab. 4.3's 36 positions (n - 4 degrees of freedom).

``python -m imurig.montecarlo.delft_tab46_study`` prints the numbers (about 30 s of CPU).
"""
from __future__ import annotations

import json
import math
import time
import tomllib
from importlib import resources

import numpy as np

from imurig.calibration.accelerometer import INPUTS, MODELS
from imurig.campaigns.delft_2005 import Delft2005
from imurig.campaigns.delft_2005_imu import ACCELEROMETER_UNITS, tab46_manufacturer_reading
from imurig.kernel.units import ARCMIN
from imurig.montecarlo import delft_fit as fit_43
from imurig.montecarlo import delft_fit_44 as fit_44

SEED_43, SEED_FINAL = 9100, 9200


def _tab43_seed() -> np.ndarray:
    """(5, 3) the seed's Tab. 4.3 sigmas (the package's published_figures.toml, as delft_fit reads it)."""
    pub = tomllib.loads(resources.files("imurig.assets").joinpath("published_figures.toml").read_text())
    return fit_43.seed_table(pub["table_4_3"])


def own_fit(u: np.ndarray, ref: np.ndarray, model: str = "physical") -> np.ndarray:
    """Residuals (3, n) X beta - A of ``model`` per axis by least squares (the seed's listing C.1.1)."""
    inputs = {n: u[:, j] for j, n in enumerate(INPUTS)}
    out = []
    for a, ax in enumerate("xyz"):
        X = MODELS[model](ax).design(inputs)
        out.append(X @ np.linalg.lstsq(X, ref[:, a], rcond=None)[0] - ref[:, a])
    return np.array(out)


def noise_free_tab43() -> dict:
    """The whole unit's linear sigma on Tab. 4.3's positions, noise-free, and its z against the seed's 15 sigmas."""
    from imurig.rigs.tilt_table import specific_force_C   # lazy: the rig module loads MuJoCo

    p = fit_43.PROTOCOL
    th, ph = np.radians(np.repeat(p["theta_deg"], 12)), np.radians(np.tile(p["phi_deg"], len(p["theta_deg"])))
    A = specific_force_C(th, ph, p["mounts"][0], 9.81242231)
    r = own_fit(tab46_manufacturer_reading(A), A, "linear")
    s = np.sqrt(np.sum(r**2, axis=1) / (len(A) - 4))
    seed = _tab43_seed()
    return {"sigma": s.tolist(), "z_vs_seed": ((s - seed) / (seed / 8)).round(2).tolist()}


def main(n_43: int = 4, n_final: int = 2) -> dict:
    t0 = time.process_time()
    pre = Delft2005.fitted()
    seed50 = _tab43_seed()[1]
    out = {"noise_free_tab_4_3": noise_free_tab43(), "units": {}}
    for unit in ACCELEROMETER_UNITS:
        s43 = np.array([fit_43.residual_sigmas(fit_43.simulate_record(
            pre.setting_error_rad / ARCMIN, pre.settling_tau_s, pre.settling_tau_y_s, 50e3, False, SEED_43 + k,
            (pre.slow_tail_alpha, pre.slow_tail_tau_s), accelerometers=unit)) for k in range(n_43)])
        rms43 = np.sqrt(np.mean(s43**2, axis=0))
        sig, env, own, man = [], [], [], []
        for k in range(n_final):
            rec = fit_44.final_lab(SEED_FINAL + k, pre.final_setting_error_rad / ARCMIN,
                                   pre.reference_phi_error_rad / ARCMIN, preset=pre, accelerometers=unit)
            u, ref = fit_44.indicated_and_reference(rec)
            sig.append(fit_44.lab_statistics(u, ref)["sigma"])
            mount = np.asarray(rec.segments["mount"])
            for m in ("z_down", "z_up"):
                i = mount == m
                r = own_fit(u[i], ref[i])
                env.append(np.abs(r).max(axis=1))
                own.append(r.std(axis=1, ddof=1))
                man.append(np.abs(ref[i] - u[i]).max(axis=0))
        sig = np.sqrt(np.mean(np.array(sig) ** 2, axis=0))
        out["units"][unit] = {
            "tab_4_3_50kHz_sigma": rms43.tolist(), "tab_4_3_50kHz_z": ((rms43 - seed50) / (seed50 / 8)).tolist(),
            "tab_4_4_sigma": sig[0].tolist(), "tab_4_5_sigma": sig[1].tolist(),
            "tab_4_4_z": ((sig[0] - np.array(fit_44.SEED_SIGMA["tab_4_4"]))
                          / (np.array(fit_44.SEED_SIGMA["tab_4_4"]) / math.sqrt(2 * (240 - 4)))).tolist(),
            "one_mounting_own_envelope": [float(np.min(env)), float(np.max(env))],
            "one_mounting_own_sigma": [float(np.min(own)), float(np.max(own))],
            "one_mounting_manufacturer_envelope_xyz": np.max(man, axis=0).tolist()}
    out["cpu_s"] = time.process_time() - t0
    return out


if __name__ == "__main__":
    print(json.dumps(main(), indent=1))
