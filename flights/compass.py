"""The compass of the GPS/INS filter: magnetic heading of the levelled magnetometer, its Jacobians,
the magnetometer's installation-error model and the IGRF declination along the route.

Measurement (:func:`mag_heading`): the field B_B (3,) T measured in body axes, levelled with the
INS's roll φ and pitch θ, gives the heading from true north

    B_h = Ry(θ) Rx(φ) B_B,   ψ_m = atan2(−B_h,y, B_h,x) + D        [rad]

(D the IGRF declination, east positive). With the installation errors θ = [b (3, T), ΔA (9, −)]
the measured field is B_m = (I + ΔA) B_B + b + n, corrected as B̂ = (I + ΔÂ)⁻¹ (B_m − b̂).
"""
from __future__ import annotations

import math

import numpy as np

def declination_rad(lat_rad: float, lon_rad: float, h_m: float, year: float) -> float:
    """IGRF declination (rad, east positive) from pyIGRF."""
    import pyIGRF  # lazy: pyIGRF reads its coefficient tables on import (~0.2 s)

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
