"""The bench's own estimators, wrapped in the :class:`~imurig.scoring.interface.Calibrator`
contract: the baseline a user's estimator is compared with (``imurig scoreboard``).

Each ``fit(recording)`` sees only the recording without truth and returns parameter rows
``{name, unit, estimate, std_error}`` exactly as the campaign reports compute them.
"""
from __future__ import annotations

from dataclasses import dataclass

from imurig.kernel.errors import ImurigError
from imurig.kernel.recording import Recording


@dataclass
class TiltTableCalibrator:
    """Inverse-model least squares on per-position medians of the 100 Hz low-passed data
    (:func:`imurig.campaigns.tilt_table.calibrate`), with the survey's uncertainty. A
    recording logged at 100 Hz or slower (averaged logging, as in the Monte-Carlo runs) is
    used as it is, as the Monte-Carlo engine does."""

    model: str = "physical"
    name: str = "bench tilt-table (inverse model, medians)"

    def fit(self, recording: Recording) -> list[dict]:
        from imurig.campaigns.tilt_table import calibrate

        processed = recording if recording.sample_rate_hz <= 100.0 + 1e-9 else None
        self.cal_ = calibrate(recording, model=self.model, processed=processed)
        return self.cal_.physical_parameters()

    def apply(self, recording: Recording) -> Recording:
        return self.cal_.apply(recording)


@dataclass
class TurnTableCalibrator:
    """Whole-round means timed by ``timer``, GLS inverse-model fit with the gyro noise model
    (:func:`imurig.campaigns.turn_table.calibrate_gyros`)."""

    timer: str = "hp6700"
    model: str = "physical"
    name: str = "bench turn-table (GLS on whole rounds, HP counter)"

    def fit(self, recording: Recording) -> list[dict]:
        from imurig.campaigns.turn_table import calibrate_gyros

        self.cal_, *_ = calibrate_gyros(recording, timer=self.timer, model=self.model)
        return self.cal_.physical_parameters()

    def apply(self, recording: Recording) -> Recording:
        return self.cal_.apply(recording)


@dataclass
class ThermalCalibrator:
    """Six-position bias and scale per step, polynomial fits with hysteresis against each
    sensor's temperature reading (:mod:`imurig.calibration.thermal`)."""

    name: str = "bench thermal (six-position, polynomial + hysteresis)"

    def fit(self, recording: Recording) -> list[dict]:
        from imurig.calibration.thermal import ThermalFit, fit_thermal, step_table
        from imurig.campaigns.thermal import compare

        self.fit_ = fit_thermal(step_table(recording))
        return [{k: r[k] for k in ("name", "unit", "estimate", "std_error")}
                for r in compare(self.fit_, ThermalFit({}, {}))]


@dataclass
class MagnetometerCalibrator:
    """Two-step field-domain fits: 2-D ellipse on the level circle, 3-D ellipsoid on the tumble
    (:func:`imurig.campaigns.magnetometer.analyse`)."""

    name: str = "bench magnetometer (two-step ellipse/ellipsoid)"

    def fit(self, recording: Recording) -> list[dict]:
        from imurig.campaigns.magnetometer import analyse

        res = analyse(recording)
        return [{k: r[k] for k in ("name", "unit", "estimate", "std_error")} for r in res["parameters"]]


BASELINES = {"tilt-table": TiltTableCalibrator, "turn-table": TurnTableCalibrator, "thermal": ThermalCalibrator,
             "magnetometer": MagnetometerCalibrator}


def baseline_for(kind: str):
    """A fresh instance of the bench's estimator for a campaign kind."""
    if kind not in BASELINES:
        raise ImurigError(f"no bench estimator for campaign kind {kind!r}")
    return BASELINES[kind]()
