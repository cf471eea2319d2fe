"""The Earth's rate cannot masquerade as a gyro g-sensitivity: numpy-made whole-round means of a
level table (six faces, the spin axis vertical), gyros whose output lacks the Earth's vertical rate
the twin adds; the g-sensitivity column fits it exactly, and the guard never lets it stand as a
plain g-sensitivity: it names the Earth-rate mismatch as its indistinguishable alternative."""
from __future__ import annotations

import numpy as np
import pytest

from imurig.diagnose.engine import select_effects
from imurig.diagnose.turn_table import EARTH_RATE_MISMATCH, earth_rate_guard
from imurig.kernel.site import EARTH_RATE_RAD_S
from imurig.sensors.effects import TurnView, for_view

G = 9.81
OMEGA_V = EARTH_RATE_RAD_S * np.sin(np.radians(52.0))


def _windows(j, recorded_earth: bool, G_true=0.0, seed=0, sigma=2e-7):
    """Gyro j's reference (the twin's: table rate + Earth's vertical rate along e_j) and reading."""
    rng = np.random.default_rng(seed)
    e = np.repeat([1.0, -1.0, 0.0, 0.0, 0.0, 0.0], 4)              # gyro j up, down, horizontal (4 faces)
    rate = np.tile([0.1, -0.1, 0.5, -0.5], 6)                      # table rate, rad/s
    ref = e * (rate + OMEGA_V)
    true = e * (rate + (OMEGA_V if recorded_earth else 0.0)) + G_true * G * e
    u = 0.02 + 1.001 * true + sigma * rng.standard_normal(e.size)  # indicated rate (rad/s)
    view = TurnView(channel=f"gyro_{'pqr'[j]}", axis="pqr"[j], on_axis=e, specific_force_m_s2=G * e,
                    table_rate_rad_s=rate)
    lib = [c for cls in for_view(TurnView.kind) for c in cls().candidates(view)]
    X0 = np.column_stack([np.ones(e.size), u])
    return select_effects(ref, X0, ["b", "a"], lib, np.random.default_rng(seed + 1), alpha=0.01, n_sim=200)


@pytest.mark.parametrize("j", [0, 1, 2])
def test_missing_earth_rate_is_not_g_sensitivity(j):
    d = _windows(j, recorded_earth=False, seed=j)
    assert [f.name for f in d.findings] == ["g_sensitivity"]          # the engine alone: the false finding
    (mark,) = earth_rate_guard(d.findings, OMEGA_V, G)
    assert d.findings[0].runner_up == EARTH_RATE_MISMATCH and d.findings[0].to_dict()["indistinguishable_from"] \
        == EARTH_RATE_MISMATCH
    assert abs(mark["G_times_g_rad_s"] + OMEGA_V) < 4 * mark["G_se"] * G


def test_a_real_g_sensitivity_is_kept():
    """G = 10 deg/h/g (5 times the Earth's vertical rate / g): far from +-Omega_v / g, kept."""
    G_true = 5 * OMEGA_V / G
    d = _windows(0, recorded_earth=True, G_true=G_true, seed=7)
    assert earth_rate_guard(d.findings, OMEGA_V, G) == []
    assert [f.name for f in d.findings] == ["g_sensitivity"] and d.findings[0].runner_up is None
    est, se = d.findings[0].params["g_sensitivity:G"]
    assert abs(est - G_true) < 4 * se


def test_earth_rate_in_the_record_no_finding():
    d = _windows(1, recorded_earth=True, seed=3)
    assert d.findings == []
