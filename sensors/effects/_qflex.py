"""What the Q-Flex triad's mean-level effects share: their truth maps read the same triad.

The tilt diagnosis fits the inverse model f = g(u) on the indicated specific force u = V / s_nom
(s_nom: the nominal sensitivity the lab converts with). Through the triad's measurement equation
(:mod:`imurig.sensors.accelerometer`) at the campaign's mean temperature, u_j = D_j (a_j + b_j +
k2_j a_j^2 + ...), a = (I + M) f, with the relative scale

    D_j = s_j (1 + ks_j (T_mean - T_ref)) / s_nom,j                                   [-]

Not an effect module (its name starts with "_"): the effects import it.
"""
from __future__ import annotations

from collections.abc import Mapping

import numpy as np

AXES = ("x", "y", "z")


def axis_index(channel: str) -> int:
    """0, 1, 2 for an accelerometer channel 'acc_x', 'acc_y', 'acc_z' (or an axis name)."""
    return AXES.index(channel[-1])


def accelerometers(truth: Mapping) -> Mapping:
    return truth["sensors"]["accelerometers"]


def relative_scale(truth: Mapping) -> np.ndarray:
    """D (3,): the true over the nominal sensitivity at the campaign's mean temperature (module doc).
    ``truth`` from :func:`imurig.sensors.effects.base.recording_truth` (it needs "conditions")."""
    acc = accelerometers(truth)
    cond = truth.get("conditions") or {}
    if cond.get("mean_temperature_K") is None or cond.get("acc_nominal_sensitivity_V_per_m_s2") is None:
        raise KeyError("the truth map needs the measurement's conditions (mean temperature, nominal "
                       "sensitivities): pass recording_truth(rec), not rec.truth")
    dT = float(cond["mean_temperature_K"]) - acc["reference_temperature_K"]
    return (np.asarray(acc["sensitivity_V_per_m_s2"]) * (1 + np.asarray(acc["scale_tempco_per_K"]) * dT)
            / np.asarray(cond["acc_nominal_sensitivity_V_per_m_s2"]))


def inverse_linear(truth: Mapping) -> np.ndarray:
    """The inverse model's linear coefficients (I + M)^-1 D^-1 (3, 3): row j = axis j's
    coefficients of the readings u_x, u_y, u_z (exact without nonlinearity)."""
    D = relative_scale(truth)
    return np.linalg.inv(np.eye(3) + np.asarray(accelerometers(truth)["misalignment_rad"])) / D[None, :]
