"""State layout, sensor noise model and settings of the loosely coupled GPS/INS filter
(:mod:`imurig.flights.ekf`).

Error state (estimate minus truth), in this order (the optional blocks follow the 18 base states in
the order of :meth:`FilterConfig.state_names`):

    δr_N  (3)  position error, m, NED metres at the vehicle (north, east, down)
    δv_N  (3)  velocity error, m/s, NED
    ψ_N   (3)  attitude error, rad: C_NB,est = (I − [ψ×]) C_NB,true
    δb_a  (3)  accelerometer bias error, m/s²        (b̂_a − b_a)
    δb_g  (3)  gyro bias error, rad/s                (b̂_g − b_g)
    δT_a  (3)  accelerometer temperature error, K    (T̂_a − T_a)
   [δs_a, δs_g (6) scale factors; misalignments (12); δk2_a (3) nonlinearity; thermal terms (12);
    the receiver's Gauss-Markov position error (3); the gyros' bias instability (3); the compass's
    heading error (1) or the magnetometer's installation errors (12)]

The sensor-error states are named as the effect library names the parameter
(:mod:`imurig.sensors.error_states`): ``acc.bias.b_x``, ``gyro.bias.b_x``,
``acc.temperature_sensor.dT_x``, ``acc.scale_factor.s_x``, ``gyro.axis_misalignment.M_xy``,
``acc.scale_nonlinearity.k2_x``, ``acc.temperature_drift.kT_x``, ``gyro.gyro_noise.b_gm_x``,
``mag.hard_iron.b_x``, ``mag.soft_iron.A_xy`` ...; each block's truth reads the same parameter
from the sensor model's truth.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from imurig.kernel.units import T_REF_K
from imurig.sensors import error_states as es
from imurig.sensors.effects.adc_quantisation import AdcQuantisation
from imurig.sensors.effects.base import ChainContext

NAV_STATES = ("dr_n", "dr_e", "dr_d", "dv_n", "dv_e", "dv_d", "psi_n", "psi_e", "psi_d")
# the sensor-error states take their names from the effect library (:mod:`imurig.sensors.error_states`)
BASE_STATES = NAV_STATES + es.names(es.ACC_BIAS, es.GYRO_BIAS, es.ACC_TEMPERATURE)
SCALE_STATES = es.names(es.ACC_SCALE, es.GYRO_SCALE)
GPS_STATES = es.names(es.GPS_POSITION)
GYRO_GM_STATES = es.names(es.GYRO_BIAS_INSTABILITY)
K2_STATES = es.names(es.ACC_NONLINEARITY)
THERMAL_STATES = es.names(*es.ACC_THERMAL)
MIS_PAIRS = es.MIS_PAIRS   # (i, j): input j sensed by axis i
MIS_STATES = es.names(es.ACC_MISALIGNMENT, es.GYRO_MISALIGNMENT)
MAG_HEADING_STATES = es.names(es.MAG_HEADING)
MAG_IRON_STATES = es.names(es.MAG_HARD_IRON, es.MAG_MATRIX)
P, V, A, BA, BG, TA, SA, SG = (slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12), slice(12, 15),
                               slice(15, 18), slice(18, 21), slice(21, 24))


#: the settings that add states to the paper's 18 (each False in the paper's filter)
STATE_BLOCK_FLAGS = ("estimate_scale_factors", "estimate_misalignments", "estimate_nonlinearity",
                     "estimate_thermal_terms", "gps_pos_states", "gyro_bias_gm_states", "mag_error_state",
                     "mag_iron_states")


def paper18_settings(settings: dict) -> dict:
    """``settings`` (keyword arguments of :class:`FilterConfig`) with every state block beyond the
    paper's 18 switched off (:data:`STATE_BLOCK_FLAGS`): the paper's filter, section 4.2."""
    out = {k: v for k, v in settings.items() if k not in STATE_BLOCK_FLAGS}
    return {**out, **{k: False for k in STATE_BLOCK_FLAGS}}


@dataclass
class ImuNoise:
    """Stochastic sensor model of the filter (SI).

    ``vrw`` m/s²/√Hz and ``arw`` rad/s/√Hz white-noise densities; gyro bias instability
    Gauss-Markov ``gyro_bias_sigma`` rad/s with ``gyro_bias_tau_s``; accelerometer bias random
    walk ``acc_bias_rw`` m/s²/√s; temperature random walk ``temp_rw`` K/√s; scale-factor random
    walks ``scale_rw`` 1/√s.
    """

    vrw: float = 3.5e-5
    arw: float = 0.0015 * math.pi / 180
    gyro_bias_sigma: float = 0.001 * math.pi / 180
    gyro_bias_tau_s: float = 100.0
    acc_bias_rw: float = 2e-6
    temp_rw: float = 2e-3
    scale_rw: float = 1e-7

    @classmethod
    def from_sensors(cls, accelerometers, gyros, sample_rate_hz: float, *, adc=None, averaged: bool | None = None,
                     **kw) -> ImuNoise:
        """Densities (N such that a white error of per-sample σ at f_s has N = σ/√f_s, the velocity
        or angle random walk) from the sensor models and the acquisition.

        Accelerometer current noise (:meth:`QFlexTriad.noise_current`): a band [0, B] of rms r has
        the two-sided PSD r²/(2B) at DC, the random-walk density; bands away from DC add nothing to
        the walk. Bands above f_s/2 alias in as white noise of per-sample rms r (N² = r²/f_s) when
        sampled directly, and average out with averaged logging (``averaged``, default
        ``adc.averaging > 1``). The ADC (``adc``, :class:`imurig.sensors.adc.DAQ6036E`) adds to
        every logged sample σ_V² = (q²/12 + (e q)²)/n_avg (dithered mean of n_avg conversions;
        q²/12 + (e q)² without averaging) + σ_cm² (common-mode noise unless differential), divided
        by each sensor's sensitivity (accelerometer k1 R_load V/(m/s²), gyro V/(rad/s); the
        smallest of the three axes). Divided by the current scale factor K1; the gyro's ARW and
        bias instability as given."""
        fs = float(sample_rate_hz)
        if averaged is None:
            averaged = adc is not None and int(getattr(adc, "averaging", 1)) > 1
        current = accelerometers.current_noise(averaged)   # the effects own their noise
        gyro_noise = gyros.noise()
        k1 = float(np.min(accelerometers.k1_A_per_m_s2))
        vrw2 = (current.random_walk_density_A(fs) / k1) ** 2
        arw2 = float(gyro_noise.arw_rad_s_per_sqrt_hz) ** 2
        if adc is not None:
            ctx = ChainContext(time_s=np.zeros(1), sample_rate_hz=fs, adc=adc)
            var_v = AdcQuantisation().noise_variance(ctx) + adc.common_mode.noise_variance(ctx)
            s_acc = float(np.min(np.asarray(accelerometers.nominal_sensitivity_V_per_m_s2())))
            s_gyro = float(np.min(np.abs(np.asarray(gyros.scale_V_per_rad_s, float))))
            vrw2 += var_v / s_acc ** 2 / fs
            arw2 += var_v / s_gyro ** 2 / fs
        return cls(vrw=math.sqrt(vrw2), arw=math.sqrt(arw2), gyro_bias_sigma=gyro_noise.bias_instability_rad_s,
                   gyro_bias_tau_s=gyro_noise.bias_instability_tau_s, **kw)


@dataclass
class FilterConfig:
    """Filter settings. Initial 1σ: position m, velocity m/s, attitude rad (roll/pitch and
    heading), accelerometer bias m/s², gyro bias rad/s, temperature K, scale factors.

    GPS position errors that are Gauss-Markov in time (``gps_pos_tau_s`` τ, white part
    ``gps_pos_sigma_white_N_m``; the rest of the fix's σ is the correlated part σ_GM) are not
    augmented as states: the filter inflates R so that N fixes of a correlated sequence carry the
    information they really carry. For a first-order GM sampled at Δt (φ = e^{−Δt/τ}) the variance
    of a long average is σ_GM² (1+φ)/(1−φ)/N instead of σ_GM²/N, hence

        R = σ_w² + σ_GM² (1+φ)/(1−φ)            [m², per NED axis]

    (≈ σ_GM² 2τ/Δt for τ ≫ Δt). This keeps the filter consistent on averages over ≳ τ; over
    shorter spans it under-weights the fixes (conservative). With ``gps_pos_states`` (off by
    default: the paper's 18 states) the correlated part is carried as 3 states instead.

    The defaults are the paper's 18-state filter (``paper18``, section 4.2); every optional block
    of states is switched on by its own flag (:data:`STATE_BLOCK_FLAGS`, :func:`paper18_settings`).

    GPS times: ``gps.time_s`` is the fix's time of validity, used at the first epoch at or after
    ``time_s + gps_latency_s``. A residual error of the time of validity (σ ``gps_time_sigma_s``,
    e.g. the IMU-clock quantisation of the tag) adds σ_t² v vᵀ to R of the position fix.

    ``mag_error_state``: the compass's systematic heading error e_m (hard/soft iron of an
    uncalibrated fluxgate: a smooth function of the attitude, constant while the attitude holds) is
    one more state, ψ_m = ψ + e_m + white, a Gauss-Markov process in the *rotation angle* of the body
    rather than in time: over a step in which the body turns by Δθ (rad, relative to the NED frame)
    φ = exp(−Δθ/θ_c), Q = σ_m²(1 − φ²), σ_m ``mag_error_sigma_rad``, θ_c ``mag_error_corr_rad``.
    ``mag_heading_sigma_rad`` is then the white part only.

    ``mag_iron_states``: instead, the magnetometer's installation errors are 12 random constants
    (no process noise) in its linear measurement equation

        B_m = (I + ΔA) B_B + b + n          [T, (3,)]   b: hard iron (body frame, T, 3 states);
                                                        ΔA: soft iron + misalignment + sensitivity
                                                        error (3×3, −, 9 states, row-major)

    The compass uses the corrected field B̂ = (I + ΔÂ)⁻¹ (B_m − b̂) (:func:`mag_iron_jacobian`);
    prior covariance ``mag_iron_prior_cov`` (12, 12) (:func:`mag_iron_prior_cov`). Directions the
    flight does not excite (e.g. b_z in level flight, the isotropic part of ΔA, which leaves the
    heading unchanged) keep their prior. ``mag_heading_sigma_rad`` is the white part. The heading
    is nonlinear in θ at the priors' size (~0.5 deg of second-order term against a 0.015 deg white
    part), so the compass update is a Gaussian second-order one (E[z] and var from the Hessian in θ,
    :func:`mag_iron_hessian`), iterated ``mag_iterations`` times (iterated EKF).

    ``mag_consider_states`` (with ``mag_iron_states``): the compass update changes only the heading
    ψ_d, the gyro biases and the iron states; every other state is a Schmidt "consider" state (its
    gain row is zero, its covariance and cross-covariances follow exactly from the Joseph form, which
    holds for any gain). The levelled compass is sensitive to the tilt (tan I ≈ 2.4 at Delft), but
    with 5 % soft iron the tilt is confounded with ΔA_xz, ΔA_zx and the hard iron, and the
    linearised update at the priors' size draws false tilt information from it: on 12 IMUs the
    uncalibrated mean NEES was 11.0 with 88 % of epochs in band (one IMU 27); with the consider
    update 9.6 and 98 %, compass NIS 1.00 after the ground circle (docs/flights-navigation.md)."""

    nav_rate_hz: float = 50.0
    estimate_scale_factors: bool = False
    gps_latency_s: float = 0.0
    use_gps_velocity: bool = True
    use_magnetometer: bool = True
    mag_rate_hz: float = 1.0
    mag_heading_sigma_rad: float = 1.0 * math.pi / 180
    temp_rate_hz: float = 1.0
    temp_sigma_K: float = 0.05
    thermal_slope_m_s2_per_K: np.ndarray = field(default_factory=lambda: np.zeros(3))
    reference_temperature_K: float = T_REF_K
    sigma0_pos_m: float = 5.0
    sigma0_vel_m_s: float = 0.5
    sigma0_tilt_rad: float = 1.0 * math.pi / 180
    sigma0_heading_rad: float = 10.0 * math.pi / 180
    sigma0_acc_bias_m_s2: float = 0.1
    sigma0_gyro_bias_rad_s: float = 0.01 * math.pi / 180
    sigma0_temp_K: float = 3.0
    sigma0_acc_scale: float = 0.01
    sigma0_gyro_scale: float = 0.02
    gps_sigma_scale: float = 1.0
    gps_pos_tau_s: float | None = None
    gps_time_sigma_s: float = 0.0
    gps_pos_sigma_white_N_m: tuple = (0.0, 0.0, 0.0)
    gps_pos_states: bool = False
    gyro_bias_gm_states: bool = False
    estimate_misalignments: bool = False
    mag_error_state: bool = False
    mag_error_sigma_rad: float = 0.0
    mag_error_corr_rad: float = 1.0
    mag_iron_states: bool = False
    mag_iron_prior_cov: np.ndarray | None = None
    mag_iterations: int = 3
    mag_consider_states: bool = False
    sigma0_acc_misalignment_rad: float = 2e-3 / math.sqrt(3.0)
    estimate_nonlinearity: bool = False
    sigma0_acc_nonlinearity_s2_m: float = 48e-6 / 9.80665 / math.sqrt(3.0)
    estimate_thermal_terms: bool = False
    sigma0_acc_thermal: tuple = (0.0, 0.0, 0.0, 0.0)
    hysteresis_width_K: float = 4.0
    sigma0_gyro_misalignment_rad: float = 2e-3 / math.sqrt(3.0)

    @property
    def n_gyro_gm(self) -> int:
        return 3 if self.gyro_bias_gm_states else 0

    @property
    def augment_gps(self) -> bool:
        """Whether the receiver's Gauss-Markov position error is carried as 3 extra states."""
        return bool(self.gps_pos_states and self.gps_pos_tau_s is not None)

    @property
    def n_states(self) -> int:
        return (18 + (6 if self.estimate_scale_factors else 0) + (12 if self.estimate_misalignments else 0)
                + (3 if self.estimate_nonlinearity else 0) + (12 if self.estimate_thermal_terms else 0)
                + (3 if self.augment_gps else 0) + self.n_gyro_gm
                + (1 if self.mag_error_state else 0) + (12 if self.mag_iron_states else 0))

    def state_names(self) -> tuple:
        return (BASE_STATES + (SCALE_STATES if self.estimate_scale_factors else ())
                + (MIS_STATES if self.estimate_misalignments else ()) + (K2_STATES if self.estimate_nonlinearity else ())
                + (THERMAL_STATES if self.estimate_thermal_terms else ())
                + (GPS_STATES if self.augment_gps else ()) + (GYRO_GM_STATES if self.gyro_bias_gm_states else ())
                + (MAG_HEADING_STATES if self.mag_error_state else ())
                + (MAG_IRON_STATES if self.mag_iron_states else ()))

    def mis_slices(self) -> tuple[slice, slice]:
        """Slices of the accelerometer and gyro misalignment states (6 each, :data:`MIS_PAIRS`)."""
        n0 = 24 if self.estimate_scale_factors else 18
        return slice(n0, n0 + 6), slice(n0 + 6, n0 + 12)

    def mag_index(self) -> int:
        """Index of the compass heading-error state (after the gyro GM states, when ``mag_error_state``)."""
        return self.gyro_gm_slice().stop

    def mag_iron_slice(self) -> slice:
        """Slice of the magnetometer installation-error states (12, the last ones, when
        ``mag_iron_states``): hard iron b (3, T) then ΔA (9, −, row-major)."""
        return slice(self.n_states - (12 if self.mag_iron_states else 0), self.n_states)

    def k2_slice(self) -> slice:
        """Slice of the accelerometers' second-order nonlinearity states δk2 (s²/m), when
        ``estimate_nonlinearity``: the filter applies f̂ = f − b̂ − k̂2 ⊙ f² (per axis)."""
        n0 = (24 if self.estimate_scale_factors else 18) + (12 if self.estimate_misalignments else 0)
        return slice(n0, n0 + 3)

    def thermal_slice(self) -> slice:
        """Slice of the accelerometers' thermal-term states (12, when ``estimate_thermal_terms``):
        per axis i the bias tempco k_T (m/s²/K), scale tempco s_T (1/K), bias hysteresis H_b (m/s²)
        and scale hysteresis H_s (-), acting relative to the alignment (T₀, h₀) on the measured
        temperature T_i and hysteresis state h_i (play operator of width ``hysteresis_width_K``):

            f̂_i = f_i − k̂_T,i ΔT_i − ŝ_T,i f_i ΔT_i − Ĥ_b,i Δh_i − Ĥ_s,i f_i Δh_i,
            ΔT = T − T₀, Δh = h − h₀  (what the terms did at T₀ is in the bias and scale states).

        Prior σ ``sigma0_acc_thermal`` = (σ_kT, σ_sT, σ_Hb, σ_Hs)."""
        n0 = ((24 if self.estimate_scale_factors else 18) + (12 if self.estimate_misalignments else 0)
              + (3 if self.estimate_nonlinearity else 0))
        return slice(n0, n0 + 12)

    def gps_slice(self) -> slice:
        n0 = ((24 if self.estimate_scale_factors else 18) + (12 if self.estimate_misalignments else 0)
              + (3 if self.estimate_nonlinearity else 0) + (12 if self.estimate_thermal_terms else 0))
        return slice(n0, n0 + 3)

    def gyro_gm_slice(self) -> slice:
        """Slice of the gyros' bias-instability states (3, when ``gyro_bias_gm_states``): the
        Gauss-Markov part b_gm of the gyro bias, b_g = b_0 + b_gm, ḃ_gm = −b_gm/τ + w
        (σ ``ImuNoise.gyro_bias_sigma``, τ ``gyro_bias_tau_s``). The δb_g states are then the
        turn-on bias b_0 alone, a random constant (prior ``sigma0_gyro_bias_rad_s``, no process
        noise). Without these states the whole bias is one Gauss-Markov state, which lets the
        filter believe that a turn-on bias error decays by itself with τ."""
        n0 = self.gps_slice().start + (3 if self.augment_gps else 0)
        return slice(n0, n0 + self.n_gyro_gm)
