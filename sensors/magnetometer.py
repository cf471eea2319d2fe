"""Three-axis fluxgate magnetometer (APS-536), analog output.

Measurement equation (SI):

    B_S = S_soft (I + M) B_C + b_hard + c (T - T_ref)     [T, (n,3)]   field seen by the sensor
    V   = s * B_S + v_noise                              [V, (n,3)]   s: sensitivity, V/T per axis

B_C: true field in the IMU case frame C. S_soft: soft-iron matrix (identity if none).
M: axis misalignment (zero diagonal). b_hard: hard-iron bias (T). c: offset temperature
coefficient (T/K) at the box temperature T (K), T_ref = 298.15 K. Each term is an effect of
:mod:`imurig.sensors.effects` (``soft_iron``, ``mag_misalignment``, ``hard_iron``,
``mag_temperature_drift``): the triad holds their parameters and composes them.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from imurig.kernel.units import T_REF_K
from imurig.sensors.effects.hard_iron import HardIron
from imurig.sensors.effects.mag_misalignment import MagMisalignment
from imurig.sensors.effects.mag_temperature_drift import MagTemperatureDrift
from imurig.sensors.effects.soft_iron import SoftIron


@dataclass
class FluxgateTriad:
    sensitivity_V_per_T: np.ndarray = field(default_factory=lambda: np.full(3, 4.0e4))  # 40 mV/uT
    hard_iron_T: np.ndarray = field(default_factory=lambda: np.zeros(3))
    soft_iron: np.ndarray = field(default_factory=lambda: np.eye(3))
    misalignment_rad: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    noise_T_rms: float = 5e-9
    tempco_T_per_K: np.ndarray = field(default_factory=lambda: np.zeros(3))
    reference_temperature_K: float = T_REF_K
    nominal_sensitivity_V_per_T: float = 4.0e4  # the datasheet's 40 mV/uT: what the lab converts with

    def __post_init__(self):
        self.sensitivity_V_per_T = np.broadcast_to(np.asarray(self.sensitivity_V_per_T, float), (3,)).copy()
        self.hard_iron_T = np.broadcast_to(np.asarray(self.hard_iron_T, float), (3,)).copy()
        self.soft_iron = np.asarray(self.soft_iron, float).reshape(3, 3).copy()
        self.misalignment_rad = np.asarray(self.misalignment_rad, float).reshape(3, 3).copy()
        np.fill_diagonal(self.misalignment_rad, 0.0)
        self.tempco_T_per_K = np.broadcast_to(np.asarray(self.tempco_T_per_K, float), (3,)).copy()

    @classmethod
    def from_datasheet(cls, rng: np.random.Generator | None = None, *, sensitivity_mV_per_uT=40.0,
                       hard_iron_max_nT=2000.0, soft_iron_max=0.05, misalignment_max_mrad=5.0,
                       noise_nT_rms=5.0) -> "FluxgateTriad":
        s = np.full(3, sensitivity_mV_per_uT * 1e-3 / 1e-6)
        nominal = sensitivity_mV_per_uT * 1e-3 / 1e-6
        if rng is None:
            return cls(sensitivity_V_per_T=s, noise_T_rms=noise_nT_rms * 1e-9, nominal_sensitivity_V_per_T=nominal)
        soft = np.eye(3) + rng.uniform(-soft_iron_max, soft_iron_max, (3, 3))
        soft = (soft + soft.T) / 2
        return cls(sensitivity_V_per_T=s * (1 + rng.uniform(-0.02, 0.02, 3)),
                   hard_iron_T=rng.uniform(-1, 1, 3) * hard_iron_max_nT * 1e-9, soft_iron=soft,
                   misalignment_rad=rng.uniform(-1, 1, (3, 3)) * misalignment_max_mrad * 1e-3,
                   noise_T_rms=noise_nT_rms * 1e-9, nominal_sensitivity_V_per_T=nominal)

    def effects(self) -> tuple:
        """The triad's effects with its parameters: misalignment, soft iron, hard iron, temperature drift."""
        return (MagMisalignment(self.misalignment_rad), SoftIron(self.soft_iron), HardIron(self.hard_iron_T),
                MagTemperatureDrift(self.tempco_T_per_K, self.reference_temperature_K))

    def output_voltage(self, B_C: np.ndarray, rng: np.random.Generator, temperature_K=None) -> np.ndarray:
        """Voltages (n, 3) for the true field ``B_C`` (n, 3) tesla at the box temperature
        ``temperature_K`` (n,) K (None: no temperature term)."""
        mis, soft, hard, temp = self.effects()
        A = soft.matrix() @ mis.matrix()  # S (I + M), composed once
        B_S = hard.inject(B_C @ np.ascontiguousarray(A.T))   # C-ordered: BLAS, the same numbers
        if temperature_K is not None and np.any(self.tempco_T_per_K):
            B_S = B_S + temp.offset_T(temperature_K)
        B_S = B_S + self.noise_T_rms * rng.standard_normal(B_S.shape)
        return B_S * self.sensitivity_V_per_T

    def truth(self) -> dict:
        d = asdict(self)
        d = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in d.items()}
        d["model"] = "APS-536 fluxgate"
        return d
