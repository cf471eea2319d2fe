"""The bench's own estimators in the :class:`~imurig.scoring.interface.Calibrator` contract (the
bench's estimator contract, :mod:`imurig.kernel.estimator`): the baseline a user's estimator is
compared with (``imurig scoreboard``).

Each ``fit(recording)`` sees only the recording without truth, returns ``self`` and leaves the
parameter rows ``{name, unit, estimate, std_error}`` in ``estimates_``, exactly as the campaign
reports compute them; the underlying calibration is ``calibration_``.
"""
from __future__ import annotations

from typing import Self

from imurig.calibration.gyro import GyroCalibration
from imurig.calibration.thermal import ThermalCalibration, step_table
from imurig.campaigns.magnetometer import analyse as analyse_magnetometer
from imurig.campaigns.thermal import compare as thermal_rows
from imurig.campaigns.tilt_table import calibrate as calibrate_tilt_table
from imurig.kernel.errors import ImurigError
from imurig.kernel.estimator import Estimator
from imurig.kernel.recording import Recording

ROW_KEYS = ("name", "unit", "estimate", "std_error")


class TiltTableCalibrator(Estimator):
    """Inverse-model least squares on per-position medians of the 100 Hz low-passed data
    (:func:`imurig.campaigns.tilt_table.calibrate`), with the survey's uncertainty. A
    recording logged at 100 Hz or slower (averaged logging, as in the Monte-Carlo runs) is
    used as it is, as the Monte-Carlo engine does."""

    def __init__(self, model: str = "physical", name: str = "bench tilt-table (inverse model, medians)"):
        self.model = model
        self.name = name

    def fit(self, recording: Recording) -> Self:
        self._clear_fitted()
        processed = recording if recording.sample_rate_hz <= 100.0 + 1e-9 else None
        self.calibration_ = calibrate_tilt_table(recording, model=self.model, processed=processed)
        self.estimates_ = self.calibration_.physical_parameters()
        return self

    def apply(self, recording: Recording) -> Recording:
        self.check_fitted()
        return self.calibration_.apply(recording)


class TurnTableCalibrator(Estimator):
    """Whole-round means timed by ``timer``, GLS inverse-model fit with the gyro noise model
    (:class:`imurig.calibration.gyro.GyroCalibration`)."""

    def __init__(self, timer: str = "hp6700", model: str = "physical",
                 name: str = "bench turn-table (GLS on whole rounds, HP counter)"):
        self.timer = timer
        self.model = model
        self.name = name

    def fit(self, recording: Recording) -> Self:
        self._clear_fitted()
        self.calibration_ = GyroCalibration(timer=self.timer, model=self.model).fit(recording)
        self.estimates_ = self.calibration_.physical_parameters()
        return self

    def apply(self, recording: Recording) -> Recording:
        self.check_fitted()
        return self.calibration_.apply(recording)


class ThermalCalibrator(Estimator):
    """Six-position bias and scale per step, polynomial fits with hysteresis against each
    sensor's temperature reading (:class:`imurig.calibration.thermal.ThermalCalibration`)."""

    def __init__(self, name: str = "bench thermal (six-position, polynomial + hysteresis)"):
        self.name = name

    def fit(self, recording: Recording) -> Self:
        self._clear_fitted()
        self.calibration_ = ThermalCalibration().fit(step_table(recording))
        self.estimates_ = [{k: r[k] for k in ROW_KEYS} for r in thermal_rows(self.calibration_)]
        return self

    def apply(self, *args, **kwargs):
        """The fitted thermal compensation (:meth:`ThermalCalibration.apply`)."""
        self.check_fitted()
        return self.calibration_.apply(*args, **kwargs)


class MagnetometerCalibrator(Estimator):
    """Two-step field-domain fits: 2-D ellipse on the level circle, 3-D ellipsoid on the tumble
    (:func:`imurig.campaigns.magnetometer.analyse`); ``calibration_`` the 3-D
    :class:`~imurig.calibration.magnetometer.MagnetometerCalibration`."""

    def __init__(self, name: str = "bench magnetometer (two-step ellipse/ellipsoid)"):
        self.name = name

    def fit(self, recording: Recording) -> Self:
        self._clear_fitted()
        res = analyse_magnetometer(recording)
        self.calibration_ = res["ellipsoid"]
        self.estimates_ = [{k: r[k] for k in ROW_KEYS} for r in res["parameters"]]
        return self

    def apply(self, *args, **kwargs):
        """The fitted 3-D calibration (:meth:`MagnetometerCalibration.apply`)."""
        self.check_fitted()
        return self.calibration_.apply(*args, **kwargs)


BASELINES = {"tilt-table": TiltTableCalibrator, "turn-table": TurnTableCalibrator, "thermal": ThermalCalibrator,
             "magnetometer": MagnetometerCalibrator}


def baseline_for(kind: str):
    """A fresh instance of the bench's estimator for a campaign kind."""
    if kind not in BASELINES:
        raise ImurigError(f"no bench estimator for campaign kind {kind!r}")
    return BASELINES[kind]()
