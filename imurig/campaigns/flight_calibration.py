"""The flight's IMU calibrated on the virtual rigs, and those calibrations applied to its samples.

The IMU that flies is the lab drawn from the seed (stream ``sensor_errors``,
:mod:`imurig.kernel.random_streams`): the same unit the tilt-table, turn-table and thermal
campaigns of that seed draw. So :func:`calibrations` and :func:`thermal_calibration` calibrate
the very sensors that fly, and :func:`mag_calibration` tumbles the flight's own fluxgate on the
magnetometer rig. :func:`imu_stream` turns the flight's volts into the filter's SI samples, with
the datasheet-nominal conversions or with these calibrations.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from imurig.calibration.gyro import GyroCalibration
from imurig.calibration.magnetometer import MagnetometerCalibration
from imurig.calibration.thermal import ThermalCalibration, step_table
from imurig.campaigns.thermal import ThermalCampaign
from imurig.campaigns.tilt_table import TiltTableCampaign
from imurig.campaigns.tilt_table import calibrate as cal_acc
from imurig.campaigns.turn_table import TurnTableCampaign
from imurig.flights import ins
from imurig.kernel import random_streams
from imurig.kernel.navdata import ImuStream
from imurig.kernel.units import T_REF_K
from imurig.rigs.mag_rig import MagRig, Tumble
from imurig.rigs.tilt_table import TiltTableProtocol
from imurig.rigs.turn_table import TurnTableProtocol
from imurig.sensors.adc import DAQ6036E
from imurig.sensors.chain import ImuLab
from imurig.sensors.disturbances import PeopleTransients, PumpVibration
from imurig.sensors.thermal import hysteresis_state


def calibrations(seed: int, quick: bool = True) -> dict:
    """Tilt-table (accelerometers) and turn-table (gyros) calibrations of the same IMU, with
    reduced protocols when ``quick`` (4 tilts x 4 azimuths x 3 s; 3 rates x 2 directions x 3 axes)."""
    if quick:
        tp = TiltTableProtocol(theta_deg=(0, 30, 60, 90), phi_deg=(0, 90, 180, 270), dwell_s=3, settle_s=1,
                               remount_s=10, sample_rate_hz=200)
        rp = TurnTableProtocol(dial_rates_dps=(4, 20, 100), min_window_s=3, settle_s=1, ramp_s=1, remount_s=10,
                               sample_rate_hz=200)
    else:
        tp, rp = TiltTableProtocol(), TurnTableProtocol()
    acc = cal_acc(TiltTableCampaign(protocol=tp, seed=seed, pump=False, people=False).simulate())
    gyro = GyroCalibration().fit(TurnTableCampaign(protocol=rp, seed=seed).simulate())
    return {"accelerometers": acc, "gyros": gyro}


def mag_calibration(lab: ImuLab, seed: int, tumble_s: float = 120.0) -> dict:
    """Calibration of the flight's magnetometer (the very fluxgate and installation iron of ``lab``)
    on the virtual magnetometer rig: a tumble on the MuJoCo gimbal (:class:`imurig.rigs.mag_rig.Tumble`,
    ``tumble_s`` s), measured through the lab's chain, then the two-step ellipsoid fit
    (:class:`imurig.calibration.magnetometer.MagnetometerCalibration`, [Elk01], paper 3.2 / Fig. 5):

        m_k = A B_C,k + b + e_k,   |B_C,k| = F (IGRF total intensity at the rig)      [T]
        calibrated field  B̂ = T (m − b),  T = A⁻¹ up to a rotation

    This removes the hard iron b (all three axes, so the heading stays right when the aircraft
    banks) and the soft iron / scale factors. A is only known up to a rotation (a heading offset
    no field-domain fit can see); the rig fixes it: its gimbal angles and the IGRF field give the
    field direction in the sensor frame, and Wahba's problem (SVD) gives the rotation R_fix with
    B_ref ≈ R_fixᵀ B̂. Mounting C_BC = I (see :mod:`imurig.flights.imu`), so the calibrated field
    is the body field. The seed instead fitted an ellipse on the ground turning circle; a 2-D fit
    leaves the vertical hard iron, which leaks ~5 deg into the heading at 60 deg of bank."""
    rig = MagRig().simulate([Tumble(duration_s=tumble_s)], "2005-06-21T10:00:00+02:00",
                            random_streams.generator("flight/mag-rig/rig", seed))
    mlab = replace(lab, pump=PumpVibration(enabled=False), people=PeopleTransients(enabled=False),
                   adc=DAQ6036E(scan_list=("mag_x", "mag_y", "mag_z", "temp_box"), sample_rate_hz=100.0,
                                averaging=10))
    rec = mlab.measure(rig, random_streams.seed_sequence("flight/mag-rig/sensor-chain", seed))
    m = rec.stack(("mag_x", "mag_y", "mag_z")) / 4.0e4
    e3 = MagnetometerCalibration("ellipsoid").fit(m, float(rec.meta["igrf_total_T"]))
    # the rotation left free by the fit: Wahba's problem between the calibrated field and the field
    # the lab predicts in the sensor frame from what it knows: the IGRF field at the site (W = ENU)
    # and the gimbal's angle encoders, B_ref = R_WCᵀ B_W, R_WC = Rz(yaw) Ry(pitch) Rx(roll)
    B_ref = gimbal_field_C(rec)
    U, _s, Vt = np.linalg.svd(e3.apply(m).T @ B_ref)
    R_fix = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt        # B_ref ≈ R_fix.T @ B̂
    out = {"ellipsoid": e3, "R_fix": R_fix, "tumble_s": tumble_s, "heading_offset_rad": 0.0,
           "rotation_fix_deg": float(np.degrees(np.arccos(np.clip((np.trace(R_fix) - 1) / 2, -1, 1)))),
           "reference": "rig gimbal encoder angles + IGRF field at the site (Wahba)", "n_samples": int(m.shape[0]),
           "H_T": float(rec.meta["igrf_horizontal_T"])}
    return out


def gimbal_field_C(rec) -> np.ndarray:
    """Field (n, 3) T the magnetometer rig's gimbal puts along the sensor axes, from the lab's own
    knowledge only: the IGRF field at the site ``meta["igrf_field_W_T"]`` (W = ENU) and the gimbal's
    angle encoders (joint angles yaw, pitch, roll, rad; :mod:`imurig.rigs.mag_rig`):

        B_C = R_WCᵀ B_W,   R_WC = Rz(yaw) Ry(pitch) Rx(roll)
    """
    B_W = np.asarray(rec.meta["igrf_field_W_T"], float)
    y, p, r = (np.asarray(rec.truth_signals[k], float) for k in ("yaw", "pitch", "roll"))
    cy, sy, cp, sp, cr, sr = np.cos(y), np.sin(y), np.cos(p), np.sin(p), np.cos(r), np.sin(r)
    R = np.empty((y.size, 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 0, 2] = cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr
    R[:, 1, 0], R[:, 1, 1], R[:, 1, 2] = sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr
    R[:, 2, 0], R[:, 2, 1], R[:, 2, 2] = -sp, cp * sr, cp * cr
    return np.einsum("nji,j->ni", R, B_W)


def thermal_calibration(seed: int) -> dict:
    """Thermal-chamber calibration of the same IMU (:class:`imurig.campaigns.thermal.ThermalCampaign`,
    default profile −50…+50 C, two cycles, six attitudes per step; ~5 s): the six-position bias
    B(T, h) and scale S(T, h) of each accelerometer against its temperature channel T (K) and the
    hysteresis state h (paper section 3.1; :mod:`imurig.calibration.thermal`)."""
    rec = ThermalCampaign(seed=seed).simulate()
    return {"fit": ThermalCalibration().fit(step_table(rec)), "width_K": float(rec.truth["sensors"]["accelerometers"]
                                                                  .get("hysteresis_width_K", 4.0)),
            "T_ref_K": T_REF_K}


def thermal_terms(th: dict, T_K: np.ndarray, fs: float):
    """Per accelerometer axis, the thermal change of the six-position bias and scale relative to the
    tilt table's conditions (T_ref = 298.15 K, hysteresis state 0):

        ΔB = B(T, h) − (S(T, h)/S(T_ref, 0)) B(T_ref, 0),   ρ = S(T, h)/S(T_ref, 0)      [(n, 3)]

    h from the measured temperature by the play operator of the sensor's hysteresis width
    (:func:`imurig.sensors.thermal.hysteresis_state`; at switch-on the mid-branch state h = 0, the
    tilt table's). Returns (ΔB, ρ, σ_ΔB): σ_ΔB (n, 3) the fit's standard error of ΔB (delta method
    on the coefficient covariance; :meth:`imurig.calibration.thermal.ThermalCalibration.compensation`)."""
    T_K = np.asarray(T_K, float)
    h = np.stack([hysteresis_state(T_K[:, j], th["width_K"], fs) for j in range(3)], 1)
    return th["fit"].compensation(T_K, h, th["T_ref_K"])


def imu_stream(truth, volts: dict, lab: ImuLab, cals: dict | None) -> ImuStream:
    """SI samples for the filter: datasheet-nominal conversions (``cals`` None) or the campaign
    calibrations (inverse models on the indicated values V / nominal sensitivity)."""
    Va = np.stack([volts[f"acc_{a}"] for a in "xyz"], 1)
    Vg = np.stack([volts[f"gyro_{a}"] for a in "pqr"], 1)
    Vm = np.stack([volts[f"mag_{a}"] for a in "xyz"], 1)
    sa = lab.accelerometers.nominal_sensitivity_V_per_m_s2()
    sg = lab.gyros.nominal_sensitivity()
    f = Va / sa
    w = Vg / sg
    sensor = lab.temp_sensors["temp_acc_x"]
    Tk = np.stack([sensor.temperature_K(volts[f"temp_acc_{a}"]) for a in "xyz"], 1)
    th = None if cals is None else cals.get("thermal")
    if th is not None:
        # back to the tilt table's conditions: u(T_ref, 0) = (u − ΔB(T, h)) / ρ(T, h)
        dB, rho, sdB = thermal_terms(th, Tk, truth.rate_hz)
        f = (f - dB) / rho
        cals["thermal_sigma_m_s2"] = float(sdB.max())
    if cals is not None:
        f = cals["accelerometers"].predict(f)
        w = cals["gyros"].predict(w)
    B = Vm / 4.0e4
    mc = None if cals is None else cals.get("magnetometer")
    if mc is not None:
        B = mc["ellipsoid"].apply(B) @ mc["R_fix"]
        c, s_ = math.cos(mc["heading_offset_rad"]), math.sin(mc["heading_offset_rad"])
        # rotate about body z by the reference-heading offset (FRD: psi = atan2(-h_y, h_x))
        B = np.column_stack([c * B[:, 0] - s_ * B[:, 1], s_ * B[:, 0] + c * B[:, 1], B[:, 2]])
    return ImuStream(time_s=truth.time_s, f_B=f, w_IB_B=w, B_B=B, T_acc_K=Tk, samples=ins.sample_semantics(truth))
