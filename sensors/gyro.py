"""Fizoptika VG941-3AM fibre-optic gyro triad (seed appendix A.2).

Measurement equation, per sample n and axis i (SI inside):

    w_S   = (I + M) w_C                                          [rad/s, (n,3)] sensed rates
    w_i'  = w_S,i + b_i + b_gm,i(t) + k2_i w_S,i^2 + kb_i (T - T0)
            + sum_{j<k} c_i,jk w_S,j w_S,k + sum_j G_ij f_C,j     [rad/s]
    V_i   = SF_i (1 + ks_i (T - T0)) w_i' + SF_i n_i(t)          [V]

w_C: true angular rate of the IMU case frame C, including the Earth's rotation. M:
misalignment / cross-axis sensitivity (zero diagonal, rad). b: turn-on bias. b_gm: bias
instability, first-order Gauss-Markov (sigma, tau). k2: scale-factor nonlinearity
(1/(rad/s)). G: g-sensitivity ((rad/s)/(m/s^2), zero by default; f_C the specific force at
the IMU, m/s^2; applied by the effect ``g_sensitivity`` of :mod:`imurig.sensors.effects`). c:
product cross-coupling (seed eq. 4.39-4.41 terms w_p w_q ...; zero by default). SF: scale
factor (V per rad/s). n: angle random walk, white rate noise with Allan deviation
sigma(tau) = N / sqrt(tau); per sample sigma = N sqrt(fs).

Datasheet units (mV/(deg/s), deg/s, deg/s/sqrt(Hz), %) appear only in ``from_datasheet``.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from imurig.kernel.units import DEG, T_REF_K
from imurig.sensors.effects.g_sensitivity import GSensitivity
from imurig.sensors.effects.gyro_noise import GyroNoise

AXES = ("p", "q", "r")


def _vec(x) -> np.ndarray:
    return np.broadcast_to(np.asarray(x, float), (3,)).copy()


@dataclass
class FOGTriad:
    """Three VG941-3AM gyros (parameters in SI)."""

    scale_V_per_rad_s: np.ndarray = field(default_factory=lambda: np.full(3, 6e-3 / DEG))
    bias_rad_s: np.ndarray = field(default_factory=lambda: np.zeros(3))
    misalignment_rad: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    k2_per_rad_s: np.ndarray = field(default_factory=lambda: np.zeros(3))
    cross_coupling_per_rad_s: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))  # [i, pair]
    g_sensitivity_rad_s_per_m_s2: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    arw_rad_s_per_sqrt_hz: float = 0.0015 * DEG
    bias_instability_rad_s: float = 0.001 * DEG
    bias_instability_tau_s: float = 100.0
    bias_tempco_rad_s_per_K: np.ndarray = field(default_factory=lambda: np.zeros(3))
    scale_tempco_per_K: np.ndarray = field(default_factory=lambda: np.zeros(3))
    reference_temperature_K: float = T_REF_K
    nominal_scale_V_per_rad_s: float = 6e-3 / DEG
    noise_enabled: bool = True

    def __post_init__(self):
        for name in ("scale_V_per_rad_s", "bias_rad_s", "k2_per_rad_s", "bias_tempco_rad_s_per_K",
                     "scale_tempco_per_K"):
            setattr(self, name, _vec(getattr(self, name)))
        self.misalignment_rad = np.asarray(self.misalignment_rad, float).reshape(3, 3).copy()
        np.fill_diagonal(self.misalignment_rad, 0.0)
        self.cross_coupling_per_rad_s = np.asarray(self.cross_coupling_per_rad_s, float).reshape(3, 3).copy()
        self.g_sensitivity_rad_s_per_m_s2 = np.asarray(self.g_sensitivity_rad_s_per_m_s2, float).reshape(3, 3).copy()

    @classmethod
    def from_datasheet(cls, rng: np.random.Generator | None = None, *, scale_mV_per_dps=6.0,
                       scale_spread=0.02, bias_repeatability_dps=0.003, bias_variation_dps=0.001,
                       random_walk_dps_per_sqrt_hz=0.0015, misalignment_max_mrad=2.0,
                       nonlinearity_max_per_dps=2e-6, bias_instability_tau_s=100.0) -> "FOGTriad":
        """A triad in datasheet units. With ``rng``, errors are drawn: scale factor within
        +-``scale_spread`` of nominal (the unit's own value, not the 0.1 % repeatability),
        bias N(0, repeatability), misalignment and nonlinearity uniform within their limits."""
        sf = scale_mV_per_dps * 1e-3 / DEG
        base = dict(arw_rad_s_per_sqrt_hz=random_walk_dps_per_sqrt_hz * DEG,
                    bias_instability_rad_s=bias_variation_dps * DEG, bias_instability_tau_s=bias_instability_tau_s,
                    nominal_scale_V_per_rad_s=sf)
        if rng is None:
            return cls(scale_V_per_rad_s=np.full(3, sf), **base)
        u = lambda lim, shape=3: rng.uniform(-lim, lim, size=shape)  # noqa: E731
        return cls(scale_V_per_rad_s=sf * (1 + u(scale_spread)),
                   bias_rad_s=rng.normal(0, bias_repeatability_dps * DEG, 3),
                   misalignment_rad=u(misalignment_max_mrad * 1e-3, (3, 3)),
                   k2_per_rad_s=u(nonlinearity_max_per_dps / DEG), **base)

    def nominal_sensitivity(self) -> np.ndarray:
        return np.full(3, self.nominal_scale_V_per_rad_s)

    def ideal_voltage(self, w_C: np.ndarray, temperature_K=None, f_C: np.ndarray | None = None) -> np.ndarray:
        """Noise-free output voltages (n, 3) for true rates ``w_C`` (n, 3) rad/s and the specific
        force ``f_C`` (n, 3) m/s^2 (needed only with a g-sensitivity)."""
        w_C = np.asarray(w_C, float)
        # M^T as a C-ordered copy: numpy's matmul then takes BLAS (~2x less CPU for (n, 3) rows than the
        # transposed view, the same numbers)
        w_S = w_C @ np.ascontiguousarray(self.misalignment_rad.T)
        w_S += w_C                                   # w_C + M w_C
        dT = 0.0 if temperature_K is None else np.asarray(temperature_K, float).reshape(-1, 1) - \
            self.reference_temperature_K
        # w = w_S + b + k2 w_S^2 + tc_b dT, added in that order; in place (two (n, 3) arrays, not six)
        w = w_S + self.bias_rad_s
        sq = np.multiply(w_S, w_S)
        sq *= self.k2_per_rad_s
        w += sq
        w += self.bias_tempco_rad_s_per_K * dT
        if np.any(self.cross_coupling_per_rad_s):
            pairs = np.stack([w_S[:, 0] * w_S[:, 1], w_S[:, 0] * w_S[:, 2], w_S[:, 1] * w_S[:, 2]], axis=1)
            w = w + pairs @ self.cross_coupling_per_rad_s.T
        if f_C is not None and np.any(self.g_sensitivity_rad_s_per_m_s2):
            w = w + GSensitivity(self.g_sensitivity_rad_s_per_m_s2).rate_error(f_C)
        k = self.scale_V_per_rad_s * (1 + self.scale_tempco_per_K * dT)
        if np.broadcast_shapes(k.shape, w.shape) != w.shape:   # one rate (3,) at a temperature: (1, 3) out
            return k * w
        w *= k
        return w

    def noise(self) -> GyroNoise:
        """The triad's rate noise as an effect (:mod:`imurig.sensors.effects.gyro_noise`)."""
        return GyroNoise(self.arw_rad_s_per_sqrt_hz, self.bias_instability_rad_s, self.bias_instability_tau_s,
                         self.noise_enabled)

    def noise_rate(self, n: int, fs: float, rng: np.random.Generator) -> np.ndarray:
        """Rate noise (n, 3) rad/s: angle random walk plus Gauss-Markov bias instability."""
        return self.noise().rate(n, fs, rng)

    def output_voltage(self, w_C, fs, rng, temperature_K=None) -> np.ndarray:
        v = self.ideal_voltage(w_C, temperature_K)
        return v + self.noise_rate(v.shape[0], fs, rng) * self.scale_V_per_rad_s

    def truth(self) -> dict:
        d = asdict(self)
        d = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in d.items()}
        d["model"] = "Fizoptika VG941-3AM"
        return d
