"""Honeywell Q-Flex QA700 accelerometer triad (seed appendix A.1), and its temperature sensors.

Measurement equation, per sample n and axis i (SI inside):

    a_S  = (I + M) f_C                                   [m/s^2, (n,3)] sensed along the input axes
    a_i' = a_S,i + b_i + k2_i a_S,i^2 + sum_k kb_ik (T - T0)^k + Hb_i h   [m/s^2]
    I_i  = K1_i (1 + ks_i (T - T0) + Hs_i h) a_i' + i_noise              [A]
    V_i  = R_L,i I_i                                     [V]  voltage over the load resistor

f_C: true specific force in the IMU case frame C. M: input-axis misalignment (zero
diagonal, rad). b: bias (m/s^2). k2: second-order nonlinearity (1/(m/s^2)). K1: current
scale factor (A per m/s^2). kb_ik (k = 1..3): bias temperature polynomial (m/s^2/K^k);
ks: scale-factor temperature coefficient (1/K). Hb, Hs: bias (m/s^2) and scale-factor (-)
thermal hysteresis: the gap between the heating and cooling branches; h in [-1/2, 1/2] is
the hysteresis state of :func:`imurig.sensors.thermal.hysteresis_state`. T: the
accelerometer's own temperature (K).
i_noise: output current noise in the datasheet's three bands.

Lever arm: the triad senses at r_C (``position_C_m``, m, case frame) from the case reference
point where the rig gives f_C; rigid-body kinematics add (the chain's
:class:`imurig.sensors.effects.lever_arm.LeverArm` with r_C = ``position_C_m``)

    f_C(r) = f_C + dw/dt x r_C + w x (w x r_C)           [m/s^2, (n,3)],  w = w_C (rad/s)

M, k2 and kb_i1 are the sensor-stage effects axis_misalignment, scale_nonlinearity and
temperature_drift of :mod:`imurig.sensors.effects` (:meth:`QFlexTriad.sensor_effects`): the triad
injects them; the effect objects own their diagnosis and truth maps.

Datasheet units (mA/g, ug, ug/g^2, ppm/C, mrad) appear only in ``from_datasheet``.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from imurig.kernel.units import G_STANDARD, T_REF_K
from imurig.sensors.effects.axis_misalignment import AxisMisalignment
from imurig.sensors.effects.lever_arm import LeverArm
from imurig.sensors.effects.lever_arm import lever_arm_specific_force  # noqa: F401  (its home: the effect)
from imurig.sensors.effects.scale_nonlinearity import ScaleNonlinearity
from imurig.sensors.effects.temperature_drift import TemperatureDrift
from imurig.sensors.effects.temperature_hysteresis import K1_NOMINAL_A_PER_M_S2
from imurig.sensors.effects.current_noise import CurrentNoise

AXES = ("x", "y", "z")


def _vec(x) -> np.ndarray:
    return np.broadcast_to(np.asarray(x, float), (3,)).copy()


def _times(c, x, out):
    """c * x, into ``out`` where the product has its shape (and ``out`` is given), else a new array."""
    if out is not None and np.broadcast_shapes(np.shape(c), np.shape(x)) == out.shape:
        return np.multiply(c, x, out=out)
    return c * x


def _plus(g, t):
    """g + t, in place where g (an array of this computation's own) already has the sum's shape."""
    if np.broadcast_shapes(g.shape, np.shape(t)) == g.shape:
        g += t
        return g
    return g + t


@dataclass
class QFlexTriad:
    """Three QA700 accelerometers with their load resistors (parameters in SI)."""

    bias_m_s2: np.ndarray = field(default_factory=lambda: np.zeros(3))
    k1_A_per_m_s2: np.ndarray = field(default_factory=lambda: np.full(3, K1_NOMINAL_A_PER_M_S2))
    misalignment_rad: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    k2_per_m_s2: np.ndarray = field(default_factory=lambda: np.zeros(3))
    bias_tempco_m_s2_per_K: np.ndarray = field(default_factory=lambda: np.zeros(3))
    bias_tempco2_m_s2_per_K2: np.ndarray = field(default_factory=lambda: np.zeros(3))
    bias_tempco3_m_s2_per_K3: np.ndarray = field(default_factory=lambda: np.zeros(3))
    scale_tempco_per_K: np.ndarray = field(default_factory=lambda: np.zeros(3))
    bias_hysteresis_m_s2: np.ndarray = field(default_factory=lambda: np.zeros(3))
    scale_hysteresis: np.ndarray = field(default_factory=lambda: np.zeros(3))
    hysteresis_width_K: float = 4.0
    load_resistor_ohm: np.ndarray = field(default_factory=lambda: np.full(3, 750.0))
    noise_bands: tuple = ((0.0, 10.0, 10e-9), (10.0, 500.0, 100e-9), (500.0, 10e3, 2e-6))
    reference_temperature_K: float = T_REF_K
    noise_enabled: bool = True
    #: where the triad senses, relative to the case reference point (the rig's 'imu' site), in C (m)
    position_C_m: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self):
        for name in ("bias_m_s2", "k1_A_per_m_s2", "k2_per_m_s2", "bias_tempco_m_s2_per_K",
                     "bias_tempco2_m_s2_per_K2", "bias_tempco3_m_s2_per_K3", "scale_tempco_per_K",
                     "bias_hysteresis_m_s2", "scale_hysteresis", "load_resistor_ohm", "position_C_m"):
            setattr(self, name, _vec(getattr(self, name)))
        self.misalignment_rad = np.asarray(self.misalignment_rad, float).reshape(3, 3).copy()
        np.fill_diagonal(self.misalignment_rad, 0.0)

    # ------------------------------------------------------------ datasheet
    @classmethod
    def from_datasheet(cls, rng: np.random.Generator | None = None, *, scale_factor_mA_per_g=1.33,
                       scale_factor_spread=0.01, bias_max_ug=8000.0, misalignment_max_mrad=2.0,
                       nonlinearity_max_ug_per_g2=48.0, bias_tempco_max_ug_per_C=70.0,
                       scale_tempco_max_ppm_per_C=200.0, bias_hysteresis_max_ug=1000.0,
                       scale_hysteresis_max_ppm=1000.0, load_resistor_ohm=750.0,
                       noise_nA_rms=(10.0, 100.0, 2000.0)) -> "QFlexTriad":
        """A triad in datasheet units; with ``rng``, each error is drawn uniformly within its limit.

        ``scale_factor_spread`` is the relative spread of K1 about its data-sheet value (the
        lab converts with the nominal value, so the calibration sees 1 +- spread).
        Without ``rng`` the triad is ideal apart from its nominal scale factor and noise.
        """
        g = G_STANDARD
        bands = ((0.0, 10.0, noise_nA_rms[0] * 1e-9), (10.0, 500.0, noise_nA_rms[1] * 1e-9),
                 (500.0, 10e3, noise_nA_rms[2] * 1e-9))
        k1 = np.full(3, scale_factor_mA_per_g * 1e-3 / g)
        if rng is None:
            return cls(k1_A_per_m_s2=k1, load_resistor_ohm=np.full(3, load_resistor_ohm), noise_bands=bands)
        u = lambda lim, shape=3, r=rng: r.uniform(-lim, lim, size=shape)  # noqa: E731
        base = dict(
            bias_m_s2=u(bias_max_ug * 1e-6 * g),
            k1_A_per_m_s2=k1 * (1 + u(scale_factor_spread)),
            misalignment_rad=u(misalignment_max_mrad * 1e-3, (3, 3)),
            k2_per_m_s2=u(nonlinearity_max_ug_per_g2 * 1e-6 / g),
            bias_tempco_m_s2_per_K=u(bias_tempco_max_ug_per_C * 1e-6 * g),
            scale_tempco_per_K=u(scale_tempco_max_ppm_per_C * 1e-6),
        )
        # the thermal-curvature and hysteresis draws come from a spawned generator, so they do
        # not shift the stream the other sensors of a lab draw from
        t = rng.spawn(1)[0]
        base.update(
            # curvature: up to 20 % (quadratic) and 10 % (cubic) of the linear tempco's change over +-50 K
            bias_tempco2_m_s2_per_K2=u(0.2 * bias_tempco_max_ug_per_C * 1e-6 * g / 50, r=t),
            bias_tempco3_m_s2_per_K3=u(0.1 * bias_tempco_max_ug_per_C * 1e-6 * g / 50**2, r=t),
            bias_hysteresis_m_s2=t.uniform(0.2, 1.0, 3) * bias_hysteresis_max_ug * 1e-6 * g,
            scale_hysteresis=t.uniform(0.2, 1.0, 3) * scale_hysteresis_max_ppm * 1e-6,
        )
        return cls(load_resistor_ohm=np.full(3, load_resistor_ohm), noise_bands=bands, **base)

    # ------------------------------------------------------------- effects
    def sensor_effects(self) -> tuple:
        """The sensor-stage effects this triad injects, with its parameters (stage "sensor")."""
        return (AxisMisalignment(self.misalignment_rad), ScaleNonlinearity(self.k2_per_m_s2),
                TemperatureDrift(self.bias_tempco_m_s2_per_K, self.reference_temperature_K))

    def lever_arm(self) -> LeverArm:
        """The specific-force effect of the triad's offset ``position_C_m`` from the reference point."""
        return LeverArm(self.position_C_m)

    # ------------------------------------------------------------- physics
    def nominal_sensitivity_V_per_m_s2(self) -> np.ndarray:
        """What the lab would use to turn volts into indicated m/s^2: nominal K1 * R_L."""
        return np.full(3, K1_NOMINAL_A_PER_M_S2) * self.load_resistor_ohm

    def ideal_voltage(self, f_C: np.ndarray, temperature_K: np.ndarray | float | None = None,
                      hysteresis: np.ndarray | float = 0.0) -> np.ndarray:
        """Noise-free output voltages (n, 3) for specific force ``f_C`` (n, 3) m/s^2, the
        accelerometers' temperature (K, scalar, (n,) or (n,3)) and hysteresis state h ((n,) or (n,3))."""
        f_C = np.asarray(f_C, float)
        a_S = f_C + f_C @ np.ascontiguousarray(self.misalignment_rad.T)   # C-ordered: BLAS, the same numbers
        if temperature_K is None:
            dT = 0.0
        else:
            T = np.asarray(temperature_K, float)
            dT = (T.reshape(-1, 1) if T.ndim == 1 else T) - self.reference_temperature_K
        h = np.asarray(hysteresis, float)
        h = h.reshape(-1, 1) if h.ndim == 1 else h
        shape = np.broadcast_shapes(a_S.shape, np.shape(dT), h.shape)
        if shape != a_S.shape:   # e.g. one f_C for many temperatures: every row of its own
            a_S = np.broadcast_to(a_S, shape).copy()
        # a = a_S + b + k2 a_S^2 + c1 dT + c2 dT^2 + c3 dT^3 + b_h h, i = k1 (1 + s_T dT + s_h h) a, v = i R_L:
        # the same operations in the same order as that expression, in place (two (n, 3) buffers, not ten)
        a = a_S + self.bias_m_s2
        buf = a_S
        np.square(a_S, out=buf)
        buf *= self.k2_per_m_s2
        a += buf
        for c, x in ((self.bias_tempco_m_s2_per_K, dT), (self.bias_tempco2_m_s2_per_K2, dT**2),
                     (self.bias_tempco3_m_s2_per_K3, dT**3), (self.bias_hysteresis_m_s2, h)):
            a += _times(c, x, buf)
        g = _times(self.scale_tempco_per_K, dT, buf)   # buf (a_S) where the product is (n, 3)
        g = np.add(1, g, out=g) if g is buf else 1 + g
        g = _plus(g, self.scale_hysteresis * h)
        g = _times(self.k1_A_per_m_s2, g, g if g.shape == a.shape else None)
        a *= g                                          # k1 (...) a: the same product, commuted
        a *= self.load_resistor_ohm
        return a

    def current_noise(self, averaged: bool = False) -> CurrentNoise:
        """The triad's output current noise as an effect (:mod:`imurig.sensors.effects.current_noise`)."""
        return CurrentNoise(self.noise_bands, self.load_resistor_ohm, averaged, self.noise_enabled)

    def noise_current(self, n: int, fs: float, rng: np.random.Generator, averaged: bool = False) -> np.ndarray:
        """Output current noise (n, 3) A. Sampled directly (``averaged`` false), bands above fs/2
        alias into the sampled band (no analog anti-alias filter before the ADC), so their rms
        is kept as white noise. For averaged logging (each sample the mean of many fast
        conversions) the parts above fs/2 average out and only the in-band part is kept."""
        return self.current_noise(averaged).current(n, fs, rng)

    def window_mean_variance_A2(self, fs: float, n_window: int, averaged: bool = False) -> float:
        """Variance (A^2) of the mean of ``n_window`` logged samples of one axis' current noise
        (long-window limit, :func:`imurig.sensors.noise.window_mean_variance`); 0 with the noise off."""
        return self.current_noise(averaged).window_variance_A2(fs, n_window)

    def output_voltage(self, f_C: np.ndarray, fs: float, rng: np.random.Generator,
                       temperature_K=None, hysteresis=0.0) -> np.ndarray:
        """Voltages (n, 3) over the load resistors, with current noise."""
        v = self.ideal_voltage(f_C, temperature_K, hysteresis)
        return v + self.noise_current(v.shape[0], fs, rng) * self.load_resistor_ohm

    def truth(self) -> dict:
        """Every injected parameter, SI, JSON-ready."""
        d = asdict(self)
        d = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in d.items()}
        d["sensitivity_V_per_m_s2"] = (self.k1_A_per_m_s2 * self.load_resistor_ohm).tolist()
        d["model"] = "Honeywell Q-Flex QA700"
        return d


@dataclass
class CurrentTemperatureSensor:
    """A 1 uA/K current-output temperature sensor over a load resistor (Q-Flex internal, AD590-like).

    V = R_L (I_0 + k_T (T - T_0)) + noise    [V];  I_0 = 298.2 uA at T_0 = 298.15 K, k_T = 1 uA/K.
    """

    uA_per_K: float = 1.0
    uA_at_reference: float = 298.2
    reference_temperature_K: float = T_REF_K
    load_resistor_ohm: float = 10e3
    offset_K: float = 0.0  # absolute error of this sensor (datasheet +-3 C before calibration)
    noise_V_rms: float = 50e-6

    def voltage(self, temperature_K: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        T = np.asarray(temperature_K, float)
        i = 1e-6 * (self.uA_at_reference + self.uA_per_K * (T + self.offset_K - self.reference_temperature_K))
        return i * self.load_resistor_ohm + self.noise_V_rms * rng.standard_normal(T.shape)

    def temperature_K(self, volts: np.ndarray) -> np.ndarray:
        """Invert the nominal characteristic: volts -> kelvin."""
        i_uA = np.asarray(volts) / self.load_resistor_ohm * 1e6
        return self.reference_temperature_K + (i_uA - self.uA_at_reference) / self.uA_per_K

    def truth(self) -> dict:
        return asdict(self)
