"""Loosely coupled GPS/INS error-state EKF with the 18 states of the paper's section 4.2.

Error state (estimate minus truth), in this order:

    δr_N  (3)  position error, m, NED metres at the vehicle (north, east, down)
    δv_N  (3)  velocity error, m/s, NED
    ψ_N   (3)  attitude error, rad: C_NB,est = (I − [ψ×]) C_NB,true
    δb_a  (3)  accelerometer bias error, m/s²        (b̂_a − b_a)
    δb_g  (3)  gyro bias error, rad/s                (b̂_g − b_g)
    δT_a  (3)  accelerometer temperature error, K    (T̂_a − T_a)
   [δs_a  (3)  accelerometer scale-factor error, −   (scale-factor variant, 24 states)
    δs_g  (3)  gyro scale-factor error, −]

The paper's "3 accelerometer temperatures" are implemented as states T_a (the accelerometers'
own temperatures) measured by the Q-Flex temperature channels and coupled into the specific
force through the bias temperature slope k_T (m/s²/K, from the thermal calibration; zero
without one). Sensor model used by the filter (per axis, SI):

    f_in = (1 + s_a) f_B + b_a + k_T (T_a − T_ref) + n_a       [m/s²]   n_a: VRW
    w_in = (1 + s_g) w_IB_B + b_g + n_g                         [rad/s]  n_g: ARW
    b_g: first-order Gauss-Markov (σ, τ) on top of a turn-on bias; b_a: random walk; T_a: random walk

The INS (:mod:`imurig.flights.ins`) runs on the corrected increments at the navigation rate;
the covariance is propagated with Φ = I + F T + ½ (F T)² and Q_d = ½(Φ Q Φᵀ + Q) T.
Linearised error dynamics (ω_in = ω_IE + ω_EN):

    δṙ = δv
    δv̇ = [f_N×] ψ − C δb_a − C diag(k_T) δT_a − C diag(f_B) δs_a − (2ω_IE + ω_EN) × δv
         − (2 δω_IE + δω_EN) × v + [0, 0, 2γ/R δr_d]
    ψ̇ = −ω_in × ψ + δω_in + C δb_g + C diag(w_B) δs_g

Measurements (innovation = predicted − measured = H δx + noise):

- GPS position of the antenna at ``r + C_NB l_B``: H = [I, −Δt I, [(C l)×], 0 …, C[l×] Δt …];
  Δt ≥ 0 is the latency between the fix's time tag and the epoch the fix is used at, so the
  stored INS history at the tag gives the prediction and the error is carried forward by δv Δt;
- GPS velocity of the antenna, v + C (ω_NB × l): H = [0, I, [(C(ω×l))×], 0, C[l×], 0];
- magnetic heading from the magnetometer levelled with the INS roll and pitch, plus the
  IGRF declination: H = [tan I cos D, tan I sin D, −1] from the levelled field
  (:func:`mag_heading_jacobian`; the levelling with the INS's own tilt is part of it);
- accelerometer temperature channels: H = [0 … I].

Each update records its normalised innovation squared (NIS) and dof.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from imurig.flights import earth as E
from imurig.flights import ins

from imurig.kernel.errors import ConfigError, RecordingError
from imurig.kernel.units import T_REF_K
from imurig.sensors.noise import sampled_bands

BASE_STATES = ("dr_n", "dr_e", "dr_d", "dv_n", "dv_e", "dv_d", "psi_n", "psi_e", "psi_d",
               "dba_x", "dba_y", "dba_z", "dbg_p", "dbg_q", "dbg_r", "dTa_x", "dTa_y", "dTa_z")
SCALE_STATES = ("dsa_x", "dsa_y", "dsa_z", "dsg_p", "dsg_q", "dsg_r")
GPS_STATES = ("dgps_n", "dgps_e", "dgps_d")
GYRO_GM_STATES = ("dbgm_p", "dbgm_q", "dbgm_r")
K2_STATES = ("dk2a_x", "dk2a_y", "dk2a_z")
THERMAL_STATES = tuple(f"{p}_{a}" for p in ("dkTa", "dsTa", "dHba", "dHsa") for a in "xyz")
MIS_PAIRS = ((0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1))   # (i, j): input j sensed by axis i
MIS_STATES = tuple(f"dma_{i}{j}" for i, j in MIS_PAIRS) + tuple(f"dmg_{i}{j}" for i, j in MIS_PAIRS)
MAG_IRON_STATES = tuple(f"dmag_b{a}" for a in "xyz") + tuple(f"dmag_A{i}{j}" for i in range(3) for j in range(3))
P, V, A, BA, BG, TA, SA, SG = (slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12), slice(12, 15),
                               slice(15, 18), slice(18, 21), slice(21, 24))


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
        dens2 = 0.0
        for lo, hi, rms in sampled_bands(accelerometers.noise_bands, fs, averaged):
            if lo <= 0:  # a band reaching DC (aliased bands arrive as white, 0..f_s/2)
                dens2 += rms ** 2 / (2 * hi)
        k1 = float(np.min(accelerometers.k1_A_per_m_s2))
        vrw2 = dens2 / k1 ** 2
        arw2 = float(gyros.arw_rad_s_per_sqrt_hz) ** 2
        if adc is not None:
            q = float(adc.lsb_V)
            e = float(adc.input_noise_lsb_rms) * q
            n_avg = max(1, int(getattr(adc, "averaging", 1)))
            var_v = (q ** 2 / 12 + e ** 2) / n_avg
            if getattr(adc, "grounding", "DIFF") != "DIFF":
                var_v += float(adc.common_mode_noise_V_rms) ** 2
            s_acc = float(np.min(np.asarray(accelerometers.nominal_sensitivity_V_per_m_s2())))
            s_gyro = float(np.min(np.abs(np.asarray(gyros.scale_V_per_rad_s, float))))
            vrw2 += var_v / s_acc ** 2 / fs
            arw2 += var_v / s_gyro ** 2 / fs
        return cls(vrw=math.sqrt(vrw2), arw=math.sqrt(arw2), gyro_bias_sigma=gyros.bias_instability_rad_s,
                   gyro_bias_tau_s=gyros.bias_instability_tau_s, **kw)


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
    shorter spans it under-weights the fixes (conservative).

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
    gps_pos_states: bool = True
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
                + (("dmag_heading",) if self.mag_error_state else ())
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


@dataclass
class ImuStream:
    """IMU samples in SI after whatever calibration the user applies (the filter's input).

    ``time_s`` (N,) uniform; ``w_IB_B`` (N, 3) rad/s; ``f_B`` (N, 3) m/s²; optional ``B_B``
    (N, 3) T magnetometer field; optional ``T_acc_K`` (N, 3) accelerometer temperature channels.
    ``samples``: ``"held"`` (each sample the mean over [t_k, t_k+1), an integrating IMU, the flight
    truth and the sensor chain) or ``"instantaneous"`` (see :func:`imurig.flights.ins.preintegrate`).
    """

    time_s: np.ndarray
    w_IB_B: np.ndarray
    f_B: np.ndarray
    B_B: np.ndarray | None = None
    T_acc_K: np.ndarray | None = None
    samples: str = "held"


@dataclass
class FilterResult:
    """Filter output at the navigation epochs ``time_s`` (M,)."""

    time_s: np.ndarray
    lat_rad: np.ndarray
    lon_rad: np.ndarray
    h_m: np.ndarray
    v_N: np.ndarray
    q_NB: np.ndarray
    acc_bias_m_s2: np.ndarray
    gyro_bias_rad_s: np.ndarray
    temp_acc_K: np.ndarray
    scale_acc: np.ndarray
    scale_gyro: np.ndarray
    P_diag: np.ndarray           # (M, n) variances of the error state
    P_nav: np.ndarray            # (M, 9, 9) covariance of δr, δv, ψ
    state_names: tuple
    updates: dict                # kind -> dict(time_s, nis, dof, innovation)
    meta: dict = field(default_factory=dict)


def _check_stream(imu: ImuStream):
    t = np.asarray(imu.time_s, float)
    for name in ("w_IB_B", "f_B", "B_B", "T_acc_K"):
        a = getattr(imu, name)
        if a is None:
            continue
        a = np.asarray(a, float)
        if a.shape != (t.size, 3):
            raise RecordingError(f"IMU stream '{name}' has shape {a.shape}, expected ({t.size}, 3)")
        if not np.all(np.isfinite(a)):
            raise RecordingError(f"IMU stream '{name}' contains NaN/inf; clean the recording first")
    return t


def check_gps(gps, imu_rate_hz: float):
    """Refuse GPS fixes that cannot be used: NaN in valid fixes, non-increasing tags, or a fix
    rate above the IMU rate."""
    t = np.asarray(gps.time_s, float)
    if t.size == 0:
        raise RecordingError("no GPS fixes: the loosely coupled filter needs at least one")
    if np.any(np.diff(t) <= 0):
        raise RecordingError("GPS fix time tags must be strictly increasing")
    if t.size > 1:
        rate = 1.0 / float(np.median(np.diff(t)))
        if rate > imu_rate_hz:
            raise ConfigError(f"GPS rate {rate:g} Hz is above the IMU rate {imu_rate_hz:g} Hz; "
                              "use a GPS rate at or below the IMU rate")
    valid = np.asarray(gps.valid, bool)
    for name in ("lat_rad", "lon_rad", "h_m", "v_N", "sigma_pos_N", "sigma_vel_N"):
        a = np.asarray(getattr(gps, name), float)[valid]
        if not np.all(np.isfinite(a)):
            raise RecordingError(f"GPS field '{name}' has NaN/inf in fixes marked valid")
    return t


def declination_rad(lat_rad: float, lon_rad: float, h_m: float, year: float) -> float:
    """IGRF declination (rad, east positive) from pyIGRF."""
    import pyIGRF

    d, *_ = pyIGRF.igrf_value(math.degrees(lat_rad), math.degrees(lon_rad), h_m / 1000.0, year)
    return math.radians(d)


class IgrfDeclination:
    """IGRF declination D(φ, λ, h) (rad, east positive) along the route at decimal ``year``,
    cached on a ``cell_deg`` grid (0.01 deg ≈ 1 km: D changes by ~0.005 deg per km over the
    Netherlands, below the fluxgate's noise). Callable as ``D(lat_rad, lon_rad, h_m)``. The
    filter evaluates it at its own position at every magnetometer update: a constant D from the
    take-off point is 0.13 deg (mean) off over the default route (0.29 deg at the coast)."""

    def __init__(self, year: float, cell_deg: float = 0.01):
        self.year = float(year)
        self.cell_deg = float(cell_deg)
        self._cache: dict = {}

    def __call__(self, lat_rad: float, lon_rad: float, h_m: float) -> float:
        key = (round(math.degrees(lat_rad) / self.cell_deg), round(math.degrees(lon_rad) / self.cell_deg),
               round(h_m / 500.0))
        d = self._cache.get(key)
        if d is None:
            d = self._cache[key] = declination_rad(key[0] * self.cell_deg * math.pi / 180,
                                                   key[1] * self.cell_deg * math.pi / 180, key[2] * 500.0, self.year)
        return d


def mag_heading(B_B, roll, pitch, decl):
    """Heading (rad, from true north) of the field ``B_B`` (3,) levelled by roll and pitch:
    B_h = Ry(θ) Rx(φ) B_B;  ψ = atan2(−B_h,y, B_h,x) + D."""
    cr, sr, cp, sp = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch)
    bx = cp * B_B[0] + sp * sr * B_B[1] + sp * cr * B_B[2]
    by = cr * B_B[1] - sr * B_B[2]
    return math.atan2(-by, bx) + decl


def mag_heading_jacobian(C_NB, B_B) -> np.ndarray:
    """∂z/∂ψ (3,) of the magnetic-heading innovation z = ŷaw − ψ_m, where ψ_m is the heading of the
    field ``B_B`` (3,) levelled with the *estimated* roll and pitch (:func:`mag_heading`). With the
    levelled field B_N = Ĉ_NB B_B (north, east, down components B_n, B_e, B_d, H² = B_n² + B_e²):

        z = −ψ_d + (B_d / H²)(B_n ψ_n + B_e ψ_e) = −ψ_d + tan I (cos D ψ_n + sin D ψ_e)

    (I dip, D declination): the compass is levelled with the same tilt error the INS carries, so a
    tilt error about north shows as tan I (2.4 at 67 deg of dip) times itself in the heading.
    The INS yaw's own dependence on ψ_n, ψ_e cancels exactly against the levelling's."""
    B_N = np.asarray(C_NB, float) @ np.asarray(B_B, float)
    h2 = B_N[0] ** 2 + B_N[1] ** 2
    return np.array([B_N[2] * B_N[0] / h2, B_N[2] * B_N[1] / h2, -1.0])


def mag_corrected_field(B_m, theta) -> np.ndarray:
    """Field (3,) T corrected for the installation-error estimate ``theta`` (12,) = [b (3, T),
    ΔA (9, row-major)]: B̂ = (I + ΔA)⁻¹ (B_m − b), the inverse of B_m = (I + ΔA) B_B + b."""
    theta = np.asarray(theta, float)
    A = np.eye(3) + theta[3:].reshape(3, 3)
    return np.linalg.solve(A, np.asarray(B_m, float) - theta[:3])


def mag_iron_jacobian(B_m, theta, roll, pitch) -> np.ndarray:
    """∂z/∂θ̂ (12,) of the magnetic-heading innovation z = ŷaw − ψ_m(B̂) with respect to the
    installation-error estimate θ̂ = [b̂, ΔÂ] (:func:`mag_corrected_field`); the filter's error
    state is δθ = θ̂ − θ, so this is its H row. With the levelled field l = L B̂ (L: the rows of
    :func:`mag_heading`'s levelling by the estimated roll and pitch), ψ_m = atan2(−l_y, l_x) + D:

        ∂ψ_m/∂B̂ = Lᵀ [l_y, −l_x, 0] / (l_x² + l_y²)            (3,)  1/T
        ∂B̂/∂b̂ = −(I + ΔÂ)⁻¹,  ∂B̂/∂ΔÂ_ij = −(I + ΔÂ)⁻¹ e_i B̂_j
        g = ∂ψ_m/∂B̂ (I + ΔÂ)⁻¹:  H_b = g,  H_ΔA,ij = g_i B̂_j"""
    theta = np.asarray(theta, float)
    A = np.eye(3) + theta[3:].reshape(3, 3)
    Bc = np.linalg.solve(A, np.asarray(B_m, float) - theta[:3])
    cr, sr, cp, sp = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch)
    rx = np.array([cp, sp * sr, sp * cr])
    ry = np.array([0.0, cr, -sr])
    lx, ly = rx @ Bc, ry @ Bc
    dpsi_dB = (ly * rx - lx * ry) / (lx * lx + ly * ly)
    g = np.linalg.solve(A.T, dpsi_dB)
    return np.concatenate([g, np.outer(g, Bc).ravel()])


def mag_iron_hessian(B_m, theta, roll, pitch) -> np.ndarray:
    """∂²z/∂θ̂² (12, 12) of the magnetic-heading innovation (:func:`mag_iron_jacobian`), by central
    differences of the analytic Jacobian (steps 1 nT on b̂, 1e-5 on ΔÂ; symmetrised)."""
    theta = np.asarray(theta, float)
    steps = np.r_[np.full(3, 1e-9), np.full(9, 1e-5)]
    Hs = np.empty((12, 12))
    for i in range(12):
        d = np.zeros(12)
        d[i] = steps[i]
        Hs[i] = (mag_iron_jacobian(B_m, theta + d, roll, pitch) - mag_iron_jacobian(B_m, theta - d, roll, pitch)) / (2 * steps[i])
    return 0.5 * (Hs + Hs.T)


def mag_iron_prior_cov(hard_iron_max_T: float, soft_iron_max: float, misalignment_max_rad: float,
                       sensitivity_spread: float) -> np.ndarray:
    """Prior covariance (12, 12) of θ = [b, ΔA] for a fluxgate drawn as
    :meth:`imurig.sensors.magnetometer.FluxgateTriad.from_datasheet` draws it and read with its
    nominal sensitivity: B_m = D (S (I + M) B + b_h), D = diag(1 + d), d_i ~ U(±spread),
    S = I + (U + Uᵀ)/2, U_ij ~ U(±soft), M_ij ~ U(±mis) (i ≠ j), b_h,i ~ U(±hard). Hence
    b = D b_h: var = (1 + spread²/3) hard²/3; ΔA = D S (I + M) − I ≈ diag(d) + (S − I) + M:
    var ΔA_ii = spread²/3 + soft²/3, var ΔA_ij = soft²/6 + mis²/3, cov(ΔA_ij, ΔA_ji) = soft²/6
    (the symmetric soft iron). The second-order products (≤ soft·mis ≈ 2.5e-4 against σ ≈ 0.03)
    are left out."""
    P = np.zeros((12, 12))
    P[:3, :3] = np.eye(3) * (1 + sensitivity_spread ** 2 / 3) * hard_iron_max_T ** 2 / 3
    for i in range(3):
        for j in range(3):
            a = 3 + 3 * i + j
            if i == j:
                P[a, a] = sensitivity_spread ** 2 / 3 + soft_iron_max ** 2 / 3
            else:
                P[a, a] = soft_iron_max ** 2 / 6 + misalignment_max_rad ** 2 / 3
                P[a, 3 + 3 * j + i] = soft_iron_max ** 2 / 6
    return P


def attitude_reset_jacobian(psi_hat) -> np.ndarray:
    """G (3, 3) of the attitude error's reset when the estimate ``psi_hat`` (3,) rad is injected,
    C_new = exp([ψ̂×]) Ĉ. With the error defined by Ĉ = exp(−[ψ×]) C, BCH gives the error after the
    injection ψ' = ψ − ψ̂ + ½ ψ̂ × ψ + O(|ψ|³), so the covariance becomes G P Gᵀ with

        G = I + ½ [ψ̂×]

    Without it a large heading correction (the uncalibrated compass's ~4 deg, resolved by the
    first GPS velocities) leaves the tilt's correlation with the accelerometer biases rotated by
    the heading error: the biases' tilt then leaks into the final attitude (1.5 mrad on one IMU)."""
    return np.eye(3) + 0.5 * ins._skew(np.asarray(psi_hat, float))


class LooseEKF:
    """The loosely coupled error-state filter. ``run`` processes a whole flight."""

    def __init__(self, config: FilterConfig | None = None, noise: ImuNoise | None = None,
                 lever_gps_B=(0.0, 0.0, 0.0), declination=0.0):
        self.cfg = config or FilterConfig()
        self.noise = noise or ImuNoise()
        self.l_gps = np.asarray(lever_gps_B, float)
        self.decl = declination if callable(declination) else float(declination)
        if self.cfg.nav_rate_hz <= 0:
            raise ConfigError("nav_rate_hz must be positive")
        if self.cfg.gps_pos_tau_s is not None and not self.cfg.gps_pos_tau_s > 0:
            raise ConfigError(f"gps_pos_tau_s must be > 0 s, got {self.cfg.gps_pos_tau_s!r}")
        if self.cfg.mag_error_state and self.cfg.mag_iron_states:
            raise ConfigError("mag_error_state and mag_iron_states model the same compass error: choose one")
        if self.cfg.mag_iron_states:
            Pm = None if self.cfg.mag_iron_prior_cov is None else np.asarray(self.cfg.mag_iron_prior_cov, float)
            if Pm is None or Pm.shape != (12, 12) or not np.all(np.isfinite(Pm)) or np.any(np.linalg.eigvalsh(
                    0.5 * (Pm + Pm.T)) < 0):
                raise ConfigError("mag_iron_states needs mag_iron_prior_cov: a finite positive semi-definite "
                                  "(12, 12) covariance of [b (T), ΔA] (see ekf.mag_iron_prior_cov)")
        self._gps_gm_var = np.zeros(3)   # σ_GM² per NED axis of the receiver's correlated error (set by run)

    # ---------------------------------------------------------------------------- model
    def _F(self, x: ins.NavState, f_B, w_B, C, thermal=None):
        n = self.cfg.n_states
        F = np.zeros((n, n))
        lat, h, v = x.lat_rad, x.h_m, x.v_N
        w_ie, w_en, g, R_N, R_E = ins._rates(lat, h, v)
        w_in = w_ie + w_en
        f_N = C @ f_B
        sl, cl, tl = math.sin(lat), math.cos(lat), math.tan(lat)
        # δω_IE, δω_EN as functions of δr (via δlat = δr_n/(R_N+h)) and δv
        dwin_dr = np.zeros((3, 3))
        dwin_dr[:, 0] = np.array([-E.OMEGA_E_RAD_S * sl, 0.0,
                                  -E.OMEGA_E_RAD_S * cl - v[1] / (R_E + h) / cl ** 2]) / (R_N + h)
        dwie_dr = np.zeros((3, 3))
        dwie_dr[:, 0] = np.array([-E.OMEGA_E_RAD_S * sl, 0.0, -E.OMEGA_E_RAD_S * cl]) / (R_N + h)
        dwen_dv = np.array([[0.0, 1.0 / (R_E + h), 0.0],
                            [-1.0 / (R_N + h), 0.0, 0.0],
                            [0.0, -tl / (R_E + h), 0.0]])
        F[P, V] = np.eye(3)
        Sv = ins._skew(v)
        F[V, A] = ins._skew(f_N)
        F[V, BA] = -C
        F[V, TA] = -C * self.cfg.thermal_slope_m_s2_per_K
        F[V, V] = -ins._skew(2 * w_ie + w_en) + Sv @ dwen_dv
        F[V, P] = Sv @ (2 * dwie_dr + (dwin_dr - dwie_dr))
        F[V.start + 2, P.start + 2] += 2.0 * g[2] / (math.sqrt(R_N * R_E) + h)
        F[A, A] = -ins._skew(w_in)
        F[A, P] = dwin_dr
        F[A, V] = dwen_dv
        F[A, BG] = C
        if self.cfg.gyro_bias_gm_states:
            GM = self.cfg.gyro_gm_slice()
            F[A, GM] = C
            F[GM, GM] = -np.eye(3) / self.noise.gyro_bias_tau_s
        else:
            F[BG, BG] = -np.eye(3) / self.noise.gyro_bias_tau_s
        if self.cfg.estimate_scale_factors:
            F[V, SA] = -C * f_B
            F[A, SG] = C * w_B
        if self.cfg.estimate_misalignments:
            MA, MG = self.cfg.mis_slices()
            for p_, (i, j) in enumerate(MIS_PAIRS):
                F[V, MA.start + p_] = -C[:, i] * f_B[j]
                F[A, MG.start + p_] = C[:, i] * w_B[j]
        if self.cfg.estimate_nonlinearity:
            F[V, self.cfg.k2_slice()] = -C * f_B ** 2
        if self.cfg.estimate_thermal_terms and thermal is not None:
            dT, dh = thermal
            TH = self.cfg.thermal_slice()
            for p_, reg in enumerate((dT, f_B * dT, dh, f_B * dh)):
                F[V, TH.start + 3 * p_: TH.start + 3 * p_ + 3] = -C * reg
        if self.cfg.augment_gps:
            G = self.cfg.gps_slice()
            F[G, G] = -np.eye(3) / self.cfg.gps_pos_tau_s
        return F

    def _Qc(self):
        nz = self.noise
        q = np.zeros(self.cfg.n_states)
        q[V] = nz.vrw ** 2
        q[A] = nz.arw ** 2
        q[BA] = nz.acc_bias_rw ** 2
        if self.cfg.gyro_bias_gm_states:
            q[self.cfg.gyro_gm_slice()] = 2 * nz.gyro_bias_sigma ** 2 / nz.gyro_bias_tau_s
        else:
            q[BG] = 2 * nz.gyro_bias_sigma ** 2 / nz.gyro_bias_tau_s
        q[TA] = nz.temp_rw ** 2
        if self.cfg.estimate_scale_factors:
            q[SA] = q[SG] = nz.scale_rw ** 2
        if self.cfg.estimate_misalignments:
            MA, MG = self.cfg.mis_slices()
            q[MA] = q[MG] = nz.scale_rw ** 2
        if self.cfg.estimate_nonlinearity:
            q[self.cfg.k2_slice()] = 0.0
        if self.cfg.estimate_thermal_terms:
            q[self.cfg.thermal_slice()] = 0.0
        if self.cfg.augment_gps:
            q[self.cfg.gps_slice()] = 2.0 * self._gps_gm_var / self.cfg.gps_pos_tau_s
        return q

    def initial_covariance(self):
        c = self.cfg
        s = np.zeros(c.n_states)
        s[P] = c.sigma0_pos_m
        s[V] = c.sigma0_vel_m_s
        s[A] = [c.sigma0_tilt_rad, c.sigma0_tilt_rad, c.sigma0_heading_rad]
        s[BA] = c.sigma0_acc_bias_m_s2
        s[BG] = c.sigma0_gyro_bias_rad_s
        s[TA] = c.sigma0_temp_K
        if c.estimate_scale_factors:
            s[SA] = c.sigma0_acc_scale
            s[SG] = c.sigma0_gyro_scale
        if c.estimate_misalignments:
            MA, MG = c.mis_slices()
            s[MA] = c.sigma0_acc_misalignment_rad
            s[MG] = c.sigma0_gyro_misalignment_rad
        if c.estimate_nonlinearity:
            s[c.k2_slice()] = c.sigma0_acc_nonlinearity_s2_m
        if c.estimate_thermal_terms:
            s[c.thermal_slice()] = np.repeat(np.asarray(c.sigma0_acc_thermal, float), 3)
        if c.augment_gps:
            s[c.gps_slice()] = np.sqrt(self._gps_gm_var)
        if c.gyro_bias_gm_states:
            s[c.gyro_gm_slice()] = self.noise.gyro_bias_sigma
        if c.mag_error_state:
            s[c.mag_index()] = c.mag_error_sigma_rad
        P0 = np.diag(s ** 2)
        if c.mag_iron_states:
            MI = c.mag_iron_slice()
            P0[MI, MI] = np.asarray(c.mag_iron_prior_cov, float)
        return P0

    def alignment_covariance(self, x0: ins.NavState, f_B, B_B, gps, *, window_s: float,
                             sigma_mag_rad: float, sigma_level_f_m_s2: float | None = None) -> np.ndarray:
        """P0 (n, n) of a static alignment, by propagating the alignment's own errors.

        The alignment (:func:`imurig.flights.report.align`) levels with the mean specific force
        ``f_B`` (3,) m/s² over ``window_s`` s, takes the heading of the mean field ``B_B`` (3,)
        levelled with that roll and pitch, and position/velocity from the first valid fix (antenna
        minus the lever arm). Sources, independent, with the filter's own priors: the sensor-error
        states x_s (biases, scale factors, misalignments, temperatures, the receiver's Gauss-Markov
        error), the white noise of the levelling mean (σ_f = ``sigma_level_f_m_s2``, default
        VRW/√window), the compass's heading error e_m (σ ``sigma_mag_rad``), the fix's white error
        e_r and velocity error e_v. The filter's specific-force error is δf_B = J_f x_s (J_f = −I on
        δb_a, −diag(f) on δs_a, −e_i f_j on the misalignments, −diag(k_T) on δT_a), and levelling
        makes the horizontal part of Ĉ f̂ vanish, [f_N×]ψ = −C δf_B on the north and east rows:

            ψ_n = (C δf_B)_e / g,   ψ_e = −(C δf_B)_n / g          (tilt = −bias/g)
            ψ_d = h_n ψ_n + h_e ψ_e − e_m                           (z_mag = 0 at the alignment)
            δr = e_r − δb_gps − [(C l)×] ψ,   δv = e_v

        with h the magnetic-heading Jacobian (:func:`mag_heading_jacobian`, h_n = tan I cos D).
        P0 = A Σ Aᵀ: the tilt is fully correlated with the accelerometer errors, so the filter knows
        that a static IMU cannot tell them apart (see docs/flights-navigation.md)."""
        c = self.cfg
        n = c.n_states
        f_B = np.asarray(f_B, float)
        g = float(np.linalg.norm(f_B))
        C = E.C_from_q(x0.q_NB)
        valid = np.asarray(gps.valid, bool)
        i0 = int(np.flatnonzero(valid)[0])
        s_pos2 = np.asarray(gps.sigma_pos_N[i0], float) ** 2
        s_vel2 = np.asarray(gps.sigma_vel_N[i0], float) ** 2
        if c.augment_gps:
            s_w2 = np.minimum(np.asarray(c.gps_pos_sigma_white_N_m, float) ** 2, s_pos2)
            self._gps_gm_var = np.maximum(s_pos2 - s_w2, 0.0)
        else:
            s_w2 = s_pos2
        P_prior = self.initial_covariance()
        var = np.diag(P_prior).copy()
        if sigma_level_f_m_s2 is None:
            sigma_level_f_m_s2 = self.noise.vrw / math.sqrt(window_s)
        var[P] = s_w2
        var[V] = s_vel2
        var[A] = [(sigma_level_f_m_s2 / g) ** 2] * 2 + [sigma_mag_rad ** 2]
        Jf = np.zeros((3, n))
        Jf[:, BA] = -np.eye(3)
        Jf[:, TA] = -np.diag(np.asarray(c.thermal_slope_m_s2_per_K, float) * np.ones(3))
        if c.estimate_scale_factors:
            Jf[:, SA] = -np.diag(f_B)
        if c.estimate_misalignments:
            MA, _ = c.mis_slices()
            for p_, (i, j) in enumerate(MIS_PAIRS):
                Jf[i, MA.start + p_] = -f_B[j]
        if c.estimate_nonlinearity:
            Jf[:, c.k2_slice()] = -np.diag(f_B ** 2)
        Cf = C @ Jf
        Amap = np.eye(n)
        Amap[6] += Cf[1] / g
        Amap[7] -= Cf[0] / g
        h = mag_heading_jacobian(C, B_B)
        Amap[8] = h[0] * Amap[6] + h[1] * Amap[7] - np.eye(n)[8]
        if c.mag_error_state:           # ψ_m = ψ + e_m: z = hᵀψ + δe_m = 0, δe_m = ê_m − e_m = −e_m
            Amap[8, c.mag_index()] = 1.0
        if c.mag_iron_states:           # z = hᵀψ + H_θ δθ = 0 (θ̂ = 0 at the alignment)
            roll, pitch, _ = E.euler_from_C(C)
            MI = c.mag_iron_slice()
            Amap[8, MI] = mag_iron_jacobian(B_B, np.zeros(12), roll, pitch)
            # the heading is quadratic in θ at the priors' size: the part of the alignment's heading
            # error that is not H_θ δθ has variance ½ tr(Hs P Hs P) (as in the compass update)
            HP = mag_iron_hessian(B_B, np.zeros(12), roll, pitch) @ P_prior[MI, MI]
            var[8] += 0.5 * float(np.sum(HP * HP.T))
        Cl = C @ self.l_gps
        Amap[P] -= ins._skew(Cl) @ Amap[A]
        if c.augment_gps:
            Amap[P, c.gps_slice()] -= np.eye(3)
        Sig = np.diag(var)
        if c.mag_iron_states:     # the iron states' prior is correlated (symmetric soft iron)
            MI = c.mag_iron_slice()
            Sig[MI, MI] = P_prior[MI, MI]
        P0 = Amap @ Sig @ Amap.T
        # second order: the levelling fixes the tilt in the body frame; mapped to NED with the
        # compass's heading (error ψ_d) the linear map above carries an extra −½ ψ_d e_z × ψ_tilt
        # (BCH of the heading and tilt rotations). Its variance (Isserlis, zero-mean Gaussians),
        # uncorrelated with the linear terms: ¼ J (σ_d² Σ_tt + 2 c cᵀ) Jᵀ, J = [[0, −1], [1, 0]],
        # c = cov(ψ_tilt, ψ_d)
        Jz = np.array([[0.0, -1.0], [1.0, 0.0]])
        cz = P0[6:8, 8]
        P0[6:8, 6:8] += 0.25 * Jz @ (P0[8, 8] * P0[6:8, 6:8] + 2.0 * np.outer(cz, cz)) @ Jz.T
        return P0

    # ---------------------------------------------------------------------------- run
    def run(self, imu: ImuStream, gps, x0: ins.NavState, *, P0=None, progress=None) -> FilterResult:
        """Process the IMU stream from ``x0`` at ``imu.time_s[0]``, with GPS fixes ``gps``
        (GpsFixes-like). ``progress`` (optional) is called with the number of epochs done."""
        c = self.cfg
        t_imu = _check_stream(imu)
        fs = 1.0 / float(np.median(np.diff(t_imu)))
        K = max(1, round(fs / c.nav_rate_hz))
        if gps is not None:
            check_gps(gps, fs)
        inc = ins.preintegrate(t_imu, imu.w_IB_B, imu.f_B, K, samples=getattr(imu, "samples", "held"))
        T = inc.T_s
        M = inc.dtheta_B.shape[0]
        idx = np.arange(M + 1) * K
        w_mean = np.asarray(imu.w_IB_B)[idx]        # rates at the epochs (for F and lever arms)
        f_mean = np.asarray(imu.f_B)[idx]
        f2_mean = None
        if c.estimate_nonlinearity:                  # mean of f² over each step's K samples (held)
            f2_mean = np.square(np.asarray(imu.f_B, float)[: M * K]).reshape(M, K, 3).mean(axis=1)
        n = c.n_states
        G = c.gps_slice() if c.augment_gps else None
        s_w2 = np.asarray(c.gps_pos_sigma_white_N_m, float) ** 2
        valid_g = np.zeros(0, bool)
        if gps is not None:
            valid_g = np.asarray(gps.valid, bool)
            if G is not None and np.any(valid_g):
                s2_first = np.asarray(gps.sigma_pos_N, float)[np.flatnonzero(valid_g)[0]] ** 2
                self._gps_gm_var = np.maximum(s2_first - s_w2, 0.0)
        Pm = self.initial_covariance() if P0 is None else np.array(P0, float)
        if Pm.shape != (n, n):
            raise ConfigError(f"P0 has shape {Pm.shape}, the filter has {n} states ({', '.join(c.state_names())})")
        qc = self._Qc()
        bgps = np.zeros(3)          # estimate of the receiver's Gauss-Markov position error, NED m
        emag = 0.0                  # estimate of the compass's systematic heading error, rad
        theta_m = np.zeros(12)      # estimate of the magnetometer's installation errors [b (T), ΔA]
        MI = c.mag_iron_slice() if c.mag_iron_states else None
        mag_consider = None
        if MI is not None and c.mag_consider_states:
            upd = np.zeros(n, bool)
            upd[A.start + 2] = True          # ψ_d, the heading
            upd[BG] = True
            upd[MI] = True
            if c.gyro_bias_gm_states:
                upd[c.gyro_gm_slice()] = True
            mag_consider = ~upd
        phi_gps = math.exp(-inc.T_s / c.gps_pos_tau_s) if G is not None else 1.0
        x = x0.copy()
        ba = np.zeros(3)
        bg = np.zeros(3)           # gyro bias estimate (turn-on + Gauss-Markov parts), rad/s
        bgm = np.zeros(3)          # its Gauss-Markov part, when c.gyro_bias_gm_states
        GM = c.gyro_gm_slice() if c.gyro_bias_gm_states else None
        phi_bgm = math.exp(-inc.T_s / self.noise.gyro_bias_tau_s)
        sa = np.zeros(3)
        sg = np.zeros(3)
        Ma = np.zeros((3, 3))      # misalignment estimates (zero diagonal): f = (I − diag(s) − M) f_in
        Mg = np.zeros((3, 3))
        k2 = np.zeros(3)           # accelerometer nonlinearity estimate, s²/m
        K2 = c.k2_slice()
        TH = c.thermal_slice()
        th = np.zeros(12)          # thermal-term estimates (k_T, s_T, H_b, H_s per axis)
        dT_ep = dh_ep = None
        if c.estimate_thermal_terms:
            if imu.T_acc_K is None:
                raise ConfigError("estimate_thermal_terms needs the accelerometer temperature channels (T_acc_K)")
            from imurig.sensors.thermal import hysteresis_state

            Tacc = np.asarray(imu.T_acc_K, float)
            hacc = np.stack([hysteresis_state(Tacc[:, j], c.hysteresis_width_K, fs) for j in range(3)], 1)
            # step means over each navigation interval, relative to the first step (the alignment)
            dT_ep = Tacc[: M * K].reshape(M, K, 3).mean(axis=1)
            dh_ep = hacc[: M * K].reshape(M, K, 3).mean(axis=1)
            dT_ep = dT_ep - dT_ep[0]
            dh_ep = dh_ep - dh_ep[0]
        MA, MG = c.mis_slices()
        mis_i = tuple(i for i, _ in MIS_PAIRS)
        mis_j = tuple(j for _, j in MIS_PAIRS)
        Tm = None if imu.T_acc_K is None else np.asarray(imu.T_acc_K, float)
        Ta = np.full(3, c.reference_temperature_K) if Tm is None else Tm[0].copy()
        kT = np.asarray(c.thermal_slope_m_s2_per_K, float)
        I_n = np.eye(n)

        # measurement schedules: epoch index at which each fix/sample is used
        ups = {k: {"time_s": [], "nis": [], "dof": [], "innovation": []} for k in ("gps_pos", "gps_vel", "mag", "temp")}
        gps_use = []
        gps_used = False       # a fix has been used (the receiver's correlated error is then re-drawn after a gap)
        if gps is not None:
            tg = np.asarray(gps.time_s, float)
            ok = np.asarray(gps.valid, bool) & (tg >= inc.t_s[0]) & (tg + c.gps_latency_s <= inc.t_s[-1])
            use_at = np.ceil((tg + c.gps_latency_s - inc.t_s[0]) / T - 1e-9).astype(int)
            gps_use = {int(e): [] for e in use_at[ok]}
            gm_inflation = 1.0
            if c.gps_pos_tau_s is not None and tg.size > 1:
                phi_g = math.exp(-float(np.median(np.diff(tg))) / c.gps_pos_tau_s)
                gm_inflation = (1.0 + phi_g) / (1.0 - phi_g)
            for i in np.flatnonzero(ok):
                gps_use[int(use_at[i])].append(int(i))
        mag_every = max(1, round(c.nav_rate_hz / c.mag_rate_hz)) if (c.use_magnetometer and imu.B_B is not None) else 0
        temp_every = max(1, round(c.nav_rate_hz / c.temp_rate_hz)) if Tm is not None else 0

        out_lat = np.empty(M + 1)
        out_lon = np.empty(M + 1)
        out_h = np.empty(M + 1)
        out_v = np.empty((M + 1, 3))
        out_q = np.empty((M + 1, 4))
        out_ba = np.empty((M + 1, 3))
        out_bg = np.empty((M + 1, 3))
        out_T = np.empty((M + 1, 3))
        out_sa = np.empty((M + 1, 3))
        out_sg = np.empty((M + 1, 3))
        out_Pd = np.empty((M + 1, n))
        out_Pn = np.empty((M + 1, 9, 9))
        hist_lat = out_lat
        hist_lon = out_lon
        hist_h = out_h
        hist_v = out_v

        def inject(dx):
            nonlocal ba, bg, bgm, Ta, sa, sg, x, bgps, Ma, Mg, emag, k2, th, theta_m, Pm
            _w_ie, _w_en, _g, R_N, R_E = ins._rates(x.lat_rad, x.h_m, x.v_N)
            lat = x.lat_rad - dx[0] / (R_N + x.h_m)
            lon = x.lon_rad - dx[1] / ((R_E + x.h_m) * math.cos(x.lat_rad))
            h = x.h_m + dx[2]
            v = x.v_N - dx[V]
            q = ins._qmul(ins._qrot(dx[A]), x.q_NB)
            q /= math.sqrt(float(q @ q))
            x = ins.NavState(lat, lon, h, v, q)
            # reset Jacobian (:func:`attitude_reset_jacobian`): P ← G P Gᵀ
            Gr = attitude_reset_jacobian(dx[A])
            Pm[A, :] = Gr @ Pm[A, :]
            Pm[:, A] = Pm[:, A] @ Gr.T
            ba = ba - dx[BA]
            bg = bg - dx[BG]
            if GM is not None:
                bg = bg - dx[GM]
                bgm = bgm - dx[GM]
            Ta = Ta - dx[TA]
            if c.estimate_scale_factors:
                sa = sa - dx[SA]
                sg = sg - dx[SG]
            if c.estimate_misalignments:
                Ma = Ma.copy()
                Mg = Mg.copy()
                Ma[mis_i, mis_j] -= dx[MA]
                Mg[mis_i, mis_j] -= dx[MG]
            if c.estimate_nonlinearity:
                k2 = k2 - dx[K2]
            if c.estimate_thermal_terms:
                th = th - dx[TH]
            if G is not None:
                bgps = bgps - dx[G]
            if c.mag_error_state:
                emag = emag - dx[c.mag_index()]
            if MI is not None:
                theta_m = theta_m - dx[MI]

        def update(kind, tk, z, H, R):
            nonlocal Pm
            S = H @ Pm @ H.T + R
            Sinv = np.linalg.inv(S)
            Kg = Pm @ H.T @ Sinv
            dx = Kg @ z
            IKH = I_n - Kg @ H
            Pm = IKH @ Pm @ IKH.T + Kg @ R @ Kg.T
            u = ups[kind]
            u["time_s"].append(tk)
            u["nis"].append(float(z @ Sinv @ z))
            u["dof"].append(int(z.size))
            u["innovation"].append(z.copy())
            inject(dx)

        for k in range(M + 1):
            tk = inc.t_s[k]
            C = ins._dcm(x.q_NB)
            # --- measurement updates at epoch k
            if gps is not None and k in gps_use:
                for i in gps_use[k]:
                    lag = tk - gps.time_s[i]
                    # INS history at the tag (linear interpolation between epochs)
                    s = (gps.time_s[i] - inc.t_s[0]) / T
                    j = min(math.floor(s), k)
                    a = s - j
                    j1 = min(j + 1, k)
                    lat_t = (1 - a) * hist_lat[j] + a * (hist_lat[j1] if j1 < k else x.lat_rad)
                    lon_t = (1 - a) * hist_lon[j] + a * (hist_lon[j1] if j1 < k else x.lon_rad)
                    h_t = (1 - a) * hist_h[j] + a * (hist_h[j1] if j1 < k else x.h_m)
                    v_t = (1 - a) * hist_v[j] + a * (hist_v[j1] if j1 < k else x.v_N)
                    if j == k:
                        lat_t, lon_t, h_t, v_t = x.lat_rad, x.lon_rad, x.h_m, x.v_N
                    dv_hist = v_t - x.v_N          # history offset, kept across the position update
                    Cl = C @ self.l_gps
                    r_ant = E.ned_from_geodetic(lat_t, lon_t, h_t, gps.lat_rad[i], gps.lon_rad[i], gps.h_m[i])
                    z = np.asarray(r_ant, float) + Cl
                    H = np.zeros((3, n))
                    H[:, P] = np.eye(3)
                    H[:, V] = -lag * np.eye(3)
                    H[:, A] = ins._skew(Cl)
                    s2 = np.asarray(gps.sigma_pos_N[i], float) ** 2
                    if G is not None:
                        # the correlated part is a state: re-started (receiver re-acquired) after a gap
                        self._gps_gm_var = np.maximum(s2 - s_w2, 0.0)
                        qc[G] = 2.0 * self._gps_gm_var / c.gps_pos_tau_s
                        if gps_used and not valid_g[i - 1]:
                            bgps = np.zeros(3)
                            Pm[G, :] = 0.0
                            Pm[:, G] = 0.0
                            Pm[G, G] = np.diag(self._gps_gm_var)
                        z = z + bgps
                        H[:, G] = np.eye(3)
                        s2 = np.minimum(s_w2, s2)
                    elif c.gps_pos_tau_s is not None:
                        s2 = np.minimum(s_w2, s2) + np.maximum(s2 - s_w2, 0.0) * gm_inflation
                    R = np.diag(c.gps_sigma_scale ** 2 * s2)
                    if c.gps_time_sigma_s > 0:
                        vg = np.asarray(gps.v_N[i], float)
                        R = R + c.gps_time_sigma_s ** 2 * np.outer(vg, vg)
                    update("gps_pos", tk, z, H, R)
                    gps_used = True
                    if c.use_gps_velocity:
                        C = ins._dcm(x.q_NB)
                        w_ie, w_en, *_ = ins._rates(x.lat_rad, x.h_m, x.v_N)
                        w_nb = (w_mean[k] - bg) - C.T @ (w_ie + w_en)
                        lv = C @ np.cross(w_nb, self.l_gps)
                        z = x.v_N + dv_hist + lv - np.asarray(gps.v_N[i], float)
                        H = np.zeros((3, n))
                        H[:, V] = np.eye(3)
                        H[:, A] = ins._skew(lv)
                        H[:, BG] = C @ ins._skew(self.l_gps)
                        if GM is not None:
                            H[:, GM] = H[:, BG]
                        R = np.diag((c.gps_sigma_scale * np.asarray(gps.sigma_vel_N[i], float)) ** 2)
                        if c.gps_time_sigma_s > 0:
                            # time-of-validity error δt: the fix's velocity is off by a_N δt
                            w_ie_, w_en_, g_n, *_ = ins._rates(x.lat_rad, x.h_m, x.v_N)
                            a_n = C @ f_mean[k] + g_n - np.cross(2.0 * w_ie_ + w_en_, x.v_N)
                            R = R + c.gps_time_sigma_s ** 2 * np.outer(a_n, a_n)
                        update("gps_vel", tk, z, H, R)
                    C = ins._dcm(x.q_NB)
            if mag_every and k % mag_every == 0:
                decl = self.decl(x.lat_rad, x.lon_rad, x.h_m) if callable(self.decl) else self.decl
                B_m = np.asarray(imu.B_B[idx[k]], float)

                def mag_model(q, th, B_m=B_m, decl=decl, P_prior=Pm, emag=emag):
                    """Innovation z (1,), its H row (1, n) and R (1, 1) at attitude q, iron estimate th."""
                    Cq = ins._dcm(q)
                    roll, pitch, yaw = E.euler_from_C(Cq)
                    B_c = B_m if MI is None else mag_corrected_field(B_m, th)
                    z = np.array([E.wrap_pi(yaw - mag_heading(B_c, roll, pitch, decl))])
                    H = np.zeros((1, n))
                    H[0, A] = mag_heading_jacobian(Cq, B_c)
                    Rm = c.mag_heading_sigma_rad ** 2
                    if MI is not None:
                        H[0, MI] = mag_iron_jacobian(B_m, th, roll, pitch)
                        # Gaussian second-order filter: the heading is quadratic in the iron errors
                        # at the size of the priors (5 % and 2000 nT: ~0.5 deg, 30x the white part),
                        # so E[z] = −½ tr(Hs P) and var += ½ tr(Hs P Hs P) (P: the iron block)
                        Hs = mag_iron_hessian(B_m, th, roll, pitch)
                        HP = Hs @ P_prior[MI, MI]
                        z = z + 0.5 * np.trace(HP)
                        Rm = Rm + 0.5 * float(np.sum(HP * HP.T))
                    if c.mag_error_state:
                        z = z + emag
                        H[0, c.mag_index()] = 1.0
                    return z, H, np.array([[Rm]])

                z, H, Rm = mag_model(x.q_NB, theta_m)
                if MI is None or (c.mag_iterations <= 1 and mag_consider is None):
                    update("mag", tk, z, H, Rm)
                else:
                    # iterated EKF (Gauss-Newton to the MAP): relinearise at the corrected attitude
                    # and iron estimate, e_{i+1} = K_i (z(x_i) + H_i e_i); NIS from the prior's linearisation
                    S0 = float((H @ Pm @ H.T + Rm)[0, 0])
                    nis0 = float(z[0] ** 2 / S0)
                    e = np.zeros(n)
                    zi, Hi, Ri = z, H, Rm
                    for _it in range(c.mag_iterations):
                        Kg = Pm @ Hi.T / float((Hi @ Pm @ Hi.T + Ri)[0, 0])
                        if mag_consider is not None:
                            Kg[mag_consider] = 0.0
                        e = (Kg @ (zi + Hi @ e)).ravel()
                        if _it == c.mag_iterations - 1:
                            break
                        qi = ins._qmul(ins._qrot(e[A]), x.q_NB)
                        qi = qi / math.sqrt(float(qi @ qi))
                        zi, Hi, Ri = mag_model(qi, theta_m - e[MI])
                    IKH = I_n - Kg @ Hi
                    Pm = IKH @ Pm @ IKH.T + Kg @ Ri @ Kg.T
                    u = ups["mag"]
                    u["time_s"].append(tk)
                    u["nis"].append(nis0)
                    u["dof"].append(1)
                    u["innovation"].append(z.copy())
                    inject(e)
                C = ins._dcm(x.q_NB)
            if temp_every and k % temp_every == 0:
                z = Ta - Tm[idx[k]]
                H = np.zeros((3, n))
                H[:, TA] = np.eye(3)
                update("temp", tk, z, H, np.eye(3) * c.temp_sigma_K ** 2)
            # --- record
            out_lat[k], out_lon[k], out_h[k], out_v[k], out_q[k] = x.lat_rad, x.lon_rad, x.h_m, x.v_N, x.q_NB
            out_ba[k], out_bg[k], out_T[k], out_sa[k], out_sg[k] = ba, bg, Ta, sa, sg
            out_Pd[k] = np.diag(Pm)
            out_Pn[k] = Pm[:9, :9]
            if k == M:
                break
            # --- propagate to epoch k+1 on corrected increments
            fB = f_mean[k]
            wB = w_mean[k]
            dth = (inc.dtheta_B[k] - bg * T) * (1.0 - sg)
            f_corr = ba + kT * (Ta - c.reference_temperature_K)
            dv = (inc.dv_B[k] - f_corr * T) * (1.0 - sa)
            if c.estimate_nonlinearity:
                dv = dv - k2 * f2_mean[k] * T
            thermal = None
            if c.estimate_thermal_terms:
                f_st = inc.dv_B[k] / T
                thermal = (dT_ep[k], dh_ep[k])
                dv = dv - (th[0:3] * dT_ep[k] + th[3:6] * f_st * dT_ep[k] + th[6:9] * dh_ep[k]
                           + th[9:12] * f_st * dh_ep[k]) * T
            if c.estimate_misalignments:
                dth = dth - Mg @ dth
                dv = dv - Ma @ dv
            F = self._F(x, (fB - f_corr) * (1 - sa), (wB - bg) * (1 - sg), C, thermal)
            x = ins.nav_step(x, dth, dv, T)
            bgps = bgps * phi_gps
            if GM is not None:          # the expected Gauss-Markov part decays with τ
                bg = bg - bgm * (1.0 - phi_bgm)
                bgm = bgm * phi_bgm
            FT = F * T
            Phi = I_n + FT + 0.5 * FT @ FT
            Qd = 0.5 * (Phi * qc) @ Phi.T * T + 0.5 * np.diag(qc) * T
            if c.mag_error_state:
                # Gauss-Markov in the body's rotation angle relative to NED over the step
                w_ie_, w_en_, *_ = ins._rates(x.lat_rad, x.h_m, x.v_N)
                dang = float(np.linalg.norm(dth - C.T @ (w_ie_ + w_en_) * T))
                phm = math.exp(-dang / c.mag_error_corr_rad)
                im = c.mag_index()
                Phi[im, :] = 0.0
                Phi[im, im] = phm
                Qd[im, :] = 0.0
                Qd[:, im] = 0.0
                Qd[im, im] = c.mag_error_sigma_rad ** 2 * (1.0 - phm ** 2)
                emag *= phm
            Pm = Phi @ Pm @ Phi.T + Qd
            if progress is not None and k % 500 == 0:
                progress(k)
        ups = {k: {"time_s": np.asarray(u["time_s"]), "nis": np.asarray(u["nis"]), "dof": np.asarray(u["dof"]),
                   "innovation": u["innovation"]} for k, u in ups.items()}
        return FilterResult(inc.t_s, out_lat, out_lon, out_h, out_v, out_q, out_ba, out_bg, out_T, out_sa, out_sg,
                            out_Pd, out_Pn, c.state_names(), ups,
                            meta={"nav_rate_hz": 1.0 / T, "imu_rate_hz": fs, "samples_per_step": K,
                                  "misalignment_acc_rad": Ma.tolist(), "misalignment_gyro_rad": Mg.tolist(),
                                  "nonlinearity_acc_s2_m": k2.tolist(), "thermal_terms_acc": th.tolist(),
                                  "gyro_bias_gm_rad_s": bgm.tolist(),
                                  "mag_hard_iron_T": theta_m[:3].tolist(),
                                  "mag_matrix_error": theta_m[3:].reshape(3, 3).tolist()})


def nees_nav(res: FilterResult, truth, idx) -> np.ndarray:
    """NEES (M,) of the 9 navigation error states (δr, δv, ψ) against ``truth`` at indices
    ``idx`` (M,): e = [r_est − r_true (NED m), v_est − v_true, ψ]; NEES = eᵀ P⁻¹ e (dof 9)."""
    sol = ins.NavSolution(res.time_s, res.lat_rad, res.lon_rad, res.h_m, res.v_N, res.q_NB)
    err = ins.nav_errors(sol, truth, idx)
    e = np.concatenate([err["pos_N_m"], err["vel_N_m_s"], err["att_N_rad"]], axis=1)
    return np.einsum("ni,ni->n", e, np.linalg.solve(res.P_nav, e[..., None])[..., 0])


# --- synthetic sensors matching the filter's model (consistency studies) ---------------------------
@dataclass
class SimpleGps:
    """GpsFixes-compatible container (same field names) for synthetic fixes."""

    time_s: np.ndarray
    lat_rad: np.ndarray
    lon_rad: np.ndarray
    h_m: np.ndarray
    v_N: np.ndarray
    sigma_pos_N: np.ndarray
    sigma_vel_N: np.ndarray
    mode: str = "synthetic"
    valid: np.ndarray | None = None
    meta: dict | None = None

    def __post_init__(self):
        if self.valid is None:
            self.valid = np.ones(self.time_s.size, bool)


def synthetic_sensors(truth, noise: ImuNoise, rng: np.random.Generator, *, acc_bias_m_s2=None,
                      gyro_bias_rad_s=None, gps_rate_hz=1.0, gps_sigma_pos_m=(0.5, 0.5, 1.0),
                      gps_sigma_vel_m_s=(0.05, 0.05, 0.1), lever_gps_B=(0.0, 0.0, 0.0), mag_sigma_rad=0.0,
                      T_acc_K=T_REF_K, temp_sigma_K=0.05, outages=()):
    """IMU, GPS, magnetometer and temperature data drawn from exactly the filter's error model.

    w = w_IB_B + b_g + GM(σ, τ) + ARW;  f = f_B + b_a + VRW  (white, per sample σ = density √fs);
    GPS antenna position/velocity + white noise at ``gps_rate_hz`` (invalid inside ``outages``
    ((t0, t1), ...)); B_B = C_BN [cos D, sin D, tan I]·|B_h| with a heading noise of σ_mag;
    temperature channels = T_acc_K + white noise. Returns (ImuStream, SimpleGps, true biases).
    """
    t = truth.time_s
    n = t.size
    fs = truth.rate_hz
    ba = rng.normal(0, 0.05, 3) if acc_bias_m_s2 is None else np.asarray(acc_bias_m_s2, float)
    bg = rng.normal(0, 0.003 * math.pi / 180, 3) if gyro_bias_rad_s is None else np.asarray(gyro_bias_rad_s, float)
    phi = math.exp(-1.0 / (noise.gyro_bias_tau_s * fs))
    from scipy.signal import lfilter

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
    gps = SimpleGps(t[gi].copy(), lat, lon, h, v, sp, sv, valid=valid)
    return ImuStream(t, w, f, B_B, Tm, samples=ins.sample_semantics(truth)), gps, {"acc_bias_m_s2": ba,
                                                                                 "gyro_bias_rad_s": bg}
