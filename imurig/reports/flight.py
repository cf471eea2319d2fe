"""`imurig flight`: the flight flown twice through the loosely coupled filter — with the IMU's
datasheet-nominal conversions only, then corrected by the calibrations estimated on the
virtual rigs — and the report (paper Figs. 6-8 side by side, errors, consistency, .rrd).

The IMU is the lab drawn from ``seed`` exactly as the campaigns draw it
(``ImuLab.draw(child_rng(SeedSequence(seed), "sensor_errors"))``), so the tilt-table and
turn-table campaigns run with the same seed calibrate the very sensors that fly.
"""
from __future__ import annotations

import math
import time
import tracemalloc
from dataclasses import dataclass

import numpy as np
from imurig.flights import earth as E
from imurig.flights import ekf, ins
from imurig.sensors.chain import ImuLab
from imurig.sensors.noise import child_rng

from imurig.kernel.errors import ConfigError
from imurig.kernel.navdata import GpsFixes, ImuStream
from imurig.kernel.progress import progress
from imurig.kernel.units import T_REF_K

DEG = math.pi / 180


@dataclass
class FlightOptions:
    flight: str = "default"            # "default" (6A's plan) or "static" (paper 4.2 static tests)
    seed: int = 2005
    duration_s: float | None = None
    nav_rate_hz: float = 25.0
    imu_rate_hz: float = 100.0
    gps_rate_hz: float = 1.0
    quick_calibration: bool = True
    gps_latency_s: float = 0.0
    gps_time_sigma_s: float = 0.0
    # uncalibrated compass: the fluxgate's installation errors as 12 random-constant states
    # (ekf.FilterConfig.mag_iron_states, compass updating heading, gyro biases and iron only);
    # False: one Gauss-Markov heading-error state instead (consistent but far too cautious, NIS 0.05)
    mag_iron_states: bool = True

    def validate(self):
        if self.flight not in ("default", "static"):
            raise ConfigError(f"unknown flight {self.flight!r}; choose 'default' or 'static'")
        if self.gps_rate_hz > self.imu_rate_hz:
            raise ConfigError(f"GPS rate {self.gps_rate_hz:g} Hz above the IMU rate {self.imu_rate_hz:g} Hz")
        if not (0 < self.nav_rate_hz <= self.imu_rate_hz):
            raise ConfigError("nav rate must be positive and at most the IMU rate")
        if self.duration_s is not None and self.duration_s <= 10:
            raise ConfigError("duration must be longer than 10 s")
        return self


def flight_truth(opt: FlightOptions):
    from imurig.flights import truth as T

    if opt.flight == "static":
        tr = T.static_tests_truth(rate_hz=opt.imu_rate_hz)
    else:
        from imurig.flights.plan import simulate_flight

        tr = simulate_flight(progress_bar=True)
    if opt.duration_s is not None:
        tr = tr.slice(tr.time_s[0], tr.time_s[0] + opt.duration_s)
    return tr


def flight_lab(seed: int) -> ImuLab:
    return ImuLab.draw(child_rng(np.random.SeedSequence(seed), "sensor_errors"))


def measure_volts(truth, lab: ImuLab, seed: int) -> dict:
    """Raw volts of the flight: 6A's ``flights.imu.measure_flight`` when it exists; otherwise the
    sensor models' own measurement equations (accelerometer, FOG, fluxgate, temperature sensors)
    with their noise, at the truth's rate."""
    try:
        from imurig.flights.imu import measure_flight
    except ImportError:
        measure_flight = None
    if measure_flight is not None:
        rec = measure_flight(truth, lab, np.random.SeedSequence(seed, spawn_key=(6,)))
        return {k: np.asarray(rec.channels[k]) for k in rec.channels}
    ss = np.random.SeedSequence(seed, spawn_key=(6,))
    fs = truth.rate_hz
    T = np.asarray(truth.T_imu_K, float)
    acc = lab.accelerometers
    out = {}
    v = acc.ideal_voltage(truth.f_B, T) + acc.noise_current(truth.n, fs, child_rng(ss, "acc")) * acc.load_resistor_ohm
    g = lab.gyros
    w = g.ideal_voltage(truth.w_IB_B, T) + g.noise_rate(truth.n, fs, child_rng(ss, "gyro")) * g.scale_V_per_rad_s
    m = lab.magnetometer.output_voltage(truth.B_B, child_rng(ss, "mag"))
    for j, a in enumerate("xyz"):
        out[f"acc_{a}"] = v[:, j]
        out[f"mag_{a}"] = m[:, j]
        out[f"temp_acc_{a}"] = lab.temp_sensors[f"temp_acc_{a}"].voltage(T, child_rng(ss, f"temp{a}"))
    for j, a in enumerate("pqr"):
        out[f"gyro_{a}"] = w[:, j]
    return out


def gps_fixes(truth, opt: FlightOptions, seed: int):
    """6A's receiver model when it exists; otherwise white-noise fixes at the antenna (DGPS-like σ)."""
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(7,)))
    try:
        from imurig.flights.gps import GpsReceiver
    except ImportError:
        GpsReceiver = None
    if GpsReceiver is not None:
        rx = GpsReceiver(rate_hz=opt.gps_rate_hz)
        fx = rx.measure(truth, rng)
        # The receiver's tag is the IMU sample at which the logger sees the fix: time of validity
        # + latency + jitter, rounded UP to the IMU clock. Time of validity used by the filter:
        # tag − latency − Δt_IMU/2 (the mid-point of the rounding interval); what remains lies in
        # ±Δt_IMU/2 plus the jitter. The phase of the GPS epochs against the IMU clock is unknown
        # and constant (both clocks are stable), so the rounding error is NOT uniform: with the
        # epochs on the IMU grid it is ±Δt_IMU/2 with equal odds (the jitter decides). Its largest
        # possible variance, (Δt_IMU/2)², is the one used: σ_t² = (Δt_IMU/2)² + σ_jitter²,
        # added to R as σ_t² v vᵀ (position) and σ_t² a aᵀ (velocity).
        dti = 1.0 / truth.rate_hz if rx.quantise_to_imu else 0.0
        opt.gps_latency_s = float(rx.latency_s + dti / 2)   # time_offset_s is an unknown error: not removed
        opt.gps_time_sigma_s = math.sqrt((dti / 2) ** 2 + rx.time_jitter_s ** 2)
        return GpsFixes(time_s=fx.time_s - opt.gps_latency_s, lat_rad=fx.lat_rad, lon_rad=fx.lon_rad, h_m=fx.h_m,
                        v_N=fx.v_N, sigma_pos_N=fx.sigma_pos_N, sigma_vel_N=fx.sigma_vel_N, mode=fx.mode,
                        valid=np.asarray(fx.valid, bool), meta=fx.meta)
    step = max(1, round(truth.rate_hz / opt.gps_rate_hz))
    gi = np.arange(0, truth.n, step)
    C = E.C_from_q(truth.q_NB[gi])
    Cl = C @ np.asarray(truth.lever_gps_B, float)
    sp = np.tile([0.5, 0.5, 1.0], (gi.size, 1))
    sv = np.tile([0.05, 0.05, 0.1], (gi.size, 1))
    lat, lon, h = E.geodetic_from_ned(Cl + rng.standard_normal((gi.size, 3)) * sp,
                                      truth.lat_rad[gi], truth.lon_rad[gi], truth.h_m[gi])
    v = truth.v_N[gi] + rng.standard_normal((gi.size, 3)) * sv
    return GpsFixes(time_s=truth.time_s[gi].copy(), lat_rad=lat, lon_rad=lon, h_m=h, v_N=v, sigma_pos_N=sp,
                    sigma_vel_N=sv, mode="white-noise fallback")


def calibrations(seed: int, quick: bool = True) -> dict:
    """Tilt-table (accelerometers) and turn-table (gyros) calibrations of the same IMU, with
    reduced protocols when ``quick`` (4 tilts x 4 azimuths x 3 s; 3 rates x 2 directions x 3 axes)."""
    from imurig.rigs.tilt_table import TiltTableProtocol
    from imurig.rigs.turn_table import TurnTableProtocol

    from imurig.campaigns.tilt_table import TiltTableCampaign
    from imurig.campaigns.tilt_table import calibrate as cal_acc
    from imurig.calibration.gyro import GyroCalibration
    from imurig.campaigns.turn_table import TurnTableCampaign

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
    from dataclasses import replace

    from imurig.calibration.magnetometer import MagnetometerCalibration
    from imurig.rigs.mag_rig import MagRig, Tumble
    from imurig.sensors.adc import DAQ6036E
    from imurig.sensors.disturbances import PeopleTransients, PumpVibration

    ss = np.random.SeedSequence(seed, spawn_key=(8,))
    rig = MagRig().simulate([Tumble(duration_s=tumble_s)], "2005-06-21T10:00:00+02:00", child_rng(ss, "rig"))
    mlab = replace(lab, pump=PumpVibration(enabled=False), people=PeopleTransients(enabled=False),
                   adc=DAQ6036E(scan_list=("mag_x", "mag_y", "mag_z", "temp_box"), sample_rate_hz=100.0,
                                averaging=10))
    rec = mlab.measure(rig, np.random.SeedSequence(seed, spawn_key=(9,)))
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


def flight_declination(truth) -> float:
    """IGRF declination (rad, east positive) at the start of the flight."""
    from imurig.kernel.site import decimal_year, parse_time

    yr = decimal_year(parse_time(truth.meta.get("start_time", "2005-06-26T08:00:00+02:00")))
    return ekf.declination_rad(float(truth.lat_rad[0]), float(truth.lon_rad[0]), float(truth.h_m[0]), yr)


def declination_model(truth) -> ekf.IgrfDeclination:
    """IGRF declination along the route (callable D(lat, lon, h), rad) at the flight's date."""
    from imurig.kernel.site import decimal_year, parse_time

    return ekf.IgrfDeclination(decimal_year(parse_time(truth.meta.get("start_time", "2005-06-26T08:00:00+02:00"))))


def gps_error_model(gps) -> dict:
    """The receiver's Gauss-Markov position error (σ_GM per NED axis, τ) from the fixes' meta, for the
    filter's correlated-error treatment; empty for white-noise fixes."""
    rx = (getattr(gps, "meta", None) or {}).get("receiver")
    if not rx:
        return {}
    return {"gps_pos_tau_s": float(rx["tau_gm_s"]), "gps_pos_sigma_white_N_m": tuple(rx["sigma_white_N_m"])}


def thermal_calibration(seed: int) -> dict:
    """Thermal-chamber calibration of the same IMU (:class:`imurig.campaigns.thermal.ThermalCampaign`,
    default profile −50…+50 C, two cycles, six attitudes per step; ~5 s): the six-position bias
    B(T, h) and scale S(T, h) of each accelerometer against its temperature channel T (K) and the
    hysteresis state h (paper section 3.1; :mod:`imurig.calibration.thermal`)."""
    from imurig.calibration.thermal import ThermalCalibration, step_table

    from imurig.campaigns.thermal import ThermalCampaign

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
    from imurig.sensors.thermal import hysteresis_state

    T_K = np.asarray(T_K, float)
    h = np.stack([hysteresis_state(T_K[:, j], th["width_K"], fs) for j in range(3)], 1)
    return th["fit"].compensation(T_K, h, th["T_ref_K"])


def datasheet_values(cls, name: str) -> float:
    """A datasheet limit as the sensor class's ``from_datasheet`` states it (keyword default)."""
    import inspect

    return inspect.signature(cls.from_datasheet).parameters[name].default


def mag_heading_error_model_datasheet(incl_rad: float, H_T: float, n_heading: int = 72) -> tuple[float, float]:
    """(σ_m, θ_c): 1σ heading error (rad) of the uncalibrated fluxgate from its datasheet limits
    (:meth:`imurig.sensors.magnetometer.FluxgateTriad.from_datasheet`: hard iron, soft iron
    (symmetric), misalignment, sensitivity spread, each uniform within its limit: σ = limit/√3), in
    level flight at inclination I, averaged over heading; and its correlation angle θ_c (rad): the
    heading change over which the heading-averaged autocorrelation falls to 1/e.

    Field error δB = ΔA B + b with B = H[cos ψ, −sin ψ, tan I] (body, level, heading ψ),
    ΔA = soft iron − I + misalignment + sensitivity error; heading error e(ψ) = u(ψ)ᵀ δB / H,
    u = [sin ψ, cos ψ, 0] across the field. e is linear in the parameters θ, e(ψ) = g(ψ)ᵀ θ, so
    Cov(e(ψ₁), e(ψ₂)) = g(ψ₁)ᵀ Σ_θ g(ψ₂) exactly."""
    from imurig.sensors.magnetometer import FluxgateTriad as F

    hi = datasheet_values(F, "hard_iron_max_nT") * 1e-9
    soft = datasheet_values(F, "soft_iron_max")
    mis = datasheet_values(F, "misalignment_max_mrad") * 1e-3
    H = float(H_T)
    psi = np.linspace(0, 2 * np.pi, n_heading, endpoint=False)
    B = H * np.stack([np.cos(psi), -np.sin(psi), np.full_like(psi, math.tan(incl_rad))], 1)
    u = np.stack([np.sin(psi), np.cos(psi), np.zeros_like(psi)], 1)
    cols, var = [], []
    for i in range(3):                       # hard iron
        cols.append(u[:, i])
        var.append(hi ** 2 / 3)
    for i in range(3):                       # diagonal: soft iron U(±s), sensitivity ±2 %
        cols.append(u[:, i] * B[:, i])
        var.append(soft ** 2 / 3 + 0.02 ** 2 / 3)
    for i, j in ((0, 1), (0, 2), (1, 2)):    # symmetric soft iron off-diagonal: mean of two U(±s)
        cols.append(u[:, i] * B[:, j] + u[:, j] * B[:, i])
        var.append(soft ** 2 / 6)
    for i in range(3):                       # misalignment, off-diagonal
        for j in range(3):
            if i != j:
                cols.append(u[:, i] * B[:, j])
                var.append(mis ** 2 / 3)
    Gm = np.stack(cols, 1) / H                # (n_heading, n_par)
    cov = (Gm * np.asarray(var)) @ Gm.T       # (n_heading, n_heading)
    sig2 = float(np.mean(np.diag(cov)))
    lags = np.array([np.mean(np.diag(np.roll(cov, -k, axis=1))) for k in range(n_heading // 2)]) / sig2
    k = int(np.argmax(lags < math.exp(-1)))
    theta_c = float(psi[k - 1] + (psi[k] - psi[k - 1]) * (lags[k - 1] - math.exp(-1)) / (lags[k - 1] - lags[k]))
    return math.sqrt(sig2), theta_c


def mag_iron_prior_datasheet() -> np.ndarray:
    """Prior covariance (12, 12) of the uncalibrated fluxgate's installation errors [b (T), ΔA]
    (:func:`ekf.mag_iron_prior_cov`) from the limits :meth:`FluxgateTriad.from_datasheet` draws
    within: hard iron ±2000 nT, soft iron ±0.05 (symmetrised), misalignment ±5 mrad, sensitivity ±2 %."""
    from imurig.sensors.magnetometer import FluxgateTriad as F

    return ekf.mag_iron_prior_cov(datasheet_values(F, "hard_iron_max_nT") * 1e-9, datasheet_values(F, "soft_iron_max"),
                                  datasheet_values(F, "misalignment_max_mrad") * 1e-3, MAG_SENSITIVITY_SPREAD)


MAG_SENSITIVITY_SPREAD = 0.02   # FluxgateTriad.from_datasheet: sensitivity × (1 + U(±0.02))


def datasheet_priors(truth, mag_iron_states: bool = True) -> dict:
    """Filter priors of the uncalibrated run, from the datasheet limits of the sensor models (each
    error uniform within ±limit: σ = limit/√3): accelerometer bias (8000 µg) with the 2nd-order
    nonlinearity at 1 g (48 µg/g²); scale factors (Q-Flex 1 %, FOG 2 %) and misalignments (2 mrad) as
    states; gyro turn-on bias N(0, 0.003 deg/s) as a random constant and the bias instability as its
    own Gauss-Markov states (``gyro_bias_gm_states``); the compass's
    systematic heading error (hard/soft iron) as a state with σ_m and correlation angle θ_c from the
    fluxgate's datasheet (:func:`mag_heading_error_model_datasheet`), white part = fluxgate noise / H;
    or, with ``mag_iron_states`` (the default), the fluxgate's hard iron and soft-iron/misalignment/
    sensitivity matrix as 12 random constants with the datasheet prior (:func:`mag_iron_prior_datasheet`),
    the compass updating only the heading, the gyro biases and the iron states (``mag_consider_states``)."""
    from imurig.sensors.accelerometer import QFlexTriad as Q
    from imurig.sensors.gyro import FOGTriad as G
    from imurig.sensors.magnetometer import FluxgateTriad as F

    from imurig.kernel.units import G_STANDARD

    g = G_STANDARD
    s_b = datasheet_values(Q, "bias_max_ug") * 1e-6 * g
    import pyIGRF

    _d, incl, H_nT, *_ = pyIGRF.igrf_value(math.degrees(truth.lat_rad[0]), math.degrees(truth.lon_rad[0]),
                                           truth.h_m[0] / 1000.0, declination_model(truth).year)
    s_m, th_c = mag_heading_error_model_datasheet(math.radians(incl), H_nT * 1e-9)
    return {"estimate_scale_factors": True, "estimate_misalignments": True, "estimate_nonlinearity": True,
            "sigma0_acc_nonlinearity_s2_m": datasheet_values(Q, "nonlinearity_max_ug_per_g2") * 1e-6 / g / math.sqrt(3),
            # temperature terms: tempcos uniform within ±limit (σ = limit/√3); hysteresis magnitudes
            # U(0.2, 1) x limit with either sign taken as unknown: σ = rms = limit √((0.04+0.2+1)/3)
            "estimate_thermal_terms": True,
            "sigma0_acc_thermal": (datasheet_values(Q, "bias_tempco_max_ug_per_C") * 1e-6 * g / math.sqrt(3),
                                   datasheet_values(Q, "scale_tempco_max_ppm_per_C") * 1e-6 / math.sqrt(3),
                                   datasheet_values(Q, "bias_hysteresis_max_ug") * 1e-6 * g * math.sqrt(1.24 / 3),
                                   datasheet_values(Q, "scale_hysteresis_max_ppm") * 1e-6 * math.sqrt(1.24 / 3)),
            "hysteresis_width_K": float(Q.__dataclass_fields__["hysteresis_width_K"].default),
            "sigma0_acc_bias_m_s2": s_b / math.sqrt(3),
            "sigma0_acc_scale": datasheet_values(Q, "scale_factor_spread") / math.sqrt(3),
            "sigma0_gyro_scale": datasheet_values(G, "scale_spread") / math.sqrt(3),
            "sigma0_acc_misalignment_rad": datasheet_values(Q, "misalignment_max_mrad") * 1e-3 / math.sqrt(3),
            "sigma0_gyro_misalignment_rad": datasheet_values(G, "misalignment_max_mrad") * 1e-3 / math.sqrt(3),
            # turn-on bias N(0, repeatability): a random constant; the bias variation (instability) is
            # the Gauss-Markov part, carried as its own states (σ, τ of the sensor model)
            "sigma0_gyro_bias_rad_s": datasheet_values(G, "bias_repeatability_dps") * DEG,
            "gyro_bias_gm_states": True,
            **({"mag_iron_states": True, "mag_iron_prior_cov": mag_iron_prior_datasheet(), "mag_consider_states": True}
               if mag_iron_states else
               {"mag_error_state": True, "mag_error_sigma_rad": s_m, "mag_error_corr_rad": th_c}),
            "mag_heading_sigma_rad": datasheet_values(F, "noise_nT_rms") * 1e-9 / (H_nT * 1e-9)}


def calibrated_priors(cals: dict | None, noise: ekf.ImuNoise) -> dict:
    """Filter priors of the calibrated run from the calibrations' reported standard errors:
    σ0 of the accelerometer bias = the largest bias SE of the tilt-table fit, with the thermal
    correction's largest SE over the flight (``cals["thermal_sigma_m_s2"]``) in quadrature; σ0 of the
    gyro turn-on bias (a random constant) = √(SE² + σ_GM²) (turn-table SE plus the instability's
    mean over the calibration session, at most σ_GM), the flight's instability as Gauss-Markov
    states; magnetic heading
    σ = the ellipsoid fit's RMS field residual / H (rad). Empty (datasheet priors) when ``cals`` is None."""
    if cals is None:
        return {}
    out = {}
    se = lambda c, pre: max(d["std_error"] for d in c.physical_parameters() if d["name"].startswith(pre))
    out["sigma0_acc_bias_m_s2"] = float(math.hypot(se(cals["accelerometers"], "bias_"),
                                                   cals.get("thermal_sigma_m_s2", 0.0)))
    # the turn-table bias is b_0 + the mean of the bias instability over the calibration session
    # (variance ≤ σ_GM²), ± its SE: a random constant in flight; the flight's own instability is
    # the Gauss-Markov part (its own states)
    out["sigma0_gyro_bias_rad_s"] = float(math.hypot(se(cals["gyros"], "bias_"), noise.gyro_bias_sigma))
    out["gyro_bias_gm_states"] = True
    # the tilt table (±1 g) leaves the second-order term uncertain, and the flight pulls up to 2-3 g
    out["estimate_nonlinearity"] = True
    out["sigma0_acc_nonlinearity_s2_m"] = float(se(cals["accelerometers"], "nonlinearity_"))
    mc = cals.get("magnetometer")
    if mc is not None:
        e3 = mc["ellipsoid"]
        out["mag_heading_sigma_rad"] = float(e3.rms_residual_T_ / mc["H_T"])
    return out


def imu_noise(lab: ImuLab, rate_hz: float) -> ekf.ImuNoise:
    """The filter's white-noise model of the flight's IMU samples: the sensor models' noise as the
    flight's acquisition (:func:`imurig.flights.imu.flight_lab`: averaged 1 kHz conversions) logs it,
    plus that acquisition's ADC noise (:meth:`ekf.ImuNoise.from_sensors`)."""
    from imurig.flights.imu import flight_lab as acquisition

    return ekf.ImuNoise.from_sensors(lab.accelerometers, lab.gyros, rate_hz, adc=acquisition(lab, rate_hz).adc)


def run_filter(truth, stream, gps, opt: FlightOptions, lab: ImuLab, pbar=None, cals: dict | None = None):
    """The filter as ``imurig flight`` runs it: priors from the datasheet (``cals`` None: with the
    scale-factor and misalignment states, which the nominal conversions leave at 1-2 % and 2 mrad) or
    from the calibrations' standard errors; P0 from the alignment's own error propagation
    (:meth:`ekf.LooseEKF.alignment_covariance`). ``opt.mag_iron_states`` chooses the uncalibrated
    compass's error model (iron states instead of the Gauss-Markov heading error)."""
    noise = imu_noise(lab, truth.rate_hz)
    pri = datasheet_priors(truth, opt.mag_iron_states) if cals is None else calibrated_priors(cals, noise)
    cfg = ekf.FilterConfig(nav_rate_hz=opt.nav_rate_hz, gps_latency_s=opt.gps_latency_s, **pri,
                           gps_time_sigma_s=opt.gps_time_sigma_s, **gps_error_model(gps))
    decl = declination_model(truth)
    f = ekf.LooseEKF(cfg, noise, lever_gps_B=truth.lever_gps_B, declination=decl)
    x0 = align(truth, stream, gps, decl)
    f_m, B_m = alignment_means(truth, stream)
    P0 = f.alignment_covariance(x0, f_m, B_m, gps, window_s=ALIGN_WINDOW_S, sigma_mag_rad=cfg.mag_heading_sigma_rad)
    last = [0]

    def cb(k):
        if pbar is not None:
            pbar.update(k - last[0])
        last[0] = k

    return f.fit(stream, gps, x0, P0=P0, progress=cb).solution_


ALIGN_WINDOW_S = 5.0


def alignment_means(truth, stream, window_s: float = ALIGN_WINDOW_S):
    """Mean specific force (3,) m/s² and mean field (3,) T over the first ``window_s`` s."""
    n = max(1, int(window_s * truth.rate_hz))
    return np.asarray(stream.f_B[:n], float).mean(0), np.asarray(stream.B_B[:n], float).mean(0)


def align(truth, stream, gps, decl, window_s=ALIGN_WINDOW_S) -> ins.NavState:
    """Initial state: position/velocity from the first fix, roll/pitch by accelerometer levelling
    over the first ``window_s`` s, heading from the magnetometer (+ declination ``decl``: rad, or a
    callable D(lat, lon, h) evaluated at the first fix)."""
    fm, Bm = alignment_means(truth, stream, window_s)
    roll = math.atan2(-fm[1], -fm[2])
    pitch = math.atan2(fm[0], math.hypot(fm[1], fm[2]))
    if callable(decl):
        i = int(np.flatnonzero(np.asarray(gps.valid, bool))[0])
        decl = decl(float(gps.lat_rad[i]), float(gps.lon_rad[i]), float(gps.h_m[i]))
    yaw = ekf.mag_heading(Bm, roll, pitch, decl)
    q = E.q_from_euler(roll, pitch, yaw)
    i = int(np.flatnonzero(np.asarray(gps.valid, bool))[0])
    Cl = E.C_from_q(q) @ np.asarray(truth.lever_gps_B, float)
    lat, lon, h = E.geodetic_from_ned(-Cl, gps.lat_rad[i], gps.lon_rad[i], gps.h_m[i])
    return ins.NavState(float(lat), float(lon), float(h), np.asarray(gps.v_N[i], float).copy(), q)


def errors(res: ekf.FilterResult, truth) -> dict:
    K = res.meta["samples_per_step"]
    idx = np.arange(res.time_s.size) * K
    sol = ins.NavSolution(res.time_s, res.lat_rad, res.lon_rad, res.h_m, res.v_N, res.q_NB)
    e = ins.nav_errors(sol, truth, idx)
    r_est, p_est, y_est = E.euler_from_q(res.q_NB)
    r_t, p_t, y_t = E.euler_from_q(truth.q_NB[idx])
    return {"idx": idx, "pos_N_m": e["pos_N_m"], "vel_N_m_s": e["vel_N_m_s"],
            "roll_rad": E.wrap_pi(r_est - r_t), "pitch_rad": E.wrap_pi(p_est - p_t),
            "heading_rad": E.wrap_pi(y_est - y_t), "nees": ekf.nees_nav(res, truth, idx)}


def mag_heading_error_rms_deg(truth, stream, decl, every_s: float = 1.0) -> float:
    """RMS (deg) of the magnetometer's own heading (levelled with the TRUE roll and pitch, + IGRF
    declination ``decl``: rad, or a callable D(lat, lon, h)) against the true heading, once per
    ``every_s``: the compass error alone."""
    step = max(1, round(every_s * truth.rate_hz))
    i = np.arange(0, truth.n, step)
    r, p_, y = E.euler_from_q(truth.q_NB[i])
    dec = (lambda j: decl(truth.lat_rad[j], truth.lon_rad[j], truth.h_m[j])) if callable(decl) else (lambda j: decl)
    psi = np.array([ekf.mag_heading(stream.B_B[j], r[k], p_[k], dec(j)) for k, j in enumerate(i)])
    return _rms(E.wrap_pi(psi - y)) / DEG


def _rms(x):
    return float(np.sqrt(np.mean(np.square(x))))


def summarise(err: dict, res: ekf.FilterResult, settle_s: float = 60.0) -> dict:
    m = res.time_s >= res.time_s[0] + settle_s
    out = {"roll_rms_deg": _rms(err["roll_rad"][m]) / DEG, "pitch_rms_deg": _rms(err["pitch_rad"][m]) / DEG,
           "heading_rms_deg": _rms(err["heading_rad"][m]) / DEG,
           "horizontal_position_rms_m": _rms(np.linalg.norm(err["pos_N_m"][m, :2], axis=1)),
           "vertical_position_rms_m": _rms(err["pos_N_m"][m, 2]),
           "velocity_rms_m_s": _rms(np.linalg.norm(err["vel_N_m_s"][m], axis=1)),
           "mean_nees_9dof": float(np.mean(err["nees"][m]))}
    for kind, u in res.updates.items():
        if len(u["nis"]):
            out[f"mean_nis_per_dof_{kind}"] = float(u["nis"].sum() / u["dof"].sum())
    return out


def run(out, opt: FlightOptions, overwrite: bool = False) -> dict:
    """The whole job; writes ``out`` atomically. Returns the summary."""
    from imurig.kernel.outputs import OutputFolder

    opt.validate()
    folder = OutputFolder(out, overwrite=overwrite)
    tracemalloc.start()
    t_wall = time.perf_counter()
    truth = flight_truth(opt)
    if abs(truth.rate_hz - opt.imu_rate_hz) > 1e-9:
        opt.imu_rate_hz = truth.rate_hz
    lab = flight_lab(opt.seed)
    volts = measure_volts(truth, lab, opt.seed)
    gps = gps_fixes(truth, opt, opt.seed)
    ekf.check_gps(gps, truth.rate_hz)
    cals = calibrations(opt.seed, opt.quick_calibration)
    cals["magnetometer"] = mag_calibration(lab, opt.seed)
    cals["thermal"] = thermal_calibration(opt.seed)
    runs = {}
    n_epochs = int((truth.time_s[-1] - truth.time_s[0]) * opt.nav_rate_hz)
    t_filter = 0.0
    with progress(total=2 * n_epochs, desc="flight filter", unit="epoch") as pbar:
        for name, c in (("uncalibrated", None), ("calibrated", cals)):
            stream = imu_stream(truth, volts, lab, c)
            t0 = time.perf_counter()
            res = run_filter(truth, stream, gps, opt, lab, pbar, c)
            t_filter += time.perf_counter() - t0
            runs[name] = (res, errors(res, truth), stream)
    duration = float(truth.time_s[-1] - truth.time_s[0])
    summary = {"flight": opt.flight, "seed": opt.seed, "duration_s": duration, "vehicle": truth.vehicle,
               "imu_rate_hz": truth.rate_hz, "nav_rate_hz": opt.nav_rate_hz, "gps_mode": getattr(gps, "mode", ""),
               "states": list(runs["calibrated"][0].state_names),
               "runs": {k: summarise(e, r) for k, (r, e, _) in runs.items()},
               "filter_wall_s": t_filter, "real_time_factor": 2 * duration / t_filter}
    mc = cals.get("magnetometer")
    decl = declination_model(truth)
    for k, (_r, _e, st) in runs.items():
        summary["runs"][k]["mag_heading_rms_deg"] = mag_heading_error_rms_deg(truth, st, decl)
    summary["magnetometer_calibration"] = None if mc is None else {
        "method": "two-step ellipsoid fit [Elk01] on a virtual-rig tumble of the flight's magnetometer",
        "tumble_s": mc["tumble_s"], "heading_reference": mc["reference"],
        "rotation_fixed_deg": mc["rotation_fix_deg"],
        "heading_offset_deg": math.degrees(mc["heading_offset_rad"]), **mc["ellipsoid"].to_dict()}
    write_products(folder, truth, runs, gps, summary)
    summary["wall_s"] = time.perf_counter() - t_wall
    summary["peak_memory_MB"] = tracemalloc.get_traced_memory()[1] / 1e6
    tracemalloc.stop()
    folder.write_json("summary.json", summary)
    folder.commit()
    return summary


def write_products(folder, truth, runs, gps, summary):
    """Figures (paper Figs. 6-8 analogues, errors, consistency), report.md and flight.rrd."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from imurig.reports.common import md_table, published_figures

    col = {"uncalibrated": "tab:red", "calibrated": "tab:blue"}
    # Fig. 6: roll and pitch in the static phases (or the first minutes on the ground)
    static = [p for p in truth.phases if p[0].startswith("static")] or [("start", truth.time_s[0],
                                                                          truth.time_s[0] + 60.0)]
    fig, ax = plt.subplots(len(static), 2, figsize=(10, 2.6 * len(static)), squeeze=False)
    for i, (nm, a, b) in enumerate(static):
        for name, (res, err, _) in runs.items():
            m = (res.time_s >= a) & (res.time_s < b)
            r, p_, _y = E.euler_from_q(res.q_NB[m])
            ax[i, 0].plot(res.time_s[m], np.degrees(r), color=col[name], label=name)
            ax[i, 1].plot(res.time_s[m], np.degrees(p_), color=col[name], label=name)
        idx = (truth.time_s >= a) & (truth.time_s < b)
        rt, pt, _ = E.euler_from_q(truth.q_NB[idx])
        ax[i, 0].plot(truth.time_s[idx], np.degrees(rt), "k--", label="truth")
        ax[i, 1].plot(truth.time_s[idx], np.degrees(pt), "k--", label="truth")
        ax[i, 0].set_ylabel(f"roll, deg\n{nm}", fontsize=7)
        ax[i, 1].set_ylabel("pitch, deg")
    ax[0, 0].legend(fontsize=7)
    ax[-1, 0].set_xlabel("time, s")
    ax[-1, 1].set_xlabel("time, s")
    fig.suptitle("Estimated roll and pitch in the static tests (cf. paper Fig. 6)")
    fig.tight_layout()
    fig.savefig(folder.file("fig6_static_roll_pitch.png"), dpi=90)
    plt.close(fig)
    # Fig. 7: bias estimates
    fig, ax = plt.subplots(3, 2, figsize=(10, 7), sharex=True)
    for name, (res, _, _) in runs.items():
        for j in range(3):
            ax[j, 0].plot(res.time_s, res.acc_bias_m_s2[:, j], color=col[name], label=name)
            ax[j, 1].plot(res.time_s, np.degrees(res.gyro_bias_rad_s[:, j]), color=col[name], label=name)
    for j, a in enumerate("XYZ"):
        ax[j, 0].set_ylabel(f"{a} acc. bias, m/s²")
        ax[j, 1].set_ylabel(f"{'pqr'[j]} gyro bias, deg/s")
    ax[0, 0].legend(fontsize=7)
    fig.suptitle("Accelerometer and gyro bias estimates before/after calibration (cf. paper Fig. 7)")
    fig.tight_layout()
    fig.savefig(folder.file("fig7_bias_estimates.png"), dpi=90)
    plt.close(fig)
    # Fig. 8: heading vs GPS track
    v = np.asarray(gps.v_N, float)
    track = np.degrees(np.arctan2(v[:, 1], v[:, 0])) % 360
    moving = np.hypot(v[:, 0], v[:, 1]) > 3.0
    fig, ax = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    ax[0].plot(gps.time_s, track, ".", ms=2, color="k", label="GPS track")
    for name, (res, _, _) in runs.items():
        y = np.degrees(E.euler_from_q(res.q_NB)[2]) % 360
        ax[0].plot(res.time_s, y, color=col[name], lw=0.8, label=f"LC {name}")
        yi = np.interp(gps.time_s, res.time_s, np.unwrap(np.radians(y)))
        resid = np.degrees(E.wrap_pi(yi - np.radians(track)))
        ax[1].plot(gps.time_s[moving], resid[moving], ".", ms=2, color=col[name], label=f"LC {name} − GPS track")
    ax[0].set_ylabel("heading, deg")
    ax[1].set_ylabel("residual, deg")
    ax[1].set_xlabel("time, s")
    ax[0].legend(fontsize=7)
    ax[1].legend(fontsize=7)
    fig.suptitle("Heading against GPS track (cf. paper Fig. 8; GPS track only where moving > 3 m/s)")
    fig.tight_layout()
    fig.savefig(folder.file("fig8_heading_vs_track.png"), dpi=90)
    plt.close(fig)
    # errors and consistency
    fig, ax = plt.subplots(4, 1, figsize=(10, 9), sharex=True)
    for name, (res, err, _) in runs.items():
        ax[0].plot(res.time_s, np.degrees(err["roll_rad"]), color=col[name], lw=0.7, label=f"roll {name}")
        ax[0].plot(res.time_s, np.degrees(err["pitch_rad"]), color=col[name], lw=0.7, ls=":")
        ax[1].plot(res.time_s, np.degrees(err["heading_rad"]), color=col[name], lw=0.7, label=name)
        ax[1].plot(res.time_s, 3 * np.degrees(np.sqrt(res.P_diag[:, 8])), color=col[name], lw=0.5, ls="--")
        ax[2].plot(res.time_s, np.linalg.norm(err["pos_N_m"], axis=1), color=col[name], lw=0.7, label=name)
        ax[3].semilogy(res.time_s, np.maximum(err["nees"], 1e-3), color=col[name], lw=0.5, label=name)
    ax[3].axhline(9, color="k", lw=0.5)
    ax[0].set_ylabel("roll/pitch err, deg")
    ax[1].set_ylabel("heading err, deg\n(-- 3σ)")
    ax[2].set_ylabel("position err, m")
    ax[3].set_ylabel("NEES (9 dof)")
    ax[3].set_xlabel("time, s")
    ax[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(folder.file("fig_errors_consistency.png"), dpi=90)
    plt.close(fig)
    # report.md
    pub = published_figures().get("magnetometer", {}).get("heading_bias_corrected_deg", 10)
    rows = []
    for k in summary["runs"]["calibrated"]:
        rows.append([k, f"{summary['runs']['uncalibrated'][k]:.4g}", f"{summary['runs']['calibrated'][k]:.4g}"])
    text = f"""# imurig flight — loosely coupled GPS/INS, uncalibrated vs calibrated IMU

Flight: `{summary['flight']}` ({summary['vehicle']}), {summary['duration_s']:.0f} s, IMU {summary['imu_rate_hz']:g} Hz,
navigation {summary['nav_rate_hz']:g} Hz, GPS: {summary['gps_mode']}. Filter states ({len(summary['states'])}):
{', '.join(summary['states'])}.
Errors are RMS against truth after the first 60 s.

{md_table(['quantity', 'uncalibrated', 'calibrated'], rows)}

Real-time factor of the filter: {summary['real_time_factor']:.1f}x ({summary['filter_wall_s']:.1f} s for two runs).

- `fig6_static_roll_pitch.png`: roll and pitch in the static phases (paper Fig. 6).
- `fig7_bias_estimates.png`: bias states before/after calibration (paper Fig. 7).
- `fig8_heading_vs_track.png`: heading vs GPS track; the paper removed a ~{pub} deg heading bias with
  its magnetometer calibration (Fig. 8). Here the uncalibrated run uses the fluxgate's nominal
  conversion (hard and soft iron left in: magnetometer heading error {summary['runs']['uncalibrated']['mag_heading_rms_deg']:.2f} deg RMS);
  the calibrated run the ellipsoid fit of a 120 s virtual-rig tumble of the same fluxgate
  ({summary['runs']['calibrated']['mag_heading_rms_deg']:.3f} deg RMS).
- `fig_errors_consistency.png`: attitude, heading (with 3σ), position errors and NEES.
- `flight.rrd`: open with `rerun flight.rrd`.

![fig6](fig6_static_roll_pitch.png)
![fig7](fig7_bias_estimates.png)
![fig8](fig8_heading_vs_track.png)
![errors](fig_errors_consistency.png)
"""
    folder.write_text("report.md", text)
    # rerun
    from imurig.reports import viz

    with viz.RrdWriter(folder.file("flight.rrd"), overwrite=True) as w:
        lat0, lon0, h0 = truth.lat_rad[0], truth.lon_rad[0], truth.h_m[0]
        sub = slice(None, None, max(1, int(truth.rate_hz)))
        d_true = E.ned_from_geodetic(truth.lat_rad[sub], truth.lon_rad[sub], truth.h_m[sub], lat0, lon0, h0)
        viz.log_points(w, "world/truth_route", d_true * [1, 1, -1], color=(200, 200, 200), radius=2.0)
        d_gps = E.ned_from_geodetic(gps.lat_rad, gps.lon_rad, gps.h_m, lat0, lon0, h0)
        viz.log_points(w, "world/gps_fixes", d_gps * [1, 1, -1], color=(255, 200, 0), radius=3.0)
        for name, (res, err, _) in runs.items():
            ss = slice(None, None, max(1, int(res.meta["nav_rate_hz"])))
            d = E.ned_from_geodetic(res.lat_rad[ss], res.lon_rad[ss], res.h_m[ss], lat0, lon0, h0)
            viz.log_points(w, f"world/ekf_{name}", d * [1, 1, -1],
                           color=(220, 60, 60) if name == "uncalibrated" else (60, 60, 220), radius=1.5)
            t = res.time_s[ss]
            viz.log_scalars(w, f"errors/{name}", t, {
                "roll_err_deg": np.degrees(err["roll_rad"][ss]), "pitch_err_deg": np.degrees(err["pitch_rad"][ss]),
                "heading_err_deg": np.degrees(err["heading_rad"][ss]),
                "heading_3sigma_deg": 3 * np.degrees(np.sqrt(res.P_diag[ss, 8])),
                "pos_err_m": np.linalg.norm(err["pos_N_m"][ss], axis=1),
                "pos_3sigma_m": 3 * np.sqrt(res.P_diag[ss, 0:3].sum(axis=1)), "nees": err["nees"][ss]})
        viz.log_text(w, "summary", text)
