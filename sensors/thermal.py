"""Temperature of the sensors: thermal lag and hysteresis memory.

Thermal lag: each sensor group follows the air temperature through a first-order lag,

    dT_s/dt = (T_air - T_s) / tau_s                     [K]   (discretised exactly per sample)

Hysteresis memory: the play (backlash) operator of width w,

    p_k = clip(p_{k-1}, T_k - w/2, T_k + w/2)           [K]

so h = (T - p) / w lies in [-1/2, +1/2]: +1/2 after heating, -1/2 after cooling, and it keeps
that value while the temperature holds still. A sensor error e(T) + H h then shows two
branches a gap H apart, as a thermal cycle in the datasheets does.
"""
from __future__ import annotations

import numpy as np
from scipy import signal


def first_order_lag(x: np.ndarray, time_s: np.ndarray, tau_s: float) -> np.ndarray:
    """Exact first-order lag of a uniformly sampled series (starting in equilibrium)."""
    x = np.asarray(x, float)
    if tau_s <= 0:
        return x.copy()
    dt = float(np.median(np.diff(time_s)))
    a = np.exp(-dt / tau_s)
    y, _ = signal.lfilter([1 - a], [1, -a], x, zi=[a * x[0]])
    return y


def play_operator(x: np.ndarray, width: float, decimate: int = 1) -> np.ndarray:
    """The play operator (see module doc) of ``x`` (n,). The recursion runs on every
    ``decimate``-th sample (temperatures change over minutes: 1 Hz is ample) and is held
    in between; this Python loop is over the decimated series only."""
    x = np.asarray(x, float)
    xs = x[::decimate]
    p = np.empty_like(xs)
    h = width / 2
    prev = xs[0]
    for k, v in enumerate(xs):
        prev = min(max(prev, v - h), v + h)
        p[k] = prev
    return np.repeat(p, decimate)[: x.size]


def hysteresis_state(temperature_K: np.ndarray, width_K: float, fs: float) -> np.ndarray:
    """h in [-1/2, 1/2] (see module doc), from a temperature series sampled at fs."""
    if width_K <= 0:
        return np.zeros_like(np.asarray(temperature_K, float))
    p = play_operator(temperature_K, width_K, decimate=max(1, int(round(fs))))
    return (np.asarray(temperature_K) - p) / width_K
