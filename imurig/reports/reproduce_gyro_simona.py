"""``imurig reproduce fig_4_19``: the SIMONA quick calibration (seed 4.4.2, appendix B, Fig. 4.19) with the
gyros' scale-factor nonlinearity fitted to Table B.1.

The seed's Table B.1 residuals about its linear calibration curve with the rate (+0.05 deg/s at rest, -0.11
at 25, +0.17 at 82 deg/s), alike in the three gyros; the seed's own gyro models carry the term (eq. 4.39-4.41:
"the second-order coefficients are beta_2"). The virtual SIMONA gyros are linear in the quiet lab, so here
they carry k2 estimated from the table (:func:`imurig.campaigns.delft_2005_imu.table_b1_gyro_k2`, with SEs).
Two statistics per gyro, each the project's least squares of the rate on the voltmeter reading:

* the linear calibration's residual sigma (what Fig. 4.19's middle panel shows): its curved part is fitted
  (k2 comes from these rows), its random part predicted -- partly a FIT TARGET;
* the quadratic calibration's residual sigma (omega = b0 + b1 V + b2 V^2): the random part alone (stopwatch
  printed to 0.01 s, voltmeter, the table's once-per-round rate ripple read at a random moment of the round).
  The ripple's size is fitted to the three gyros' pooled variance of these rows
  (:mod:`imurig.montecarlo.delft_fit_simona`), so these rows are FIT TARGETS in their mean over the gyros;
  one virtual lab's values scatter about that mean by ~19 % (the fit's record).

Tolerance of a sigma with dof degrees of freedom: 2 sqrt(se_seed^2 + se_imurig^2), se = sigma / sqrt(2 dof).
"""
from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from imurig.calibration.simona import GYROS, SimonaCalibration, read_simona
from imurig.campaigns.delft_2005_imu import table_b1_gyro_k2
from imurig.campaigns.delft_2005_turn import Delft2005Turn, fitted_ripple
from imurig.campaigns.turn_table import SimonaSetup, simona_virtual
from imurig.reports.reproduce_lab import row


@lru_cache(maxsize=1)
def simona_runs():
    """(the seed's Table B.1, the virtual SIMONA experiment on the preset), once per process."""
    return read_simona(), simona_virtual(setup=preset_setup())


def preset_setup() -> SimonaSetup:
    """The virtual SIMONA on the Delft 2005 preset: Table B.1's k2 and the table ripple fitted to Table B.1's
    scatter about a quadratic (:mod:`imurig.montecarlo.delft_fit_simona`)."""
    k2 = table_b1_gyro_k2()
    return SimonaSetup(k2_per_rad_s=tuple(k2[g]["value_per_rad_s"] for g in GYROS),
                       table=Delft2005Turn.fitted().table_errors())


def quadratic_sigma(summary: dict) -> tuple[float, int]:
    """(residual sigma in deg/s, dof) of omega_ref = b0 + b1 V + b2 V^2 over a calibration's rows."""
    V, w = np.asarray(summary["voltage_V"]), np.asarray(summary["reference_rate_dps"])
    X = np.column_stack([np.ones_like(V), V, V**2])
    b, *_ = np.linalg.lstsq(X, w, rcond=None)
    r = w - X @ b
    return float(np.sqrt(r @ r / (w.size - 3))), w.size - 3


def _tol(s_a: float, dof_a: int, s_b: float, dof_b: int) -> float:
    return 2 * math.hypot(s_a / math.sqrt(2 * dof_a), s_b / math.sqrt(2 * dof_b))


def fig_4_19() -> list[dict]:
    """Fig. 4.19's own-calibration residual sigma per gyro, linear and quadratic (module doc)."""
    real, virt = (SimonaCalibration().fit(r).summary_ for r in simona_runs())
    k2 = table_b1_gyro_k2()
    out = []
    for g in GYROS:
        s_r, s_v = real[g]["sigma_res_dps"], virt[g]["sigma_res_dps"]
        dof_r, dof_v = len(real[g]["rows"]) - 2, len(virt[g]["rows"]) - 2
        fit = f"k2 {k2[g]['value_per_dps']:.3g} +- {k2[g]['se_per_dps']:.2g} per deg/s"
        out.append(row("fig_4_19", f"{g} gyro own-calibration residual sigma", "deg/s", s_r, s_v,
                       _tol(s_r, dof_r, s_v, dof_v),
                       f"FIT TARGET in part: the virtual gyros' {fit} is fitted to these rows (its curve by "
                       f"construction), the table's ripple to their scatter about a quadratic (the random part, "
                       f"in the mean over the gyros); manufacturer's residuals reach "
                       f"{real[g]['manufacturer_max_abs_dps']:.1f} (seed) and {virt[g]['manufacturer_max_abs_dps']:.1f} "
                       "deg/s (virtual)"))
    rip = fitted_ripple()["sizes"]["table_ripple"]
    for g in GYROS:
        (q_r, d_r), (q_v, d_v) = quadratic_sigma(real[g]), quadratic_sigma(virt[g])
        out.append(row("fig_4_19", f"{g} gyro residual sigma about a quadratic calibration (the random part)", "deg/s",
                       q_r, q_v, _tol(q_r, d_r, q_v, d_v),
                       f"FIT TARGET in the mean over the gyros: the table's ripple {rip['value']:.2g} +- {rip['se']:.2g} "
                       "of the rate is fitted to the three gyros' pooled variance about a quadratic (stopwatch printed "
                       "to 0.01 s, autoscaling voltmeter and the rest as in the quiet lab); one lab's value scatters "
                       "about it"))
    return out
