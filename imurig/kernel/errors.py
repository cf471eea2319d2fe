"""Exceptions raised on bad input. Each message says what is wrong and how to fix it."""


class ImurigError(Exception):
    """Base class of every error the bench raises on purpose."""


class RecordingError(ImurigError, ValueError):
    """A recording is malformed: NaNs, missing or mislabelled channels, wrong units."""


class ScheduleError(ImurigError, ValueError):
    """A protocol or schedule cannot be executed or cannot identify the requested model."""


class UnidentifiableTermsError(ImurigError, ValueError):
    """The design matrix is rank deficient: some model terms cannot be separated.

    Attributes
    ----------
    terms : list[str]
        Names of the terms that take part in the linear dependency.
    """

    def __init__(self, message: str, terms: list[str]):
        super().__init__(message)
        self.terms = list(terms)


class OutputExistsError(ImurigError, FileExistsError):
    """An output would overwrite existing results without --overwrite."""


class ConfigError(ImurigError, ValueError):
    """A rig, sensor or acquisition setting is impossible (e.g. too many ADC channels)."""


class NotFittedError(ImurigError, ValueError, AttributeError):
    """An estimator's ``apply`` (or a fitted result) was asked for before ``fit`` ran.

    Raised by :meth:`imurig.kernel.estimator.Estimator.check_fitted`; the message names the
    estimator and says to call ``fit(...)`` first.
    """
