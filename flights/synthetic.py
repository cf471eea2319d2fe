"""Synthetic sensors drawn from exactly the GPS/INS filter's error model (consistency studies of
:mod:`imurig.flights.ekf`)."""
from __future__ import annotations

import math

import numpy as np
from imurig.flights import earth as E
from imurig.flights import ins
from imurig.flights.filter_config import ImuNoise
from scipy.signal import lfilter

from imurig.kernel.navdata import FlightTruth, GpsFixes, ImuStream
from imurig.kernel.units import T_REF_K


def synthetic_sensors(truth: FlightTruth, noise: ImuNoise, rng: np.random.Generator, *, acc_bias_m_s2=None,
                      gyro_bias_rad_s=None, gps_rate_hz=1.0, gps_sigma_pos_m=(0.5, 0.5, 1.0),
                      gps_sigma_vel_m_s=(0.05, 0.05, 0.1), lever_gps_B=(0.0, 0.0, 0.0), mag_sigma_rad=0.0,
                      T_acc_K=T_REF_K, temp_sigma_K=0.05, outages=()):
    """IMU, GPS, magnetometer and temperature data drawn from exactly the filter's error model.

    w = w_IB_B + b_g + GM(σ, τ) + ARW;  f = f_B + b_a + VRW  (white, per sample σ = density √fs);
    GPS antenna position/velocity + white noise at ``gps_rate_hz`` (invalid inside ``outages``
    ((t0, t1), ...)); B_B = C_BN [cos D, sin D, tan I]·|B_h| with a heading noise of σ_mag;
    temperature channels = T_acc_K + white noise. Returns (ImuStream, GpsFixes, true biases).
    """
    t = truth.time_s
    n = t.size
    fs = truth.rate_hz
    ba = rng.normal(0, 0.05, 3) if acc_bias_m_s2 is None else np.asarray(acc_bias_m_s2, float)
    bg = rng.normal(0, 0.003 * math.pi / 180, 3) if gyro_bias_rad_s is None else np.asarray(gyro_bias_rad_s, float)
    phi = math.exp(-1.0 / (noise.gyro_bias_tau_s * fs))
    drive = rng.standard_normal((n, 3)) * noise.gyro_bias_sigma * math.sqrt(1 - phi ** 2)
    drive[0] = rng.standard_normal(3) * noise.gyro_bias_sigma
    gm = lfilter([1.0], [1.0, -phi], drive, axis=0)
    w = truth.w_IB_B + bg + gm + rng.standard_normal((n, 3)) * noise.arw * math.sqrt(fs)
    f = truth.f_B + ba + rng.standard_normal((n, 3)) * noise.vrw * math.sqrt(fs)
    C_NB = E.C_from_q(truth.q_NB)
    # magnetometer: a unit horizontal field pointing north (declination 0), dip 67 deg
    head_noise = rng.standard_normal(n) * mag_sigma_rad
    B_N = np.stack([np.cos(head_noise), -np.sin(head_noise), np.full(n, math.tan(67 * math.pi / 180))], 1) * 19e-6
    B_B = np.einsum("nji,nj->ni", C_NB, B_N)
    Tm = np.full((n, 3), T_acc_K) + rng.standard_normal((n, 3)) * temp_sigma_K
    step = max(1, round(fs / gps_rate_hz))
    gi = np.arange(0, n, step)
    l = np.asarray(lever_gps_B, float)
    Cl = np.einsum("nij,j->ni", C_NB[gi], l)
    lat, lon, h = E.geodetic_from_ned(Cl, truth.lat_rad[gi], truth.lon_rad[gi], truth.h_m[gi])
    w_ie, w_en = E.omega_IE_N(truth.lat_rad[gi]), E.omega_EN_N(truth.lat_rad[gi], truth.h_m[gi], truth.v_N[gi])
    w_nb = truth.w_IB_B[gi] - np.einsum("nji,nj->ni", C_NB[gi], w_ie + w_en)
    v_ant = truth.v_N[gi] + np.einsum("nij,nj->ni", C_NB[gi], np.cross(w_nb, l))
    sp = np.tile(np.asarray(gps_sigma_pos_m, float), (gi.size, 1))
    sv = np.tile(np.asarray(gps_sigma_vel_m_s, float), (gi.size, 1))
    dpos = rng.standard_normal((gi.size, 3)) * sp
    lat, lon, h = E.geodetic_from_ned(dpos, lat, lon, h)
    v = v_ant + rng.standard_normal((gi.size, 3)) * sv
    valid = np.ones(gi.size, bool)
    for t0, t1 in outages:
        valid &= ~((t[gi] >= t0) & (t[gi] < t1))
    gps = GpsFixes(time_s=t[gi].copy(), lat_rad=lat, lon_rad=lon, h_m=h, v_N=v, sigma_pos_N=sp, sigma_vel_N=sv,
                   valid=valid, mode="synthetic")
    imu = ImuStream(time_s=t, f_B=f, w_IB_B=w, B_B=B_B, T_acc_K=Tm, samples=ins.sample_semantics(truth))
    return imu, gps, {"acc_bias_m_s2": ba, "gyro_bias_rad_s": bg}
