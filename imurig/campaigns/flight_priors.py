"""The navigation filter's priors for the flight: from the sensors' datasheets (an uncalibrated
IMU) or from the rig calibrations' standard errors, and the IGRF declination along the route.

Datasheet limits are read from the sensor classes themselves (the keyword defaults of their
``from_datasheet``), each error taken as uniform within ±limit: σ = limit/√3.
"""
from __future__ import annotations

import inspect
import math

import numpy as np
import pyIGRF

from imurig.flights import ekf
from imurig.flights.filter_config import paper18_settings
from imurig.flights.imu import flight_lab as acquisition_lab
from imurig.kernel.errors import ConfigError
from imurig.kernel.site import decimal_year, parse_time
from imurig.kernel.units import G_STANDARD
from imurig.sensors.accelerometer import QFlexTriad
from imurig.sensors.chain import ImuLab
from imurig.sensors.gyro import FOGTriad
from imurig.sensors.magnetometer import FluxgateTriad

DEG = math.pi / 180


def flight_declination(truth) -> float:
    """IGRF declination (rad, east positive) at the start of the flight."""
    yr = decimal_year(parse_time(truth.meta.get("start_time", "2005-06-26T08:00:00+02:00")))
    return ekf.declination_rad(float(truth.lat_rad[0]), float(truth.lon_rad[0]), float(truth.h_m[0]), yr)


def declination_model(truth) -> ekf.IgrfDeclination:
    """IGRF declination along the route (callable D(lat, lon, h), rad) at the flight's date."""
    return ekf.IgrfDeclination(decimal_year(parse_time(truth.meta.get("start_time", "2005-06-26T08:00:00+02:00"))))


def gps_error_model(gps) -> dict:
    """The receiver's Gauss-Markov position error (σ_GM per NED axis, τ) from the fixes' meta, for the
    filter's correlated-error treatment; empty for white-noise fixes."""
    rx = (getattr(gps, "meta", None) or {}).get("receiver")
    if not rx:
        return {}
    return {"gps_pos_tau_s": float(rx["tau_gm_s"]), "gps_pos_sigma_white_N_m": tuple(rx["sigma_white_N_m"])}


def datasheet_values(cls, name: str) -> float:
    """A datasheet limit as the sensor class's ``from_datasheet`` states it (keyword default)."""
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
    F = FluxgateTriad
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
    F = FluxgateTriad
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
    Q, G, F = QFlexTriad, FOGTriad, FluxgateTriad
    g = G_STANDARD
    s_b = datasheet_values(Q, "bias_max_ug") * 1e-6 * g
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
            # the compass's systematic heading error: σ_m, θ_c also without its state (paper18 folds σ_m into R)
            "mag_error_sigma_rad": s_m, "mag_error_corr_rad": th_c,
            **({"mag_iron_states": True, "mag_iron_prior_cov": mag_iron_prior_datasheet(), "mag_consider_states": True}
               if mag_iron_states else {"mag_error_state": True}),
            "mag_heading_sigma_rad": datasheet_values(F, "noise_nT_rms") * 1e-9 / (H_nT * 1e-9)}


#: the flight filter's named state sets (``imurig flight --filter``, ``FlightOptions.filter``)
FILTER_VARIANTS = {
    "paper18": "the paper's 18 states (section 4.2): position, velocity, attitude, accelerometer and gyro biases, "
               "accelerometer temperatures, in both runs; what has no state is in R (uncalibrated compass: its "
               "systematic heading error as white noise; the receiver's correlated error: R inflated)",
    "extended": "the 18 and a state for each sensor error the run's calibration leaves uncertain: uncalibrated 69 "
                "(scale factors, misalignments, nonlinearity, thermal terms, gyro instability, the receiver's "
                "correlated error, the compass's 12 installation errors; 58 with --compass-model gauss-markov), "
                "calibrated 27 (nonlinearity, gyro instability, the receiver's error)",
}


def filter_settings(variant: str, truth, gps, noise: ekf.ImuNoise, cals: dict | None,
                    mag_iron_states: bool = True) -> dict:
    """:class:`ekf.FilterConfig` keyword arguments (priors and states) of one flight run: the datasheet
    priors (``cals`` None: the uncalibrated IMU) or the calibrated ones, the receiver's error model,
    and the states of the named ``variant`` (:data:`FILTER_VARIANTS`). ``paper18`` keeps the paper's
    18 states: the uncalibrated compass's systematic heading error σ_m (the datasheet's, which
    ``extended`` carries as states) is added to the white heading σ in quadrature, and the single
    gyro-bias state (Gauss-Markov, σ_GM, τ) starts at √(σ_turn-on² + σ_GM²)."""
    if variant not in FILTER_VARIANTS:
        raise ConfigError(f"unknown filter {variant!r}; choose one of {', '.join(FILTER_VARIANTS)}")
    pri = datasheet_priors(truth, mag_iron_states) if cals is None else calibrated_priors(cals, noise)
    settings = {**pri, **gps_error_model(gps)}
    if variant == "extended":
        return {**settings, "gps_pos_states": True}
    out = paper18_settings(settings)
    if cals is None:
        out["mag_heading_sigma_rad"] = math.hypot(pri["mag_heading_sigma_rad"], pri["mag_error_sigma_rad"])
        out["sigma0_gyro_bias_rad_s"] = math.hypot(pri["sigma0_gyro_bias_rad_s"], noise.gyro_bias_sigma)
    return out


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
    return ekf.ImuNoise.from_sensors(lab.accelerometers, lab.gyros, rate_hz, adc=acquisition_lab(lab, rate_hz).adc)
