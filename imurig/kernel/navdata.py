"""The navigation data types, defined once: the IMU stream, GPS fixes and the navigation truth.

Frames (as in :mod:`imurig.flights`): I inertial, E Earth-fixed, N local navigation frame
north-east-down (NED), B body front-right-down (FRD) with its origin at the IMU. A field name
says the frame: ``f_B`` is a vector in B axes, ``w_IB_B`` the rate of B relative to I in B
axes, ``v_N`` a velocity w.r.t. the Earth in N axes, ``r_N`` a position in N. Quaternions are
scalar first (w, x, y, z); ``q_NB`` maps B to N coordinates, x_N = C(q_NB) x_B. SI units
throughout (s, m, m/s, m/s^2, rad, rad/s, T, K).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from imurig.kernel.errors import ConfigError

SAMPLE_SEMANTICS = ("held", "instantaneous")


@dataclass(kw_only=True)
class ImuStream:
    """IMU samples in SI, after whatever calibration the user applied (a navigation filter's input).

    ``time_s`` (n,) s, uniform; ``f_B`` (n, 3) m/s^2 specific force in B; ``w_IB_B`` (n, 3) rad/s
    angular rate of B w.r.t. I in B; optional ``B_B`` (n, 3) T magnetic field at the
    magnetometer in B axes; optional ``T_acc_K`` (n, 3) K accelerometer temperature channels.
    ``samples``: ``"held"`` (each sample the mean over [t_k, t_k+1): an integrating IMU, the flight
    truth and the sensor chain) or ``"instantaneous"`` (values of smooth signals at t_k; see
    :func:`imurig.flights.ins.preintegrate`). Measurement equation of a calibrated IMU::

        f_B = f_B,true + n_a,   w_IB_B = w_IB_B,true + n_g        (residual errors n)
    """

    time_s: np.ndarray
    f_B: np.ndarray
    w_IB_B: np.ndarray
    B_B: np.ndarray | None = None
    T_acc_K: np.ndarray | None = None
    samples: str = "held"

    def __post_init__(self):
        if self.samples not in SAMPLE_SEMANTICS:
            raise ConfigError(f"samples must be one of {SAMPLE_SEMANTICS}, got {self.samples!r}")

    @property
    def n(self) -> int:
        return int(np.asarray(self.time_s).size)


def _per_axis(sigma, k: int, name: str) -> np.ndarray | None:
    """A 1-sigma given as a scalar, (3,), (k,) or (k, 3), as (k, 3)."""
    if sigma is None:
        return None
    s = np.asarray(sigma, float)
    if s.ndim == 1 and s.size == k and k != 3:
        s = s[:, None]
    try:
        return np.broadcast_to(s, (k, 3)).copy()
    except ValueError:
        raise ConfigError(f"{name} must be a scalar, (3,), ({k},) or ({k}, 3) array of 1-sigma values, "
                          f"got shape {s.shape}") from None


@dataclass(frozen=True, kw_only=True)
class GpsFixes:
    """GPS fixes of the antenna (one receiver run).

    ``time_s`` (k,) s: the time each fix is valid at, on the IMU clock (a producer that stamps
    fixes later, e.g. :meth:`imurig.flights.gps.GpsReceiver.measure` with its logger tags, says so).
    Position, either geodetic or local:

    - ``lat_rad``, ``lon_rad``, ``h_m`` (k,): WGS-84 latitude, longitude, ellipsoidal height; ``v_N``
      then in the local-level NED axes at the fix;
    - ``r_N`` (k, 3) m: metres from the origin of a fixed NED frame N that the context states
      (the scorer's N0, :mod:`imurig.scoring.interface`); ``v_N`` then in N axes.

    ``v_N`` (k, 3) m/s antenna velocity w.r.t. the Earth (optional); ``sigma_pos_N`` and
    ``sigma_vel_N`` the 1-sigma per NED axis in m and m/s (given as a scalar, (3,), (k,) or
    (k, 3); stored (k, 3)); ``valid`` (k,) False in outages (values NaN there; default all True);
    ``mode`` the receiver mode; ``t_true_s`` (k,) the epoch each fix refers to (simulation truth,
    for tests and reports); ``meta`` the receiver settings. Measurement equation::

        fix_k = r_antenna(t_k) + e_k,   e_k ~ (0, diag(sigma_pos_N,k^2))      [m, NED]
    """

    time_s: np.ndarray
    lat_rad: np.ndarray | None = None
    lon_rad: np.ndarray | None = None
    h_m: np.ndarray | None = None
    r_N: np.ndarray | None = None
    v_N: np.ndarray | None = None
    sigma_pos_N: np.ndarray | None = None
    sigma_vel_N: np.ndarray | None = None
    valid: np.ndarray | None = None
    mode: str = ""
    t_true_s: np.ndarray | None = None
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        k = int(np.asarray(self.time_s).size)
        geodetic = [self.lat_rad is not None, self.lon_rad is not None, self.h_m is not None]
        if not (all(geodetic) or (not any(geodetic) and self.r_N is not None)):
            raise ConfigError("give the antenna position of the fixes either as lat_rad, lon_rad and h_m "
                              "(WGS-84) or as r_N (metres in a fixed NED frame), not both or neither")
        object.__setattr__(self, "valid", np.ones(k, bool) if self.valid is None else np.asarray(self.valid, bool))
        object.__setattr__(self, "sigma_pos_N", _per_axis(self.sigma_pos_N, k, "sigma_pos_N"))
        object.__setattr__(self, "sigma_vel_N", _per_axis(self.sigma_vel_N, k, "sigma_vel_N"))
        if self.meta is None:
            object.__setattr__(self, "meta", {})

    @property
    def n(self) -> int:
        return int(np.asarray(self.time_s).size)

    @property
    def geodetic(self) -> bool:
        """Whether the position is geodetic (lat_rad, lon_rad, h_m) rather than local (r_N)."""
        return self.lat_rad is not None


@dataclass(frozen=True, kw_only=True)
class FlightTruth:
    """Navigation truth at the IMU on the IMU clock (a simulated flight or a closed-form trajectory).

    ``time_s`` (n,) s uniform at ``rate_hz``; ``lat_rad``, ``lon_rad``, ``h_m`` (n,) WGS-84 position
    of the IMU; ``v_N`` (n, 3) m/s its velocity w.r.t. the Earth in local NED; ``q_NB`` (n, 4)
    attitude, x_N = C(q_NB) x_B; ``f_B`` (n, 3) m/s^2 true specific force at the IMU (WGS-84 normal
    gravity, Coriolis, transport rate); ``w_IB_B`` (n, 3) rad/s true inertial angular rate (body rate
    + Earth rate + transport rate); ``B_B`` (n, 3) T IGRF field at the magnetometer in B axes (sensor
    errors not included; None for trajectories without one); ``T_imu_K`` (n,) K IMU box air
    temperature (or None); ``lever_gps_B``, ``lever_mag_B`` (3,) m GPS antenna and magnetometer
    relative to the IMU in B; ``phases`` ((name, t_start_s, t_end_s), ...) manoeuvre labels;
    ``vehicle`` ("citation", "van", "fixture", "kinematic"); ``meta`` (start_time ISO, seed, plan,
    ``imu_samples``: "held" or "instantaneous", see :data:`SAMPLE_SEMANTICS`). The samples satisfy
    the NED mechanisation (:func:`imurig.flights.truth.mechanise`)::

        dv_N/dt = C_NB f_B − (2 ω_IE_N + ω_EN_N) × v_N + g_N,   w_NB_B = w_IB_B − C_BN (ω_IE_N + ω_EN_N)
    """

    time_s: np.ndarray
    rate_hz: float
    lat_rad: np.ndarray
    lon_rad: np.ndarray
    h_m: np.ndarray
    v_N: np.ndarray
    q_NB: np.ndarray
    f_B: np.ndarray
    w_IB_B: np.ndarray
    B_B: np.ndarray | None = None
    T_imu_K: np.ndarray | None = None
    lever_gps_B: np.ndarray = field(default_factory=lambda: np.zeros(3))
    lever_mag_B: np.ndarray = field(default_factory=lambda: np.zeros(3))
    phases: tuple = ()
    vehicle: str = "kinematic"
    meta: dict = field(default_factory=dict)

    @property
    def n(self) -> int:
        return int(self.time_s.size)

    def phase_mask(self, name: str) -> np.ndarray:
        """Boolean (n,) mask of the samples in every phase called ``name``."""
        m = np.zeros(self.n, bool)
        for nm, a, b in self.phases:
            if nm == name:
                m |= (self.time_s >= a) & (self.time_s < b)
        return m

    def slice(self, start_s: float, stop_s: float) -> FlightTruth:
        """The samples with start_s <= t < stop_s (time kept on the same clock)."""
        i = (self.time_s >= start_s) & (self.time_s < stop_s)
        kw = {k: (getattr(self, k)[i] if isinstance(getattr(self, k), np.ndarray)
                  and getattr(self, k).shape[:1] == (self.n,) else getattr(self, k))
              for k in self.__dataclass_fields__}
        kw["phases"] = tuple((nm, max(a, start_s), min(b, stop_s)) for nm, a, b in self.phases
                             if b > start_s and a < stop_s)
        return FlightTruth(**kw)
