"""What is injected in each kind of bench campaign, and the data its residuals need.

``TRUTH[kind](recording) -> (parameters, notes)``: the injected parameters ``{name, unit,
injected}`` of the campaign's recording (with its truth); ``RESIDUALS[kind](recording) ->
dict``: the measured outputs and true inputs per segment that
:func:`imurig.scoring.residuals.compute_residuals` compares with the forward model. The
forward models are those of :mod:`imurig.scoring.campaigns` (module doc).
"""
from __future__ import annotations

import numpy as np

from imurig.calibration.accelerometer import ACC
from imurig.calibration.accelerometer import AXES as ACC_AXES
from imurig.calibration.accelerometer import injected_parameters as acc_injected_parameters
from imurig.calibration.gyro import AXES as GYRO_AXES
from imurig.calibration.gyro import AXIS_OF_MOUNT, GYRO, round_windows
from imurig.calibration.gyro import injected_parameters as gyro_injected_parameters
from imurig.calibration.preprocess import segment_statistic
from imurig.calibration.thermal import ThermalCalibration, step_table
from imurig.campaigns.magnetometer import indicated_field, manoeuvre_mask, true_invariants
from imurig.campaigns.thermal import twin_channels
from imurig.kernel.recording import Recording
from imurig.scoring.specs import ACC_UNITS, GYRO_UNITS, triad_names


def _tilt_truth(rec: Recording):
    inj = acc_injected_parameters(rec.truth)
    params = [{"name": n, "unit": ACC_UNITS[n.split("_")[0]], "injected": float(inj[n])}
              for n in triad_names(ACC_AXES)]
    return params, ("forward model V_i = s_i (a_i + b_i + k2_i a_i^2), a = (I + M) f_C; misalignment M_ij "
                    "is the sensitivity of axis i to f_C along j")


def _turn_truth(rec: Recording):
    inj = gyro_injected_parameters(rec.truth, list(rec.segments["mount"]))
    params = [{"name": n, "unit": GYRO_UNITS[n.split("_")[0]], "injected": float(inj[n])}
              for n in triad_names(GYRO_AXES)]
    return params, ("forward model V_i = s_i (w_i + b_i + k2_i w_i^2), w = (I + M) w_table; the misalignment "
                    "column of the axis on the table includes the table's wobble (effective misalignment)")


def _thermal_truth(rec: Recording):
    twin = ThermalCalibration().fit(step_table(rec, channels=twin_channels(rec)))
    unit = {"acc_bias": "m/s^2", "acc_scale": "1", "gyro_bias": "rad/s"}
    params = []
    for key, r in twin.results_.items():
        kind = key.rsplit("_", 1)[0]
        for n, c in zip(r.names, r.coef_):
            k = 0 if n in ("1", "hysteresis") else (1 if n == "dT" else int(n.split("^")[1]))
            u = unit[kind] + ("" if k == 0 else f"/K^{k}" if k > 1 else "/K")
            params.append({"name": f"{key}:{n}", "unit": u, "injected": float(c)})
    return params, ("coefficients of b(T) = c0 + c1 dT + c2 dT^2 + c3 dT^3 + H s (accelerometer bias), "
                    "s(T) = c0 + c1 dT + H s (scale), b(T) = c0 + c1 dT + H s (gyro bias) against each sensor's "
                    "temperature reading, dT = T - 298.15 K, s = +1/2 heating, -1/2 cooling; injected = the same "
                    "six-position analysis on the noise-free twin")


def _mag_truth(rec: Recording):
    t = true_invariants(rec)
    A, b = t["A"], t["b"]
    AAt = A @ A.T
    params = [{"name": f"3d:AAt_{n}", "unit": "1", "injected": float(AAt[i, j])}
              for n, (i, j) in zip(("xx", "xy", "xz", "yy", "yz", "zz"), zip(*np.triu_indices(3)))]
    params += [{"name": f"3d:b_{a}", "unit": "T", "injected": float(b[k])} for k, a in enumerate("xyz")]
    circ = manoeuvre_mask(rec, "level_circle")
    Bz = float(np.mean(rec.truth_signals["B_C_z"][circ]))
    b2 = b[:2] + A[:2, 2] * Bz
    T2 = A[:2, :2] @ A[:2, :2].T
    params += [{"name": "2d:A2A2t_xx", "unit": "1", "injected": float(T2[0, 0])},
               {"name": "2d:A2A2t_xy", "unit": "1", "injected": float(T2[0, 1])},
               {"name": "2d:A2A2t_yy", "unit": "1", "injected": float(T2[1, 1])},
               {"name": "2d:b2_x", "unit": "T", "injected": float(b2[0])},
               {"name": "2d:b2_y", "unit": "T", "injected": float(b2[1])}]
    return params, ("indicated field m = V / s_nom = A B_C + b (+ noise); 3-D on the tumble: b and A A'; 2-D on "
                    "the level circle: m_xy = A2 B_xy + b2 with b2 = b_xy + A_xy,z B_z")


TRUTH = {"tilt-table": _tilt_truth, "turn-table": _turn_truth, "thermal": _thermal_truth,
         "magnetometer": _mag_truth}


# ------------------------------------------------------------------ residual data
def _tilt_residual_data(rec: Recording) -> dict:
    v = segment_statistic(rec, list(ACC), "median")
    f = segment_statistic(rec, ["f_C_x", "f_C_y", "f_C_z"], "median", source="truth_signals")
    return {"kind": "triad_forward", "axes": ["x", "y", "z"], "unit": "m/s^2", "true_input": f.tolist(),
            "measured_volts": v.tolist(), "what": "per-position 1 kHz median volts vs the forward model at the "
            "true specific force"}


def _turn_residual_data(rec: Recording) -> dict:
    rw, _ = round_windows(rec, "hp6700")
    v = segment_statistic(rw, list(GYRO), "mean")
    w = segment_statistic(rw, ["w_C_x", "w_C_y", "w_C_z"], "mean", source="truth_signals")
    q = np.zeros_like(w)
    for i, m in enumerate(rw.segments["mount"]):
        j, _ = AXIS_OF_MOUNT[str(m)]
        q[i, j] = w[i, j]   # the other components belong to the effective misalignment
    return {"kind": "triad_forward", "axes": ["p", "q", "r"], "unit": "rad/s", "true_input": q.tolist(),
            "measured_volts": v.tolist(), "what": "whole-round mean volts (HP counter windows) vs the forward "
            "model at the true table rate"}


def _mag_residual_data(rec: Recording) -> dict:
    tum = manoeuvre_mask(rec, "tumble")
    m = indicated_field(rec)[tum]
    step = max(1, m.shape[0] // 2000)
    return {"kind": "field_norm", "unit": "T", "indicated_T": m[::step].tolist(),
            "field_T": float(rec.meta["igrf_total_T"]),
            "what": f"calibrated field norm |A^-1 (m - b)| - F on the tumble (every {step}-th sample)"}


RESIDUALS = {"tilt-table": _tilt_residual_data, "turn-table": _turn_residual_data,
             "magnetometer": _mag_residual_data}
