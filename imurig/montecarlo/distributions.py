"""User-set error distributions for Monte-Carlo studies (TOML or JSON).

By default every run draws each error source from its datasheet distribution (uniform
within the datasheet limit, :meth:`imurig.sensors.chain.ImuLab.draw`; the table errors
from :meth:`imurig.rigs.tilt_table.TiltTableErrors.draw`). A distributions file replaces
chosen sources by normal distributions, in SI units::

    # errors.toml
    ["accelerometer.bias_m_s2"]
    mean = 0.0
    std = 0.02                    # or: variance = 4e-4

    ["table.theta_zero_rad"]
    mean = 0.0
    std = 2.9e-4

``mean`` and ``std``/``variance`` are scalars or lists with one value per element of the
source (3 axes; 3 x 3 for a misalignment matrix, whose diagonal is ignored). A negative
variance, a non-finite value or an unknown source is refused with a :class:`ConfigError`.
"""
from __future__ import annotations

import json
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from imurig.kernel.errors import ConfigError


@dataclass(frozen=True)
class Source:
    """One error source a campaign can draw: its SI unit and shape."""

    name: str
    unit: str
    shape: tuple[int, ...]
    doc: str


def normalise(spec: dict | None, sources: dict[str, Source]) -> dict:
    """Validate ``{source: {mean, std|variance}}``; returns {source: {"mean": list, "std": list}}.

    Raises ConfigError on an unknown source, a missing std, a negative variance or NaN.
    """
    out = {}
    for name, d in (spec or {}).items():
        if name not in sources:
            raise ConfigError(f"unknown error source {name!r}; this campaign draws {sorted(sources)}")
        if not isinstance(d, dict) or "mean" not in d or not ({"std", "variance"} & set(d)):
            raise ConfigError(f"error source {name!r} needs 'mean' and 'std' (or 'variance'), got {d!r}")
        if "std" in d and "variance" in d:
            raise ConfigError(f"error source {name!r}: give 'std' or 'variance', not both")
        src = sources[name]
        mean = _array(d["mean"], src, name, "mean")
        if "variance" in d:
            var = _array(d["variance"], src, name, "variance")
            if np.any(var < 0):
                raise ConfigError(f"error source {name!r} has a negative variance {d['variance']!r} "
                                  f"({src.unit}^2); a variance must be >= 0")
            std = np.sqrt(var)
        else:
            std = _array(d["std"], src, name, "std")
            if np.any(std < 0):
                raise ConfigError(f"error source {name!r} has a negative standard deviation {d['std']!r} "
                                  f"({src.unit}); it must be >= 0 (its square is the variance)")
        out[name] = {"mean": mean.tolist(), "std": std.tolist(), "unit": src.unit}
    return out


def _array(v, src: Source, name: str, what: str) -> np.ndarray:
    try:
        a = np.asarray(v, float)
    except (TypeError, ValueError):
        raise ConfigError(f"error source {name!r}: {what} must be a number or a list of numbers, got {v!r}") from None
    if not np.all(np.isfinite(a)):
        raise ConfigError(f"error source {name!r}: {what} must be finite, got {v!r}")
    try:
        return np.broadcast_to(a, src.shape).copy()
    except ValueError:
        raise ConfigError(f"error source {name!r}: {what} has shape {a.shape}; expected a scalar or shape "
                          f"{src.shape}") from None


def load(path) -> dict:
    """Read a distributions file (.toml or .json)."""
    p = Path(path)
    if not p.exists():
        raise ConfigError(f"distributions file {p} does not exist")
    text = p.read_text()
    try:
        if p.suffix.lower() == ".json":
            return json.loads(text)
        return tomllib.loads(text)
    except (json.JSONDecodeError, tomllib.TOMLDecodeError) as e:
        raise ConfigError(f"cannot parse {p}: {e}") from None


def draw(dist: dict, rng: np.random.Generator) -> np.ndarray:
    """One draw of a normalised source: mean + std * N(0, 1), elementwise."""
    mean, std = np.asarray(dist["mean"], float), np.asarray(dist["std"], float)
    return mean + std * rng.standard_normal(mean.shape)


def describe(sources: dict[str, Source]) -> str:
    return "\n".join(f"  {s.name} [{s.unit}] shape {s.shape}: {s.doc}" for s in sources.values())


def _finite(x) -> bool:
    return isinstance(x, (int, float)) and math.isfinite(x)
