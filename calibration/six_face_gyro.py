"""Gyro calibration from rotations through a known angle (the six-position-and-rotation protocol).

Measurement equation (indicated rate u = x / s_nom, SI; K = S (I + M) the scale and misalignment):

    u(t) = K w(t) + b + n(t)

For rotation i, over its window [t0, t1) of length T_i, the rate integrated with the bias b^
(the mean over the six still faces, each face weighted equally) removed is

    A_i = sum (u - b^) dt = K theta_i + (b - b^) T_i + int n dt,     theta_i = +-angle e_axis(i)

(the body's rate integrated over a closed turn about a fixed axis; the Earth's rate, < 1e-4 of a
turn over a few seconds, is left out). Per gyro j the row K_j solves A_j = K_j Theta by generalised
least squares with

    cov(A_j) = diag(q_j T_i) + var(b^_j) T T',

q_j (SI^2 s) the noise's low-frequency density from the still faces (variance of a face's mean
by batch means x the face's duration, averaged over faces) and var(b^_j) = sum_f var_f / 36.
With one rotation per axis Theta is 3 x 3 and K = A Theta^-1 exactly: the standard errors come
from the noise alone. Parameters: sensitivity_j = K_jj s_nom,j, misalignment_jk = K_jk / K_jj,
bias_j = b^_j / K_jj. A rate nonlinearity cannot be identified from integrated angles at one rate
per axis and is refused (:class:`~imurig.kernel.errors.UnidentifiableTermsError`).
"""
from __future__ import annotations

import numpy as np

from imurig.calibration.gls import delta_cov
from imurig.calibration.six_face import FACES, face_table
from imurig.kernel.errors import RecordingError, UnidentifiableTermsError

AXES = ("p", "q", "r")


def rotation_angles(gyro_u: np.ndarray, fs: float, rotations: list[dict], bias: np.ndarray):
    """(A (3, m) integrated angles, Theta (3, m) references, T (m,) durations) of the rotations."""
    dt = 1.0 / fs
    A = np.array([(gyro_u[r["slice"]] - bias).sum(axis=0) * dt for r in rotations]).T
    Th = np.zeros((3, len(rotations)))
    for i, r in enumerate(rotations):
        Th[r["axis"], i] = r["angle_rad"]
    T = np.array([(r["slice"].stop - r["slice"].start) * dt for r in rotations])
    return A, Th, T


def refuse_nonlinearity(rotations: list[dict], fs: float) -> None:
    """Raise UnidentifiableTermsError: integrated angles at one rate per axis cannot give a nonlinearity."""
    rates = {a: sorted({round(abs(r["angle_rad"]) * fs / (r["slice"].stop - r["slice"].start), 2)
                        for r in rotations if r["axis"] == k}) for k, a in enumerate(AXES)}
    raise UnidentifiableTermsError(
        "a gyro nonlinearity cannot be identified from rotations through a known angle: the integrated angle "
        "gives one number per rotation, which the scale factor already explains (mean rates per axis, rad/s: "
        f"{rates}). Fit the linear model (--model linear), or calibrate the nonlinearity on a turn table at "
        "several rates (--rig turn-table)", [f"w{a}^2" for a in AXES])


def fit_gyro(gyro_u: np.ndarray, fs: float, faces: dict, rotations: list[dict], sensitivity=np.ones(3),
             unit: str = "1", batches: int = 10) -> dict:
    """Scale and misalignment from the rotations, bias from the faces (module doc). Returns
    {'parameters': [...], 'K', 'bias', 'angles_rad', 'reference_rad', 'durations_s'}."""
    axes_seen = {r["axis"] for r in rotations}
    if axes_seen != {0, 1, 2}:
        missing = [AXES[k] for k in range(3) if k not in axes_seen]
        raise RecordingError(f"the gyro calibration needs a rotation about each axis; found none about "
                             f"{missing}. Turn the box through the known angle about every axis "
                             "(or give --rotation-deg if the angle was not 360 deg)")
    means, var, n = face_table(gyro_u, faces, batches)
    bias = means.mean(axis=0)
    var_b = var.sum(axis=0) / len(FACES) ** 2
    q = np.mean(var * (n[:, None] / fs), axis=0)
    A, Th, T = rotation_angles(gyro_u, fs, rotations, bias)
    rows, covs = [], []
    for j in range(3):
        C = np.diag(q[j] * T) + var_b[j] * np.outer(T, T)
        X = Th.T
        Ci = np.linalg.inv(C)
        cov = np.linalg.inv(X.T @ Ci @ X)
        rows.append(cov @ X.T @ Ci @ A[j])
        covs.append(cov)
    K = np.array(rows)
    x = np.concatenate([K.ravel(), bias])
    cov = np.zeros((12, 12))
    for j in range(3):
        cov[3 * j:3 * j + 3, 3 * j:3 * j + 3] = covs[j]
    cov[9:, 9:] = np.diag(var_b)
    sens = np.asarray(sensitivity, float)

    def h(v):
        Kv = v[:9].reshape(3, 3)
        G = np.diag(Kv)
        return np.array(list(G * sens) + [Kv[i, k] / Kv[i, i] for i in range(3) for k in range(3) if i != k]
                        + list(v[9:] / G))

    est, se = h(x), np.sqrt(np.clip(np.diag(delta_cov(h, x, cov)), 0, None))
    names = ([(f"sensitivity_{a}", f"{unit}/(rad/s)") for a in AXES]
             + [(f"misalignment_{AXES[i]}{AXES[k]}", "rad") for i in range(3) for k in range(3) if i != k]
             + [(f"bias_{a}", "rad/s") for a in AXES])
    return {"parameters": [{"name": nm, "unit": u, "estimate": float(e), "std_error": float(s)}
                           for (nm, u), e, s in zip(names, est, se)],
            "K": K, "bias": bias, "angles_rad": A, "reference_rad": Th, "durations_s": T}


def inverse_model(K: np.ndarray, b: np.ndarray, axes, inputs) -> dict:
    """The linear inverse model q = K^-1 (u - b) as {axis: {terms, coef}} (calibration.json)."""
    Ki = np.linalg.inv(K)
    c = -Ki @ b
    return {a: {"terms": ["1", *inputs], "coef": [float(c[j]), *map(float, Ki[j])]} for j, a in enumerate(axes)}
