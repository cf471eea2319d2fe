"""Compound units of estimated parameters: parse, check the dimension, convert to SI.

Parameter units are written as products and quotients of atomic units with integer powers,
e.g. ``V/(m/s^2)``, ``1/(rad/s)``, ``m/s^2/K^2``, ``mg``, ``deg/h``, ``mV/(deg/s)``. The
atomic units are those of the lab CSV suffix table (:mod:`imurig.kernel.units`: V, mV, uV, A, mA,
uA, rad, deg, arcmin, arcsec, T, uT, nT, K, degC, s, ms, us, m, Hz, ohm, and the suffix
forms rad_s, deg_s, dps, m_s2) plus g, mg, ug (standard gravity), mrad, urad, h, min,
ppm, % and 1.

A unit is a scale and a dimension vector over (V, A, rad, m, s, T, K):

    value_SI = scale * value_in_unit

Temperatures appear only as differences in parameter units (per K), so degC counts as K
with scale 1 (its offset never applies to a coefficient).
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass

from imurig.kernel.errors import ImurigError
from imurig.kernel.units import G_STANDARD, UNITS

BASE = ("V", "A", "rad", "m", "s", "T", "K")


class UnitError(ImurigError, ValueError):
    """A unit string cannot be parsed or has the wrong dimension."""


@dataclass(frozen=True)
class Unit:
    """scale (to SI) and exponents over :data:`BASE`."""

    scale: float
    dims: tuple[int, ...]

    def __mul__(self, o: Unit) -> Unit:
        return Unit(self.scale * o.scale, tuple(a + b for a, b in zip(self.dims, o.dims)))

    def __truediv__(self, o: Unit) -> Unit:
        return Unit(self.scale / o.scale, tuple(a - b for a, b in zip(self.dims, o.dims)))

    def __pow__(self, k: int) -> Unit:
        return Unit(self.scale ** k, tuple(a * k for a in self.dims))


def _d(**kw) -> tuple[int, ...]:
    return tuple(kw.get(b, 0) for b in BASE)


_SI = {"V": _d(V=1), "A": _d(A=1), "rad": _d(rad=1), "rad/s": _d(rad=1, s=-1), "m/s^2": _d(m=1, s=-2),
       "T": _d(T=1), "K": _d(K=1), "s": _d(s=1), "m": _d(m=1), "Hz": _d(s=-1), "ohm": _d(V=1, A=-1),
       "1": _d()}

ATOMS: dict[str, Unit] = {suf: Unit(spec.scale, _SI[spec.si]) for suf, spec in UNITS.items()}
ATOMS.update({
    "g": Unit(G_STANDARD, _d(m=1, s=-2)), "mg": Unit(1e-3 * G_STANDARD, _d(m=1, s=-2)),
    "ug": Unit(1e-6 * G_STANDARD, _d(m=1, s=-2)), "mrad": Unit(1e-3, _d(rad=1)), "urad": Unit(1e-6, _d(rad=1)),
    "h": Unit(3600.0, _d(s=1)), "min": Unit(60.0, _d(s=1)), "ppm": Unit(1e-6, _d()), "%": Unit(1e-2, _d()),
})
_TOKEN = re.compile(r"\s*(?:(\d+(?:\.\d*)?(?:[eE][+-]?\d+)?)|([A-Za-z%_][A-Za-z0-9_]*)|(\^-?\d+)|([*/()·]))")


def parse_unit(text: str) -> Unit:
    """Parse a unit string (see module doc). Raises UnitError naming the unknown part."""
    s = str(text).strip()
    if not s:
        raise UnitError("empty unit; write the unit of the value, e.g. 'V/(m/s^2)' or '1' if dimensionless")
    toks, pos = [], 0
    while pos < len(s):
        m = _TOKEN.match(s, pos)
        if not m or m.end() == pos:
            raise UnitError(f"cannot read unit {text!r} at {s[pos:]!r}")
        toks.append(m.group(0).strip())
        pos = m.end()
    toks = [t for t in toks if t]
    i = 0

    def atom() -> Unit:
        nonlocal i
        if i >= len(toks):
            raise UnitError(f"unit {text!r} ends unexpectedly")
        t = toks[i]
        i += 1
        if t == "(":
            u = expr()
            if i >= len(toks) or toks[i] != ")":
                raise UnitError(f"unbalanced parentheses in unit {text!r}")
            i += 1
        elif re.fullmatch(r"\d+(?:\.\d*)?(?:[eE][+-]?\d+)?", t):
            u = Unit(float(t), _d())
        elif t in ATOMS:
            u = ATOMS[t]
        else:
            raise UnitError(f"unknown unit {t!r} in {text!r}; known: {', '.join(sorted(ATOMS))}")
        if i < len(toks) and toks[i].startswith("^"):
            u = u ** int(toks[i][1:])
            i += 1
        return u

    def expr() -> Unit:
        nonlocal i
        u = atom()
        while i < len(toks) and toks[i] in ("*", "/", "·"):
            op = toks[i]
            i += 1
            u = u / atom() if op == "/" else u * atom()
        return u

    u = expr()
    if i != len(toks):
        raise UnitError(f"cannot read unit {text!r} after {' '.join(toks[:i])!r}")
    return u


def dimension_name(u: Unit) -> str:
    num = [f"{b}^{k}" if k != 1 else b for b, k in zip(BASE, u.dims) if k > 0]
    den = [f"{b}^{-k}" if k != -1 else b for b, k in zip(BASE, u.dims) if k < 0]
    return ("*".join(num) or "1") + ("/" + "/".join(den) if den else "")


def conversion_factor(from_unit: str, to_unit: str) -> float:
    """Factor f with value_in_to = f * value_in_from. Raises UnitError on a dimension mismatch."""
    a, b = parse_unit(from_unit), parse_unit(to_unit)
    if a.dims != b.dims:
        raise UnitError(f"unit {from_unit!r} has dimension {dimension_name(a)} but {to_unit!r} "
                        f"({dimension_name(b)}) is needed")
    f = a.scale / b.scale
    return 1.0 if math.isclose(f, 1.0, rel_tol=1e-15) else f
