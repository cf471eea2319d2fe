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
