"""Run a user's estimator on a named campaign and score it against the injected truth.

    campaign(name, seed) -> recording without truth -> calibrator.fit -> estimates
      -> score_estimates(truth, estimates)    (the same function ``imurig score`` uses)
      -> + calibrated-output residuals if the calibrator has ``apply``
"""
from __future__ import annotations

import time

import numpy as np

from imurig.calibration.gyro import round_windows
from imurig.calibration.preprocess import segment_statistic
from imurig.scoring.campaigns import BenchCampaign, campaign
from imurig.scoring.interface import fitted_estimates
from imurig.scoring.score import Score, score_estimates


def _name(est) -> str:
    return getattr(est, "name", None) or type(est).__name__


def score_calibrator(calibrator, camp: BenchCampaign | str, seed: int | None = None, z_bound: float | None = None,
                     with_apply: bool = True) -> Score:
    """Fit ``calibrator`` on the campaign's recording (without truth) and score it.

    ``camp`` is a :class:`BenchCampaign` or a campaign name (then ``seed``, default the
    campaign's fixed seed). Adds ``extra['fit_wall_s']`` and, when the calibrator has an
    ``apply`` method, ``extra['output_residuals']``: the RMS per axis of the calibrated
    output minus the true input over the segments (tilt and turn table).
    """
    c = campaign(camp, seed) if isinstance(camp, str) else camp
    rec = c.recording()
    truth = c.truth()
    t0 = time.perf_counter()
    est = fitted_estimates(calibrator, rec)
    wall = time.perf_counter() - t0
    s = score_estimates(truth, est, estimator=_name(calibrator), source=f"{_name(calibrator)}.fit()", z_bound=z_bound)
    s.extra["fit_wall_s"] = wall
    if with_apply and hasattr(calibrator, "apply") and c.kind in ("tilt-table", "turn-table"):
        s.extra["output_residuals"] = output_residuals(c, calibrator.apply(rec))
    return s


def output_residuals(c: BenchCampaign, calibrated) -> dict:
    """RMS per axis (SI) of the calibrated channels minus the true input, per segment."""
    d = c.truth(with_bench=False).residuals
    q = np.asarray(d["true_input"])
    if c.kind == "tilt-table":
        names = ["acc_cal_x", "acc_cal_y", "acc_cal_z"]
        out = segment_statistic(calibrated, names, "median")
    else:
        names = ["gyro_cal_p", "gyro_cal_q", "gyro_cal_r"]
        rw, _ = round_windows(calibrated, "hp6700")
        out = segment_statistic(rw, names, "mean")
    r = out - q
    return {"unit": d["unit"], "rms": {a: float(np.sqrt(np.mean(r[:, j] ** 2))) for j, a in enumerate(d["axes"])}}
