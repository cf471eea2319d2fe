"""The tilt table's reference and the accelerometer fit against it (seed 4.1-4.3).

The reference of a tilt-table position is the specific force the table's set-points give at the
IMU in the case frame C, from the mounting, the set-point angles (theta, phi), the site's local
gravity and the surveyed table errors: f_ref,C = specific_force(theta, phi, mount, g; survey)
(:func:`imurig.rigs.tilt_table.reference_with_jacobian`, which also gives df_ref / d(survey error)
and the survey's 1-sigma errors). The accelerometer calibration is the inverse model
f_ref,C,j = sum_k c_jk t_k(u) per axis j, u = V / s_nom the indicated specific force, fitted by
least squares to the per-position statistics of the 100 Hz record, with the reference's
uncertainty propagated (:class:`imurig.calibration.accelerometer.AccelerometerCalibration`).
Used by the tilt-table campaign and by its diagnosis (the twin of the position means).
"""
from __future__ import annotations

import numpy as np

from imurig.calibration.accelerometer import AccelerometerCalibration
from imurig.calibration.preprocess import lowpass_downsample
from imurig.kernel.errors import RecordingError
from imurig.kernel.recording import Recording
from imurig.kernel.site import Site
from imurig.rigs.tilt_table import TableSurvey, reference_with_jacobian, setting_error_covariance


def tilt_table_reference(rec: Recording):
    """Reference specific force per segment from set-points and survey: (ref, J, sigma)."""
    return reference_with_jacobian(*reference_inputs(rec))


def reference_inputs(rec: Recording):
    """(segments with 'mount', local gravity, survey) of a tilt-table recording."""
    for col in ("theta", "phi"):
        if col not in rec.segments:
            raise RecordingError(f"the recording's segments lack the set-point '{col}'; tilt-table recordings "
                                 "need theta and phi set-points (CSV columns theta_deg, phi_deg and the "
                                 "'# setpoints: [\"theta\", \"phi\"]' metadata line)")
    segs = dict(rec.segments)
    if "mount" not in segs:
        runs = rec.meta.get("runs", ["z_up"])
        run_idx = segs.get("run", np.zeros(rec.n_segments, int)).astype(int)
        segs["mount"] = np.array([runs[i] for i in run_idx])
    g = Site.from_dict(rec.meta.get("site", {})).gravity_m_s2
    survey = rec.meta.get("table_survey") or {}
    survey = TableSurvey(**survey) if survey else TableSurvey()
    return segs, g, survey


def calibrate(rec: Recording, model: str = "physical", statistic: str = "huber",
              processed: Recording | None = None) -> AccelerometerCalibration:
    """Low-pass/downsample (if not given) and fit the inverse model with the reference's uncertainty,
    on the per-position ``statistic``: 'huber' (robust M-estimate, 95 % Gaussian efficiency; default),
    'median' (the seed's), 'mean', or 'raw' (every sample)."""
    rec100 = processed if processed is not None else lowpass_downsample(rec)
    ref, J, sigma = tilt_table_reference(rec100)
    cal = AccelerometerCalibration(model=model, statistic=statistic)
    if statistic == "raw":
        return cal.fit(rec100, ref)
    setting = None if model in ("stepwise", "backward") else setting_error_covariance(*reference_inputs(rec100))
    return cal.fit(rec100, ref, J, sigma, segment_cov=setting)
