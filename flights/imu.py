"""The measured IMU stream of a flight: the truth at the IMU through the project's sensor chain.

    FlightTruth (f_B, w_IB_B, B_B at the magnetometer, box air temperature)
      -> case frame C:  f_C = C_CB f_B,  w_C = C_CB w_IB_B,  B_C = C_CB B_B
      -> ImuLab.measure (Q-Flex triad, VG941-3AM FOG triad, APS-536 fluxgate, temperature
         sensors with their thermal lags and hysteresis, DAQ-6036E: scan skew, crosstalk,
         common-mode noise, 16-bit quantisation, averaged logging)
      -> Recording: acc_x/y/z, gyro_p/q/r, mag_x/y/z, temp_acc_x/y/z, temp_box (volts) at the IMU rate

Mounting: the IMU case axes C coincide with the body axes (``C_BC = I``: x forward, y right,
z down; gyros p, q, r about x, y, z; the magnetometer's axes likewise). Calibrated
sensor-frame values map to the body as x_B = C_BC x_C. The magnetometer sits at
``truth.lever_mag_B`` (on the van, the tip of the 5 m boom); the field it sees is in
``truth.B_B``; the vehicle's own iron is lumped into the fluxgate's hard- and soft-iron terms.
``truth.T_imu_K`` is the air temperature in the IMU box: each sensor group follows it with
the lab's first-order thermal lags (:class:`imurig.sensors.chain.ThermalLags`); the sensor
temperatures are in ``truth_signals`` (T_acc, T_gyro, T_box).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
from imurig.sensors.chain import ImuLab
from imurig.sensors.disturbances import LooseCable, PeopleTransients, PumpVibration

from imurig.kernel.errors import ConfigError
from imurig.kernel.navdata import FlightTruth
from imurig.kernel.recording import Recording

FLIGHT_SCAN = ("acc_x", "acc_y", "acc_z", "gyro_p", "gyro_q", "gyro_r", "mag_x", "mag_y", "mag_z",
               "temp_acc_x", "temp_acc_y", "temp_acc_z", "temp_box")
C_BC = np.eye(3)   # IMU case axes -> body FRD axes (the rack holds the IMU box aligned with the body)


def flight_lab(lab: ImuLab, rate_hz: float) -> ImuLab:
    """The lab's sensors with the flight's acquisition: all 13 channels, logged at ``rate_hz`` as
    the mean of 1 kHz conversions (averaged logging), no basement pump or people, no loose cable."""
    if rate_hz > 1000:
        raise ConfigError(f"IMU rate {rate_hz:g} Hz is above the DAQ-6036E's 1000 Hz; use <= 1000 Hz")
    averaging = max(1, round(1000.0 / rate_hz))
    adc = replace(lab.adc, scan_list=FLIGHT_SCAN, sample_rate_hz=rate_hz, averaging=averaging)
    return replace(lab, adc=adc, pump=PumpVibration(enabled=False), people=PeopleTransients(enabled=False),
                   cable=LooseCable(enabled=False))


def rig_recording(truth: FlightTruth, C_BC_: np.ndarray = C_BC) -> Recording:
    """The flight as a rig recording: truth signals f_C_*, w_C_*, B_C_* and T_air (what
    :meth:`imurig.sensors.chain.ImuLab.measure` consumes), meta with rate and start time."""
    C_CB = np.asarray(C_BC_, float).T
    if np.array_equal(C_CB, np.eye(3)):   # the rack's mounting: x_C = x_B, each axis one contiguous line
        f_C, w_C, B_C = (np.ascontiguousarray(x.T) for x in (truth.f_B, truth.w_IB_B, truth.B_B))
    else:
        f_C, w_C, B_C = ((x @ C_CB.T).T for x in (truth.f_B, truth.w_IB_B, truth.B_B))
    ts, tu = {}, {}
    for j, a in enumerate("xyz"):
        ts[f"f_C_{a}"], tu[f"f_C_{a}"] = f_C[j], "m/s^2"
        ts[f"w_C_{a}"], tu[f"w_C_{a}"] = w_C[j], "rad/s"
        ts[f"B_C_{a}"], tu[f"B_C_{a}"] = B_C[j], "T"
    ts["T_air"], tu["T_air"] = truth.T_imu_K, "K"
    meta = {"rig": f"{truth.vehicle} flight", "sample_rate_hz": truth.rate_hz,
            "start_time": truth.meta["start_time"], "averaged_logging": True,
            "mounting_C_BC": np.asarray(C_BC_, float).tolist(), "vehicle": truth.vehicle,
            "phases": [list(p) for p in truth.phases]}
    flight = {"vehicle": truth.vehicle, "lever_gps_B_m": truth.lever_gps_B.tolist(),
              "lever_mag_B_m": truth.lever_mag_B.tolist(), "mounting_C_BC": np.asarray(C_BC_, float).tolist(),
              "phases": [list(p) for p in truth.phases],
              "meta": {k: v for k, v in truth.meta.items()
                       if isinstance(v, (str, int, float, list, dict)) and k != "controls"}}
    return Recording(time_s=truth.time_s, channels={}, units={}, meta=meta, truth={"flight": flight},
                     truth_signals=ts, truth_units=tu)


def measure_flight(truth: FlightTruth, lab: ImuLab, seed: np.random.SeedSequence,
                   C_BC_: np.ndarray = C_BC, acquisition: bool = True) -> Recording:
    """The raw IMU recording (volts) of a flight; ``truth`` of the result holds every injected
    sensor parameter (``truth["sensors"]``), the chain settings and the flight's lever arms.

    ``acquisition=True`` replaces the lab's ADC settings and disturbances by :func:`flight_lab`;
    pass False to use ``lab`` exactly as given (its scan list must then name the channels).
    """
    if not isinstance(seed, np.random.SeedSequence):
        raise ConfigError("seed must be a numpy.random.SeedSequence (same seed => identical data)")
    C = np.asarray(C_BC_, float)
    if C.shape != (3, 3) or not np.allclose(C @ C.T, np.eye(3), atol=1e-9) or np.linalg.det(C) < 0:
        raise ConfigError("C_BC must be a proper rotation matrix (3x3, orthonormal, det +1)")
    for name in ("f_B", "w_IB_B", "B_B", "T_imu_K"):
        if getattr(truth, name) is None:
            raise ConfigError(f"truth.{name} is missing: the sensor chain needs the field at the magnetometer "
                              "and the IMU temperature (a flight truth, not a closed-form trajectory)")
        if not np.all(np.isfinite(getattr(truth, name))):
            raise ConfigError(f"truth.{name} has non-finite values; rebuild the truth")
    rig = rig_recording(truth, C)
    if acquisition:
        lab = flight_lab(lab, truth.rate_hz)
    rec = lab.measure(rig, seed)
    rec.meta["imu_channels"] = list(lab.adc.scan_list)
    return rec
