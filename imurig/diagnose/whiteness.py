"""Is what a diagnosis leaves white? The engine's verdict on each channel's residual and the summary's
reading of it, from one function (numpy only)."""
from __future__ import annotations

import numpy as np


def residual_whiteness(r: np.ndarray) -> tuple[float, bool]:
    """(lag-1 autocorrelation rho of the residual r, white): white when |rho| < 2.5 / sqrt(n), the
    2.5-sigma bound of rho for n white values. With no spread left (a model as large as the data, an axis
    not excited: r[:-1] or r[1:] constant) rho is undefined (NaN) and nothing is unexplained: white, as
    the summary reads it (:mod:`imurig.diagnose.summary`). Fewer than 4 values: NaN, not called white."""
    r = np.asarray(r, float)
    if r.size <= 3:
        return float("nan"), False
    if np.ptp(r[:-1]) == 0 or np.ptp(r[1:]) == 0:
        return float("nan"), True
    lag1 = float(np.corrcoef(r[:-1], r[1:])[0, 1])
    return lag1, bool(abs(lag1) < 2.5 / np.sqrt(r.size))
