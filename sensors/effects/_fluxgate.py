"""Shared by the magnetometer effects: the recorded fluxgate in a truth mapping, and the diagnosis'
stacked-axis columns."""
from __future__ import annotations

from collections.abc import Mapping

import numpy as np

AXES = "xyz"
PAIRS = ((0, 1), (0, 2), (1, 2))
NT = 1e9  # nT per T


def fluxgate(truth: Mapping) -> Mapping:
    """The fluxgate's truth (truth["sensors"]["magnetometer"])."""
    return truth["sensors"]["magnetometer"]


def gain(truth: Mapping) -> np.ndarray:
    """g_j = s_true / s_nominal (3,): the gains the diagnosis' indicated field m = V / s_nominal carries."""
    t = fluxgate(truth)
    return np.asarray(t["sensitivity_V_per_T"], float) / np.asarray(t["nominal_sensitivity_V_per_T"], float)


def case_truth(truth: Mapping) -> Mapping:
    """What a concealed magnetometer case injected beside the sensor (truth["magnetometer_diagnosis"])."""
    return truth.get("magnetometer_diagnosis") or {}
