"""The one estimator contract of the bench: every calibrator and every navigation filter follows it.

As scikit-learn's estimators::

    est = SomeCalibration(model="physical")   # __init__ stores the settings, nothing else: no work,
                                              # no checks of data, no fitted values
    est.fit(data, ...)                        # returns est; fitted values in attributes ending in "_"
                                              # (coef_, cov_, results_, solution_ ...), which do not
                                              # exist before fit; a second fit replaces them all
    est.apply(data, ...)                      # the calibrated output / the filtered solution;
                                              # before fit: NotFittedError
    est.is_fitted()                           # fit has run (or fitted values were loaded)
    est.get_params()                          # the settings: type(est)(**est.get_params()) is the
                                              # same estimator, unfitted

Settings are the parameters of ``__init__``, stored under the same names. Data, references and
noise models of one data set are arguments of ``fit``. ``fit`` is deterministic: the same data
give identical fitted attributes, and fitting twice gives the result of fitting once (no state
carried over from an earlier fit). ``tests/test_estimator_contract.py`` checks all of this for
every estimator of the project.
"""
from __future__ import annotations

import inspect
from abc import ABC, abstractmethod
from typing import Any, Self

from imurig.kernel.errors import NotFittedError


class Estimator(ABC):
    """Base class of the contract (module doc). Subclasses define ``__init__`` (settings only),
    ``fit`` (returns ``self``) and ``apply``; a class without either cannot be instantiated."""

    @abstractmethod
    def fit(self, *args: Any, **kwargs: Any) -> Self:
        """Estimate from data; store fitted values in attributes ending in ``_``; return ``self``."""

    @abstractmethod
    def apply(self, *args: Any, **kwargs: Any) -> Any:
        """Use the fitted values (the calibrated output, the filtered solution); refuses before ``fit``."""

    # ------------------------------------------------------------------ settings
    @classmethod
    def param_names(cls) -> list[str]:
        """Names of the settings: the named parameters of ``__init__``."""
        sig = inspect.signature(cls.__init__)
        return [p.name for p in sig.parameters.values()
                if p.name != "self" and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)]

    def get_params(self) -> dict:
        """The settings as stored by ``__init__`` (name -> value)."""
        return {k: getattr(self, k) for k in self.param_names()}

    def set_params(self, **params: Any) -> Self:
        """Change settings (names of ``__init__``); fitted values are left as they are until the next fit."""
        names = set(self.param_names())
        unknown = sorted(set(params) - names)
        if unknown:
            raise ValueError(f"{type(self).__name__} has no setting(s) {unknown}; its settings are {sorted(names)}")
        for k, v in params.items():
            setattr(self, k, v)
        return self

    # ------------------------------------------------------------------ fitted state
    def fitted_attributes(self) -> dict:
        """The fitted values: public attributes whose names end in ``_``."""
        return {k: v for k, v in vars(self).items() if k.endswith("_") and not k.startswith("_")}

    def is_fitted(self) -> bool:
        """Whether ``fit`` has run (or fitted values were loaded, e.g. from a saved calibration)."""
        return bool(self.fitted_attributes())

    def check_fitted(self, what: str = "apply") -> None:
        """Raise :class:`~imurig.kernel.errors.NotFittedError` unless the estimator is fitted."""
        if not self.is_fitted():
            raise NotFittedError(f"this {type(self).__name__} is not fitted yet: call fit(...) before {what}()")

    def _clear_fitted(self) -> None:
        """Remove every fitted value (the start of ``fit``: nothing of an earlier fit survives)."""
        for k in self.fitted_attributes():
            delattr(self, k)

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.get_params().items())
        return f"{type(self).__name__}({args})"
