"""The Delft 2005 preset's own IMU: sizes estimated from the seed's published data (issue 17)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from imurig.campaigns.delft_2005_imu import (GYRO_SCALE_BOUNDS, NOMINAL_GYRO_SCALE_V_PER_RAD_S, Delft2005Imu,
                                             table_b1_gyro_scale)
from imurig.campaigns.delft_2005_turn import Delft2005Turn
from imurig.kernel.units import DEG
from imurig.sensors.chain import ImuLab

TABLE_B1 = Path(__file__).resolve().parents[1] / ".." / "shared" / "reference" / "simona_gyro_table_b1.csv"


def _independent_table_b1_fit() -> tuple[np.ndarray, np.ndarray]:
    """Scale factors (V per rad/s) and SEs by a plain least squares of the seed's CSV, independent of
    the project's SIMONA code: rate = 360 / T_round (0 at rest) = b0 + b1 V, S = 1 / b1 (deg -> rad)."""
    lines = [ln for ln in TABLE_B1.read_text().splitlines() if ln.strip() and not ln.startswith("#")]
    head = lines[0].split(",")
    rows = np.array([[float(v) for v in ln.split(",")] for ln in lines[1:]])
    d = {h: rows[:, k] for k, h in enumerate(head)}
    T = d["measured_round_s"]
    rate = np.where(T > 0, 360.0 / np.where(T > 0, T, 1.0), 0.0)
    S, se = [], []
    for g in "pqr":
        V = d[f"{g}_V"]
        X = np.column_stack([np.ones_like(V), V])
        coef, res, *_ = np.linalg.lstsq(X, rate, rcond=None)
        s2 = res[0] / (V.size - 2)
        cov = s2 * np.linalg.inv(X.T @ X)
        S.append(1.0 / coef[1] / DEG)
        se.append(np.sqrt(cov[1, 1]) / coef[1] ** 2 / DEG)
    return np.array(S), np.array(se)


def test_preset_gyro_scale_factors_are_table_b1_estimates_within_bounds():
    """The preset's scale factors equal an independent least squares of Table B.1 (to rounding of the
    arithmetic), their SEs too, and lie inside the stated physical bound around the datasheet's 6 mV/(deg/s)."""
    S, se = _independent_table_b1_fit()
    imu = Delft2005Imu.estimated()
    np.testing.assert_allclose(imu.gyro_scale_V_per_rad_s, S, rtol=1e-9)
    np.testing.assert_allclose(imu.gyro_scale_se_V_per_rad_s, se, rtol=1e-6)
    assert imu.within_bounds()
    r = S / NOMINAL_GYRO_SCALE_V_PER_RAD_S
    assert np.all((r > GYRO_SCALE_BOUNDS[0]) & (r < GYRO_SCALE_BOUNDS[1]))
    # the estimate is far from the datasheet's nominal in units of its own SE (the point of the preset)
    assert np.all(np.abs(S - NOMINAL_GYRO_SCALE_V_PER_RAD_S) > 100 * se)
    assert table_b1_gyro_scale()["p"]["n_rows"] == 25


def test_turn_preset_chain_carries_the_estimates_and_the_quiet_lab_does_not():
    imu = Delft2005Imu.estimated()
    quiet = ImuLab()
    lab = Delft2005Turn.fitted().apply(quiet, 100.0)
    np.testing.assert_array_equal(lab.gyros.scale_V_per_rad_s, imu.gyro_scale_V_per_rad_s)
    # the manufacturer's nominal stays the datasheet's (the manufacturer's conversion uses it)
    assert lab.gyros.nominal_scale_V_per_rad_s == NOMINAL_GYRO_SCALE_V_PER_RAD_S
    np.testing.assert_array_equal(quiet.gyros.scale_V_per_rad_s, np.full(3, NOMINAL_GYRO_SCALE_V_PER_RAD_S))


def test_thermal_preset_r_gyro_bias_tempco_is_the_fig2_reading():
    """Fig. 2's r panel (y 6.0-8.5 mV, tick 0.5 mV; x 2.3-3.2 V, tick 0.1 V; 10 mV/K): the slope's bounds
    2.0 mV / 0.9 V and 2.5 mV / 0.8 V; the preset's kb_r is their middle over Table B.1's S_r, SE the half-width
    over sqrt(3). The quiet chamber keeps its drawn coefficient (within +-2e-4 deg/s/K)."""
    from imurig.campaigns.thermal import ThermalCampaign

    lo, hi = 0.01 * 2.0e-3 / 0.9, 0.01 * 2.5e-3 / 0.8            # V/K
    S, _ = _independent_table_b1_fit()
    imu = Delft2005Imu.estimated()
    np.testing.assert_allclose(imu.gyro_r_bias_tempco_rad_s_per_K, (lo + hi) / 2 / S[2], rtol=1e-12)
    np.testing.assert_allclose(imu.gyro_r_bias_tempco_se_rad_s_per_K, (hi - lo) / 2 / np.sqrt(3) / S[2], rtol=1e-12)
    _, lab, _ = ThermalCampaign(lab="delft-2005").build()
    _, quiet, _ = ThermalCampaign().build()
    assert lab.gyros.bias_tempco_rad_s_per_K[2] == imu.gyro_r_bias_tempco_rad_s_per_K
    np.testing.assert_array_equal(lab.gyros.bias_tempco_rad_s_per_K[:2], quiet.gyros.bias_tempco_rad_s_per_K[:2])
    np.testing.assert_array_equal(lab.gyros.scale_V_per_rad_s, imu.gyro_scale_V_per_rad_s)
    assert abs(quiet.gyros.bias_tempco_rad_s_per_K[2]) <= 2e-4 * DEG
