"""Forward-model residuals of a score: how well the estimated parameters explain the
measurements, against the floor the injected parameters reach.

Tilt and turn table (``triad_forward``): per segment the indicated quantity
r_i = V_i / s_i - (a_i + b_i + k2_i a_i^2), a = (I + M) q with q the true input, in m/s^2 or
rad/s. Magnetometer (``field_norm``): the calibrated field norm on the tumble,
|A^-1 (m - b)| - F in tesla, from b and A A' alone. The data come from
:data:`imurig.scoring.truth.RESIDUALS`.
"""
from __future__ import annotations

import numpy as np


def _triad_indicated_residual(d: dict, values: dict) -> dict:
    axes = d["axes"]
    q = np.asarray(d["true_input"], float)
    V = np.asarray(d["measured_volts"], float)
    M = np.eye(3)
    for i, a in enumerate(axes):
        for j, c in enumerate(axes):
            if i != j:
                M[i, j] = values[f"misalignment_{a}{c}"]
    aS = q @ M.T
    s = np.array([values[f"sensitivity_{a}"] for a in axes])
    b = np.array([values[f"bias_{a}"] for a in axes])
    k2 = np.array([values[f"nonlinearity_{a}"] for a in axes])
    r = V / s - (aS + b + k2 * aS**2)
    return {a: float(np.sqrt(np.mean(r[:, j] ** 2))) for j, a in enumerate(axes)}


def _field_norm_residual(d: dict, values: dict) -> dict:
    n = ("xx", "xy", "xz", "yy", "yz", "zz")
    T = np.zeros((3, 3))
    for k, (i, j) in zip(n, zip(*np.triu_indices(3))):
        T[i, j] = T[j, i] = values[f"3d:AAt_{k}"]
    b = np.array([values[f"3d:b_{a}"] for a in "xyz"])
    m = np.asarray(d["indicated_T"], float) - b
    try:
        Ti = np.linalg.inv(T)
    except np.linalg.LinAlgError:
        return {"norm": float("inf")}
    q = np.einsum("ni,ij,nj->n", m, Ti, m)
    norm = np.sqrt(np.clip(q, 0, None))
    return {"norm": float(np.sqrt(np.mean((norm - d["field_T"]) ** 2)))}


def compute_residuals(truth, values: dict) -> dict:
    """Residual RMS with the estimated ``values`` (SI, by name) and with the injected ones, for
    the residual data and parameters of ``truth`` (a :class:`imurig.scoring.score.TruthSet`)."""
    d = truth.residuals
    if not d:
        return {}
    f = {"triad_forward": _triad_indicated_residual, "field_norm": _field_norm_residual}[d["kind"]]
    inj = {p["name"]: p["injected"] for p in truth.parameters}
    return {"forward_model": {"unit": d["unit"], "rms": f(d, values), "floor_rms": f(d, inj), "what": d["what"]}}
