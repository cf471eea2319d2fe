"""The effect library: one module per physical effect, each an :class:`~imurig.sensors.effects.base.Effect`.

``LIBRARY`` holds every effect class of this package, found by importing each of its modules, so
a new effect is one new file here (docs/architecture.md, "Adding an effect"): the sensor chain, the diagnosis,
the bounds and the filter priors find it through ``LIBRARY``, ``by_name`` and ``for_view`` and
nowhere else. Each class is also an attribute of this package (``from imurig.sensors.effects
import AdcCrosstalk``).

The modules are imported when the library is first asked for (``LIBRARY``, a class by name, ``by_name``,
``for_view``), not when the package is: importing one effect's module (the tilt table's backlash, when
the command line is built) does not load every effect and what they load (scipy.signal: ~1 CPU-s).
"""
from __future__ import annotations

import importlib
from contextlib import contextmanager
import pkgutil

from imurig.sensors.effects.base import (STAGES, Candidate, ChainContext, Effect, Param, PositionView,  # noqa: F401
                                         ScanSlot, ScatterView, recording_truth)
from imurig.sensors.effects.views import (MagView, RateRowView, RateShortfallView, RawChannelView, ThermalView,  # noqa: F401
                                          TurnSampleView, TurnView, VoltmeterRowView)


def _discover() -> tuple[type[Effect], ...]:
    """Every named Effect subclass defined in a module of this package, by (``order``, name): the
    diagnosis offers candidates in that order (position means: crosstalk, drift, axes, square, product)."""
    found = {}
    for info in pkgutil.iter_modules(__path__):
        if info.name in ("base", "views") or info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{__name__}.{info.name}")
        for obj in vars(module).values():
            if isinstance(obj, type) and issubclass(obj, Effect) and obj.name and obj.__module__ == module.__name__:
                if obj.name in found and found[obj.name] is not obj:
                    raise TypeError(f"two effects are called '{obj.name}': {found[obj.name].__module__} and "
                                    f"{module.__name__}; an effect's name is its identity, rename one")
                found[obj.name] = obj
    return tuple(sorted(found.values(), key=lambda c: (c.order, c.name)))


def _library() -> tuple[type[Effect], ...]:
    """The library (module doc), discovered on the first call; afterwards also the package's ``LIBRARY``
    and each class an attribute of the package."""
    lib = globals().get("LIBRARY")
    if lib is None:
        lib = _discover()
        globals().update({cls.__name__: cls for cls in lib})
        globals()["LIBRARY"] = lib
    return lib


def __getattr__(name: str):
    """``LIBRARY`` and the effect classes by name, discovered on first use (module doc)."""
    if name.startswith("__") or name in {i.name for i in pkgutil.iter_modules(__path__)}:
        raise AttributeError(name)   # a submodule: the import system loads it
    lib = _library()
    if name == "LIBRARY":
        return lib
    if name in globals():
        return globals()[name]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def by_name(name: str) -> type[Effect]:
    """The effect class called ``name``; raises KeyError naming the library's effects."""
    lib = _library()
    for cls in lib:
        if cls.name == name:
            return cls
    raise KeyError(f"no effect '{name}' in the library; known: {', '.join(c.name for c in lib)}")


def for_view(kind: str) -> list[type[Effect]]:
    """The effect classes that offer diagnosis candidates for views of ``kind`` ("positions", ...)."""
    return [cls for cls in _library() if kind in cls.views]


def run_tests(kind: str, view) -> dict:
    """Every library effect's own ``test`` on ``view`` (of ``kind``): their statistics merged, and
    a test that fires reports its finding under the effect's ``finding_key``."""
    out: dict = {}
    for cls in for_view(kind):
        res = dict(cls().test(view))
        finding = res.pop("finding", None)
        out.update(res)
        if finding is not None:
            out[getattr(cls, "finding_key", "finding")] = finding
    return out


@contextmanager
def registered(*classes: type[Effect]):
    """Add effect classes defined outside this package (a lab's own, an example) to ``LIBRARY`` for
    the duration of a ``with`` block: the diagnosis and every other consumer then find them too."""
    global LIBRARY
    before = _library()
    names = {c.name for c in before}
    for cls in classes:
        if not (isinstance(cls, type) and issubclass(cls, Effect) and cls.name):
            raise TypeError(f"{cls!r} is not a named Effect subclass")
        if cls.name in names:
            raise TypeError(f"an effect called '{cls.name}' is already in the library")
    LIBRARY = tuple(sorted((*before, *classes), key=lambda c: (c.order, c.name)))
    try:
        yield LIBRARY
    finally:
        LIBRARY = before
