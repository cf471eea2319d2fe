"""MuJoCo's step without its profiling clock.

``mj_step`` times each of its stages for ``mjData.timer`` through the global callback ``mjcb_time``
(``TM_START`` / ``TM_END`` in MuJoCo's engine: the clock is read only when the callback is set). The
Python bindings install a default one, a ``std::chrono`` clock (newer releases again whenever an
``MjData`` is made while none is set), so a step reads the clock some forty times: on this project's
2-core machine that is a third of a small model's step (tilt table 4.1 -> 2.8 µs, the Citation 3.7 ->
2.5 µs, medians of 8 interleaved runs). The timers are profiling only: no state, sensor or contact
depends on them, so a model steps to the same bits either way (tested).

:func:`untimed` clears the callback when it is the bindings' default, i.e. set but not through
``mujoco.set_mjcb_time`` (a timer the user set stays). The rigs and the flights call it after making
their data, right before they step.
"""
from __future__ import annotations

import ctypes
from pathlib import Path

import mujoco

_STATE: dict = {}


def mujoco_library() -> Path | None:
    """The MuJoCo shared library the ``mujoco`` package ships (None if not found)."""
    here = Path(mujoco.__file__).parent
    for pattern in ("libmujoco.so*", "libmujoco*.dylib", "mujoco.dll"):
        found = sorted(here.glob(pattern))
        if found:
            return found[0]
    return None


def _callback():
    """The ``mjcb_time`` global of MuJoCo's library as a ctypes pointer, or None."""
    if "cb" not in _STATE:
        lib = mujoco_library()
        try:
            _STATE["cb"] = ctypes.c_void_p.in_dll(ctypes.CDLL(str(lib)), "mjcb_time") if lib is not None else None
        except (OSError, ValueError):   # no library to open, or no such symbol: the steps stay timed
            _STATE["cb"] = None
        # the bindings' default timer as first seen (for the tests: the clock put back)
        _STATE["default"] = _STATE["cb"].value if _STATE["cb"] is not None and mujoco.get_mjcb_time() is None \
            else None
    return _STATE["cb"]


def untimed() -> bool:
    """Clear ``mjcb_time`` if it is the bindings' default timer: set, but not through
    ``mujoco.set_mjcb_time`` (module doc). True if the steps now run without a clock."""
    cb = _callback()
    if cb is None:
        return False
    if cb.value is not None and mujoco.get_mjcb_time() is None:
        cb.value = None
    return cb.value is None
