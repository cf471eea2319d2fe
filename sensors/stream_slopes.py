"""The slopes of the streamed chain's lines (what the converter's multiplexer crosstalk reads): np.gradient's
central differences over a piece, with one neighbouring row of each adjacent piece."""
from __future__ import annotations

import numpy as np


class Gradient:
    """np.gradient(x, t) (second-order central differences inside, first-order at the ends), its
    coefficients computed once for the sample times ``t`` and used for every line: the same values."""

    def __init__(self, t: np.ndarray):
        dx = np.diff(t)
        self.dx = dx
        d1, d2 = dx[:-1], dx[1:]
        self.a = -d2 / (d1 * (d1 + d2))
        self.b = (d2 - d1) / (d1 * d2)
        self.c = d1 / (d2 * (d1 + d2))

    def __call__(self, x: np.ndarray) -> np.ndarray:
        out = np.empty_like(x)
        mid = out[1:-1]   # a x[:-2] + b x[1:-1] + c x[2:], summed in that order, in place
        np.multiply(self.a, x[:-2], out=mid)
        tmp = self.b * x[1:-1]
        mid += tmp
        np.multiply(self.c, x[2:], out=tmp)
        mid += tmp
        out[0] = (x[1] - x[0]) / self.dx[0]
        out[-1] = (x[-1] - x[-2]) / self.dx[-1]
        return out
