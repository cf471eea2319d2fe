"""The lab site: position, local gravity, Earth rate and geomagnetic field.

Frames: ``W`` is the local-level world frame of the rigs, x east, y north, z up (ENU).
"""
from __future__ import annotations

import datetime as _dt
import math
from dataclasses import asdict, dataclass

import numpy as np

from imurig.kernel.errors import ConfigError

EARTH_RATE_RAD_S = 7.2921150e-5  # WGS-84, rad/s


@dataclass(frozen=True)
class Site:
    """A lab site. ``gravity_m_s2`` is the magnitude of local (effective) gravity."""

    name: str = "TU Delft calibration lab"
    latitude_deg: float = 52.0
    longitude_deg: float = 4.37
    altitude_m: float = 0.0
    gravity_m_s2: float = 9.81242231  # seed section 4.3.1, geodetic institute

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "Site":
        fields = {k: d[k] for k in cls.__dataclass_fields__ if k in d}
        return cls(**fields)

    @property
    def latitude_rad(self) -> float:
        return math.radians(self.latitude_deg)

    def earth_rate_W(self) -> np.ndarray:
        """Earth's rotation rate expressed in W (ENU), rad/s, shape (3,)."""
        phi = self.latitude_rad
        return EARTH_RATE_RAD_S * np.array([0.0, math.cos(phi), math.sin(phi)])

    def magnetic_field_W(self, when: _dt.datetime) -> np.ndarray:
        """IGRF main field in W (ENU), tesla, shape (3,), from pyIGRF (pinned 0.3.3)."""
        import pyIGRF

        _, _, _, north_nT, east_nT, down_nT, _ = pyIGRF.igrf_value(
            self.latitude_deg, self.longitude_deg, self.altitude_m / 1000.0, decimal_year(when))
        return 1e-9 * np.array([east_nT, north_nT, -down_nT], dtype=float)


def decimal_year(when: _dt.datetime) -> float:
    start = _dt.datetime(when.year, 1, 1, tzinfo=when.tzinfo)
    end = _dt.datetime(when.year + 1, 1, 1, tzinfo=when.tzinfo)
    return when.year + (when - start).total_seconds() / (end - start).total_seconds()


def parse_time(text: str) -> _dt.datetime:
    """ISO-8601 text to an aware datetime (UTC if no zone given)."""
    try:
        t = _dt.datetime.fromisoformat(str(text))
    except ValueError:
        raise ConfigError(f"{text!r} is not an ISO 8601 time; write e.g. 2005-06-14T18:00:00+02:00") from None
    return t if t.tzinfo else t.replace(tzinfo=_dt.timezone.utc)
