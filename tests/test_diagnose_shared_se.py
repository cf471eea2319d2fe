"""Standard errors of the position regression's refitted effects where the positions share rounding errors.

On a converter whose step q is near the noise (16 bits over +-5 V: q = 153 uV, dither 0.4 q), a
position's averaged codes carry the rounding error of its true reading, which the samples do not
average away, and positions at one level (the twelve theta = 0 / 180 positions of the x axis, the
phi pairs of one theta) share it. An OLS standard error counts those positions as independent
observations: on the independent lab a nonlinearity's z RMS was 1.63 over 20 such records. The
engine gives the refitted parameters standard errors from the noise model's covariance
(:func:`imurig.diagnose.engine._model_std_errors` with
:class:`imurig.diagnose.position_noise.SharedNoise`).

The truth: a tilt table's x-axis readings through a rounding converter, the inverse model
f = b0 + b1 r + k2 r^2 fitted to the positions' means (k2 = 0 true), over many records with a
random grid offset (the sensor's bias). The z = k2_hat / SE must have the spread its reference
distribution predicts: E z^2 = nu / (nu - 2) for a t with the Satterthwaite dof nu of the scale,
within 4 sampling SDs of the mean of z^2.
"""
from __future__ import annotations

import numpy as np

from imurig.diagnose.engine import _model_std_errors, select_effects
from imurig.diagnose.position_noise import SharedNoise, position_noise
from imurig.sensors.effects.base import Candidate

Q = 10.0 / 2 ** 16          # V, the 16-bit +-5 V step
K = 1.0 / 9.80665           # V per m/s^2
DITHER = 0.4 * Q            # the converter's noise before rounding (V rms)
N_SAMPLES = 400             # samples per position


def _positions() -> np.ndarray:
    """f_x = -g cos(phi) sin(theta) (m/s^2) of the serpentine 7 x 6 tilt positions."""
    th, ph = np.meshgrid(np.radians(np.arange(0, 181, 30)), np.radians(np.arange(0, 301, 60)), indexing="ij")
    return (-9.81 * np.cos(ph) * np.sin(th)).ravel()


def _record(rng: np.random.Generator, f: np.ndarray):
    """(position means (V), per-position sd (V)) of codes round((K f + b + n) / q) q."""
    v = K * f + rng.uniform(-0.5, 0.5) * Q + 0.004
    codes = np.rint((v[:, None] + DITHER * rng.standard_normal((f.size, N_SAMPLES))) / Q) * Q
    return codes.mean(axis=1), codes.std(axis=1, ddof=1)


def _z(rng, f, X_of):
    mean_V, sd_V = _record(rng, f)
    r = mean_V / K
    X = X_of(r)
    b = np.linalg.lstsq(X, f, rcond=None)[0]
    res = f - X @ b
    se_ols = np.sqrt(res @ res / (f.size - X.shape[1]) * np.linalg.inv(X.T @ X)[-1, -1])
    noise, info = position_noise(f, X[:, :-1], f, mean_V, Q, K, sd_V, np.full(f.size, N_SAMPLES),
                                 decimated=True, dither_V=DITHER)
    assert info["shared_level_errors"] and isinstance(noise, SharedNoise)
    S = noise.covariance
    se_model = _model_std_errors(X, f, S)[-1]
    P = np.linalg.pinv(X)
    MS = (np.eye(f.size) - X @ P) @ S
    nu = np.trace(MS) ** 2 / np.trace(MS @ MS)
    return b[-1] / se_ols, b[-1] / se_model, nu


def test_model_standard_errors_count_the_shared_rounding_once():
    rng = np.random.default_rng(16)
    f = _positions()
    out = np.array([_z(rng, f, lambda r: np.column_stack([np.ones_like(r), r, r ** 2])) for _ in range(300)])
    z_ols, z_model, nu = out.T
    expect = float(np.mean(nu / (nu - 2)))
    for z, name in ((z_model, "model"),):
        z2 = z ** 2
        tol = 4 * z2.std(ddof=1) / np.sqrt(z2.size)
        assert abs(z2.mean() - expect) < tol, (name, z2.mean(), expect, tol)
    # the OLS standard error is too small here (the failure this fixes)
    z2 = z_ols ** 2
    assert z2.mean() > expect + 4 * z2.std(ddof=1) / np.sqrt(z2.size), (z2.mean(), expect)


def test_shared_noise_draws_have_its_covariance():
    """The engine's threshold draws and its standard errors use one model: the draws' covariance,
    projected on a regression row, matches ``covariance`` within the sampling error."""
    rng = np.random.default_rng(7)
    f = _positions()
    mean_V, sd_V = _record(rng, f)
    X = np.column_stack([np.ones_like(f), mean_V / K])
    noise, _ = position_noise(f, X, f, mean_V, Q, K, sd_V, np.full(f.size, N_SAMPLES), decimated=True,
                              dither_V=DITHER)
    a = (mean_V / K) ** 2
    a = a - X @ np.linalg.lstsq(X, a, rcond=None)[0]
    proj = np.array([a @ noise(rng, f.size) for _ in range(4000)])
    want = float(a @ noise.covariance @ a)
    # var of a sample variance of n normals: 2 sigma^4 / (n - 1)
    assert abs(proj.var(ddof=1) - want) < 4 * want * np.sqrt(2 / (proj.size - 1))


def test_engine_reports_the_model_standard_error():
    """A finding accepted with a SharedNoise carries the model's standard error (not OLS's) and says so."""
    rng = np.random.default_rng(3)
    f = _positions()
    mean_V, sd_V = _record(rng, f)
    r = mean_V / K
    X0 = np.column_stack([np.ones_like(r), r])
    y = f + 2e-4 * r ** 2          # a nonlinearity far above the noise
    noise, _ = position_noise(y, X0, y, mean_V, Q, K, sd_V, np.full(f.size, N_SAMPLES), decimated=True,
                              dither_V=DITHER)
    cand = Candidate("scale_nonlinearity", "k2", ("k2",), lambda _: r ** 2)
    d = select_effects(y, X0, ["b0", "b1"], [cand], rng, alpha=0.05, n_sim=60, noise=noise)
    (fd,) = d.findings
    est, se = fd.params["scale_nonlinearity:k2"]
    X = np.column_stack([X0, r ** 2])
    assert se == _model_std_errors(X, y, noise.covariance)[-1]
    assert fd.to_dict()["std_error_model"] == "noise model's covariance"
