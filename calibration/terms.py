"""Named, composable polynomial term libraries (in the spirit of pysindy's feature libraries).

A :class:`Term` is a monomial such as ``ax^2*az`` over named inputs; a
:class:`TermLibrary` is an ordered, duplicate-free collection of terms that
builds the regression design matrix ``X`` (shape ``(n, p)``, one column per
term, in library order) from a mapping ``input name -> (n,) array``.

Term names use ``*`` between factors and ``^k`` for powers; the constant term
is named ``"1"``. Examples: ``"1"``, ``"ax"``, ``"ax^2"``, ``"ay*az"``,
``"ax^2*az"``. :meth:`TermLibrary.from_names` parses such names back.
"""

from __future__ import annotations

import functools
import itertools
import re
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

__all__ = [
    "Term",
    "TermLibrary",
    "polynomial",
    "seed_accelerometer_terms",
    "parse_term",
]

_INPUT_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_FACTOR_RE = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)(?:\^([0-9]+))?$")


def _check_input_name(name: str) -> None:
    if not isinstance(name, str) or not _INPUT_RE.match(name):
        raise ValueError(
            f"invalid input name {name!r}: input names must be identifiers "
            "(letters, digits, underscore; not starting with a digit), e.g. 'ax'"
        )


@dataclass(frozen=True, eq=False)
class Term:
    """A monomial ``prod_i input_i ** k_i`` over named inputs.

    Attributes
    ----------
    powers : tuple[tuple[str, int], ...]
        ``(input name, exponent)`` pairs, exponents >= 1, each input at most
        once, in the input order of the owning library. ``()`` is the
        constant term ``"1"``.

    Two terms are equal when they have the same factors, regardless of the
    order of the factors (``ay*az == az*ay``).
    """

    powers: tuple[tuple[str, int], ...] = ()

    def __post_init__(self) -> None:
        seen: set[str] = set()
        clean = []
        for item in self.powers:
            if len(item) != 2:
                raise ValueError(f"Term powers must be (name, exponent) pairs, got {item!r}")
            name, k = item
            _check_input_name(name)
            if isinstance(k, bool) or int(k) != k:
                raise ValueError(f"exponent of {name!r} must be an integer, got {k!r}")
            k = int(k)
            if k < 0:
                raise ValueError(f"exponent of {name!r} must be >= 0, got {k}")
            if name in seen:
                raise ValueError(f"input {name!r} appears twice in term {self.powers!r}; merge the exponents")
            seen.add(name)
            if k > 0:
                clean.append((name, k))
        object.__setattr__(self, "powers", tuple(clean))

    # -- identity ---------------------------------------------------------
    @property
    def key(self) -> frozenset[tuple[str, int]]:
        """Order-independent identity of the monomial."""
        return frozenset(self.powers)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Term):
            return NotImplemented
        return self.key == other.key

    def __hash__(self) -> int:
        return hash(self.key)

    # -- description ------------------------------------------------------
    @property
    def name(self) -> str:
        """``"1"`` for the constant, else e.g. ``"ax"``, ``"ax^2"``, ``"ax^2*az"``."""
        if not self.powers:
            return "1"
        return "*".join(n if k == 1 else f"{n}^{k}" for n, k in self.powers)

    @property
    def degree(self) -> int:
        """Total degree (sum of exponents); 0 for the constant."""
        return sum(k for _, k in self.powers)

    @property
    def inputs(self) -> tuple[str, ...]:
        """Names of the inputs the term depends on."""
        return tuple(n for n, _ in self.powers)

    def __repr__(self) -> str:
        return f"Term({self.name!r})"

    def evaluate(self, inputs: Mapping[str, np.ndarray]) -> np.ndarray:
        """Evaluate the monomial: ``(n,)`` float64 array.

        ``inputs`` maps input names to ``(n,)`` arrays. The constant term
        returns ones with the length of the (first) array in ``inputs``.
        """
        if not self.powers:
            for v in inputs.values():
                return np.ones(np.shape(v)[0], dtype=np.float64)
            raise ValueError("cannot evaluate the constant term '1' without any input array to take n from")
        out = None
        for name, k in self.powers:
            if name not in inputs:
                raise ValueError(
                    f"term {self.name!r} needs input {name!r}, which is missing; "
                    f"available inputs: {sorted(inputs)}"
                )
            v = np.asarray(inputs[name], dtype=np.float64)
            col = v if k == 1 else v**k
            out = col.copy() if out is None else out * col
        return out


def parse_term(name: str) -> Term:
    """Parse a term name (``"1"``, ``"ax"``, ``"ax^2*az"``) into a :class:`Term`.

    Factors are kept in the order written; a repeated factor (``"ax*ax"``)
    is merged into a power.
    """
    if not isinstance(name, str):
        raise ValueError(f"term name must be a string, got {name!r}")
    s = name.replace(" ", "")
    if s == "1":
        return Term(())
    if not s:
        raise ValueError("empty term name; use '1' for the constant term")
    powers: dict[str, int] = {}
    for factor in s.split("*"):
        m = _FACTOR_RE.match(factor)
        if not m:
            raise ValueError(
                f"cannot parse term {name!r}: factor {factor!r} is not of the form 'name' or 'name^k' "
                "(examples of valid terms: '1', 'ax', 'ax^2', 'ay*az', 'ax^2*az')"
            )
        var, k = m.group(1), int(m.group(2) or 1)
        if k == 0:
            raise ValueError(f"cannot parse term {name!r}: zero exponent in factor {factor!r}")
        powers[var] = powers.get(var, 0) + k
    return Term(tuple(powers.items()))


class TermLibrary:
    """Ordered, duplicate-free collection of :class:`Term` objects.

    ``lib + other`` is the union (order preserved, duplicates dropped).
    ``name in lib`` tests membership by term name (factor order ignored).
    ``lib.design(inputs)`` builds the ``(n, p)`` design matrix.
    """

    __slots__ = ("_terms", "_index", "_inputs")

    def __init__(self, terms: Iterable[Term] = ()):
        terms = tuple(terms)
        index: dict[frozenset, int] = {}
        for i, t in enumerate(terms):
            if not isinstance(t, Term):
                raise TypeError(f"TermLibrary holds Term objects, got {t!r}; use TermLibrary.from_names for strings")
            if t.key in index:
                raise ValueError(
                    f"duplicate term {t.name!r} in library (positions {index[t.key]} and {i}); "
                    "use `lib_a + lib_b` to merge libraries with duplicates dropped"
                )
            index[t.key] = i
        inputs: dict[str, None] = {}
        for t in terms:
            for n in t.inputs:
                inputs.setdefault(n, None)
        self._terms = terms
        self._index = index
        self._inputs = tuple(inputs)

    # -- construction -----------------------------------------------------
    @classmethod
    def from_names(cls, names: Iterable[str]) -> TermLibrary:
        """Build a library from term names, e.g. ``["1", "ax", "ax^2", "ay*az"]``.

        Input order is the order of first appearance; each term's factors are
        sorted into that order, so ``from_names(lib.names).names == lib.names``.
        """
        if isinstance(names, str):
            raise TypeError("from_names expects a sequence of term names, not a single string")
        names = tuple(names)
        if all(isinstance(n, str) for n in names):   # a library is immutable: one per list of names
            return _library_of(cls, names)
        return cls._parsed(names)

    @classmethod
    def _parsed(cls, names: tuple) -> TermLibrary:
        parsed = [parse_term(n) for n in names]
        order: dict[str, int] = {}
        for t in parsed:
            for n in t.inputs:
                order.setdefault(n, len(order))
        return cls(Term(tuple(sorted(t.powers, key=lambda nk: order[nk[0]]))) for t in parsed)

    def __add__(self, other: TermLibrary) -> TermLibrary:
        if not isinstance(other, TermLibrary):
            return NotImplemented
        extra = [t for t in other._terms if t.key not in self._index]
        return TermLibrary(self._terms + tuple(extra))

    # -- container protocol ------------------------------------------------
    @property
    def terms(self) -> tuple[Term, ...]:
        return self._terms

    @property
    def names(self) -> list[str]:
        """Term names in library order."""
        return [t.name for t in self._terms]

    @property
    def inputs(self) -> tuple[str, ...]:
        """Input names the library needs (order of first appearance)."""
        return self._inputs

    def __len__(self) -> int:
        return len(self._terms)

    def __iter__(self) -> Iterator[Term]:
        return iter(self._terms)

    def __getitem__(self, i: int) -> Term:
        return self._terms[i]

    def __contains__(self, item: object) -> bool:
        if isinstance(item, Term):
            return item.key in self._index
        if isinstance(item, str):
            try:
                return parse_term(item).key in self._index
            except ValueError:
                return False
        return False

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, TermLibrary):
            return NotImplemented
        return self._terms == other._terms

    def __hash__(self) -> int:
        return hash(self._terms)

    def __repr__(self) -> str:
        return f"TermLibrary({self.names!r})"

    def index(self, name: str) -> int:
        """Column index of term ``name``; KeyError if absent."""
        key = parse_term(name).key
        if key not in self._index:
            raise KeyError(f"term {name!r} is not in the library {self.names}")
        return self._index[key]

    def subset(self, names: Iterable[str]) -> TermLibrary:
        """Library restricted to ``names``, in *library* order.

        Raises KeyError naming every unknown term.
        """
        if isinstance(names, str):
            names = [names]
        keys = set()
        unknown = []
        for n in names:
            try:
                k = parse_term(n).key
            except ValueError:
                unknown.append(n)
                continue
            if k in self._index:
                keys.add(k)
            else:
                unknown.append(n)
        if unknown:
            raise KeyError(f"unknown term(s) {unknown} not in library {self.names}")
        return TermLibrary(t for t in self._terms if t.key in keys)

    # -- evaluation ---------------------------------------------------------
    def design(self, inputs: Mapping[str, np.ndarray]) -> np.ndarray:
        """Design matrix ``X``, shape ``(n, p)`` float64, columns in library order.

        ``inputs`` maps each name in :attr:`inputs` to a ``(n,)`` array
        (extra entries are ignored). Each distinct power of each input is
        computed once and reused across terms.
        """
        missing = [n for n in self._inputs if n not in inputs]
        if missing:
            raise ValueError(
                f"design needs input(s) {missing} which are missing from the mapping "
                f"(got {sorted(inputs)}); the library {self.names} needs {list(self._inputs)}"
            )
        arrays: dict[str, np.ndarray] = {}
        n = None
        for name in self._inputs:
            v = np.asarray(inputs[name], dtype=np.float64)
            if v.ndim != 1:
                raise ValueError(f"input {name!r} must be a 1-D (n,) array, got shape {v.shape}")
            if n is None:
                n = v.shape[0]
            elif v.shape[0] != n:
                raise ValueError(
                    f"inputs have different lengths: {self._inputs[0]!r} has {n} samples, {name!r} has {v.shape[0]}"
                )
            arrays[name] = v
        if n is None:  # only the constant term (or empty library): take n from any input
            for v in inputs.values():
                n = np.shape(v)[0]
                break
            else:
                raise ValueError("cannot build a design for a constant-only library from an empty input mapping")
        X = np.empty((n, len(self._terms)), dtype=np.float64)
        cache: dict[tuple[str, int], np.ndarray] = {}

        def power(name: str, k: int) -> np.ndarray:
            if (name, k) not in cache:
                cache[(name, k)] = arrays[name] if k == 1 else arrays[name] ** k
            return cache[(name, k)]

        for j, t in enumerate(self._terms):
            if not t.powers:
                X[:, j] = 1.0
                continue
            (n0, k0), *rest = t.powers
            col = power(n0, k0)
            for name, k in rest:
                col = col * power(name, k)
            X[:, j] = col
        return X


def polynomial(inputs: Sequence[str], degree: int, cross: bool = True, bias: bool = True) -> TermLibrary:
    """All monomials in ``inputs`` up to total ``degree``.

    Order: constant (if ``bias``), then by degree, then lexicographic in the
    order of ``inputs``. With ``cross=False`` only pure powers ``x^k``.
    ``polynomial(["a","b"], 2).names == ["1","a","b","a^2","a*b","b^2"]``.
    """
    if isinstance(inputs, str):
        raise TypeError("inputs must be a sequence of names, e.g. ['ax', 'ay'], not a single string")
    inputs = list(inputs)
    for n in inputs:
        _check_input_name(n)
    if len(set(inputs)) != len(inputs):
        raise ValueError(f"duplicate input names in {inputs}")
    if isinstance(degree, bool) or int(degree) != degree or degree < 0:
        raise ValueError(f"degree must be a non-negative integer, got {degree!r}")
    degree = int(degree)
    terms: list[Term] = [Term(())] if bias else []
    for d in range(1, degree + 1):
        if cross:
            for combo in itertools.combinations_with_replacement(range(len(inputs)), d):
                counts: dict[int, int] = {}
                for i in combo:
                    counts[i] = counts.get(i, 0) + 1
                terms.append(Term(tuple((inputs[i], k) for i, k in sorted(counts.items()))))
        else:
            terms.extend(Term(((n, d),)) for n in inputs)
    return TermLibrary(terms)


def seed_accelerometer_terms(axis: str) -> TermLibrary:
    """Final accelerometer model of seed Table 4.6, terms in beta0..beta7 order.

    Inputs ``ax, ay, az``: ``1, ax, ax^2, ay, ay^2, az, az^2`` plus ``ay*az``
    for axis ``"x"`` and ``ax*az`` for ``"y"`` and ``"z"``.
    """
    cross = {"x": "ay*az", "y": "ax*az", "z": "ax*az"}
    if axis not in cross:
        raise ValueError(f"axis must be one of 'x', 'y', 'z', got {axis!r}")
    return TermLibrary.from_names(["1", "ax", "ax^2", "ay", "ay^2", "az", "az^2", cross[axis]])


@functools.lru_cache(maxsize=1024)
def _library_of(cls, names: tuple[str, ...]) -> TermLibrary:
    """:meth:`TermLibrary.from_names`, parsed once per class and list of names: a calibration applied in
    pieces (e.g. the .rrd's block means, ~1600 pieces) asks for the same few libraries again and again."""
    return cls._parsed(names)
