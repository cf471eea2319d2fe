"""Stepwise model selection (seed section 4.2.2): forward selection and backward elimination.

Criteria
--------
``"bic"``, ``"aic"``   : a step is taken if it strictly lowers the criterion
                         (see :class:`~imurig.calibration.regression.RegressionResult`).
``"r2_adj"``           : a step is taken if it strictly raises the adjusted R^2 (eq. 4.30).
``"f_test"``           : partial F test with 1 numerator degree of freedom at level
                         ``alpha``. Forward: the candidate with the largest F enters if
                         its p-value < alpha. Backward: the term with the smallest F
                         leaves if its p-value > alpha.

Each step evaluates every candidate and takes the best one (ties: library
order). Candidates that would make the design rank deficient are skipped and
recorded in the history with action ``"skip"``. The selected model always
keeps at least one term.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import scipy.special

from imurig.kernel.errors import UnidentifiableTermsError

from .regression import RegressionResult, check_identifiable, fit_ols
from .terms import TermLibrary

__all__ = ["SelectionResult", "forward_selection", "backward_elimination", "CRITERIA"]

CRITERIA = ("bic", "aic", "r2_adj", "f_test")
#: residual degrees of freedom a backward elimination's starting model must leave (else it cannot test a term)
MIN_START_DOF = 2


@dataclass
class SelectionResult:
    """Outcome of a stepwise selection.

    ``selected``: chosen term names in library order; ``result``: the fit of
    that model; ``history``: one dict per step with keys ``step``, ``action``
    (``"start"``, ``"add"``, ``"remove"``, ``"skip"``), ``term``,
    ``criterion`` (value of the criterion after the step; for ``"f_test"``
    the p-value of the partial F test, with ``"F"`` also given),
    ``sigma_res``, ``r2_adj`` (``"skip"`` rows carry ``reason`` and
    ``dependent_terms`` instead).
    """

    selected: list[str]
    result: RegressionResult
    history: list[dict] = field(default_factory=list)
    criterion: str = "bic"
    alpha: float = 0.05

    @property
    def library(self) -> TermLibrary:
        return TermLibrary.from_names(self.selected)

    def to_dict(self) -> dict:
        """JSON-serialisable summary."""

        def clean(v):
            if isinstance(v, (float, np.floating)):
                v = float(v)
                return v if np.isfinite(v) else None
            if isinstance(v, (np.integer,)):
                return int(v)
            if isinstance(v, (list, tuple)):
                return [clean(x) for x in v]
            return v

        return {
            "criterion": self.criterion,
            "alpha": float(self.alpha),
            "selected": list(self.selected),
            "result": self.result.to_dict(),
            "history": [{k: clean(v) for k, v in h.items()} for h in self.history],
        }


def _check_criterion(criterion: str) -> None:
    if criterion not in CRITERIA:
        raise ValueError(f"unknown criterion {criterion!r}; valid criteria are {list(CRITERIA)}")


def _score(res: RegressionResult, criterion: str) -> float:
    """Lower is better (bic, aic, -r2_adj)."""
    if criterion == "bic":
        return res.bic
    if criterion == "aic":
        return res.aic
    return -res.r2_adj


def _prepare(library: TermLibrary, inputs, y, weights):
    if not isinstance(library, TermLibrary):
        raise TypeError(f"library must be a TermLibrary, got {type(library).__name__}")
    if len(library) == 0:
        raise ValueError("the term library is empty")
    D = library.design(inputs)
    y = np.asarray(y, dtype=np.float64)
    if y.shape != (D.shape[0],):
        raise ValueError(f"y must have shape ({D.shape[0]},) like the inputs, got {y.shape}")
    return D, y, library.names, weights


class _Fitter:
    """Fits sub-models of a library's design by column index (library order)."""

    def __init__(self, D, y, names, weights):
        self.D, self.y, self.names, self.weights = D, y, names, weights

    def fit(self, cols: set[int]) -> RegressionResult:
        idx = sorted(cols)
        return fit_ols(self.D[:, idx], self.y, [self.names[i] for i in idx], self.weights)


def _row(step, action, term, res: RegressionResult, criterion, value, F=None) -> dict:
    row = {
        "step": step,
        "action": action,
        "term": term,
        "criterion": float(value),
        "sigma_res": float(res.sigma_res),
        "r2_adj": float(res.r2_adj),
        "n_terms": res.p,
    }
    if F is not None:
        row["F"] = float(F)
    return row


def _crit_value(res: RegressionResult, criterion: str) -> float:
    return res.r2_adj if criterion == "r2_adj" else (res.bic if criterion == "bic" else res.aic)


def forward_selection(
    library: TermLibrary,
    inputs: Mapping[str, np.ndarray],
    y: np.ndarray,
    start: Sequence[str] = ("1",),
    criterion: str = "bic",
    alpha: float = 0.05,
    max_terms: int | None = None,
    weights: np.ndarray | None = None,
) -> SelectionResult:
    """Forward selection: start from ``start`` and add one term at a time.

    ``inputs`` maps input names to (n,) arrays, ``y`` is (n,). Stops when no
    candidate improves the criterion, when ``max_terms`` terms are selected,
    or when another term would leave fewer than ``MIN_START_DOF`` residual
    degrees of freedom (recorded as a ``"stop"`` row naming the untested terms). With an
    empty ``start`` the first step always adds the best single term.
    """
    _check_criterion(criterion)
    if not 0 < alpha < 1:
        raise ValueError(f"alpha must be in (0, 1), got {alpha}")
    D, y, names, weights = _prepare(library, inputs, y, weights)
    n = D.shape[0]
    fitter = _Fitter(D, y, names, weights)
    current = {library.index(s) for s in library.subset(start).names} if start else set()
    if max_terms is not None and max_terms < max(len(current), 1):
        raise ValueError(f"max_terms={max_terms} is smaller than the {len(current)} start terms")
    history: list[dict] = []
    step = 0
    res = None
    if current:
        res = fitter.fit(current)  # a deficient start model raises UnidentifiableTermsError
        value = np.nan if criterion == "f_test" else _crit_value(res, criterion)
        history.append(_row(0, "start", ",".join(res.names), res, criterion, value))
    excluded: set[int] = set()
    limit = len(names) if max_terms is None else max_terms
    while len(current) < limit and len(current) + 1 <= n - MIN_START_DOF:
        step += 1
        best = None  # (key, j, res)
        for j in range(len(names)):
            if j in current or j in excluded:
                continue
            try:
                cand = fitter.fit(current | {j})
            except UnidentifiableTermsError as e:
                excluded.add(j)
                history.append({
                    "step": step, "action": "skip", "term": names[j],
                    "reason": "rank deficient with the current model", "dependent_terms": list(e.terms),
                })
                continue
            key = cand.ss_res if criterion == "f_test" else _score(cand, criterion)
            if best is None or key < best[0]:
                best = (key, j, cand)
        if best is None:
            break
        _, j, cand = best
        F = pval = None
        if res is None:
            accept = True
        elif criterion == "f_test":
            F = (res.ss_res - cand.ss_res) / cand.ms_res if cand.ms_res > 0 else np.inf
            pval = float(scipy.special.fdtrc(1, cand.dof, F))
            accept = pval < alpha
        else:
            accept = _score(cand, criterion) < _score(res, criterion)
        if not accept:
            break
        current.add(j)
        res = cand
        value = pval if criterion == "f_test" else _crit_value(res, criterion)
        if value is None:
            value = np.nan
        history.append(_row(step, "add", names[j], res, criterion, value, F))
    if res is None:
        raise ValueError("forward selection found no identifiable term to start from")
    untested = [names[j] for j in range(len(names)) if j not in current and j not in excluded]
    if untested and len(current) + 1 > n - MIN_START_DOF:
        history.append({"step": step + 1, "action": "stop", "term": ",".join(untested),
                        "reason": f"{n} observations would leave fewer than {MIN_START_DOF} residual degrees of "
                                  "freedom with another term: the data cannot test these", "dependent_terms": []})
    return SelectionResult(list(res.names), res, history, criterion, alpha)


def backward_elimination(
    library: TermLibrary,
    inputs: Mapping[str, np.ndarray],
    y: np.ndarray,
    keep: Sequence[str] = ("1",),
    criterion: str = "bic",
    alpha: float = 0.05,
    weights: np.ndarray | None = None,
) -> SelectionResult:
    """Backward elimination: start from the whole library, remove one term at a time.

    Terms in ``keep`` are never removed. If the whole library is rank
    deficient, or leaves fewer than ``MIN_START_DOF`` residual degrees of
    freedom (e.g. six positions for a ten-term library), the starting model is
    built by taking terms in library order (``keep`` first) and skipping each
    term that is linearly dependent on the ones already taken or that would
    leave fewer than ``MIN_START_DOF`` residual degrees of freedom (each recorded
    as ``"skip"`` with its reason).
    """
    _check_criterion(criterion)
    if not 0 < alpha < 1:
        raise ValueError(f"alpha must be in (0, 1), got {alpha}")
    D, y, names, weights = _prepare(library, inputs, y, weights)
    fitter = _Fitter(D, y, names, weights)
    keep_idx = {library.index(s) for s in library.subset(keep).names} if keep else set()
    history: list[dict] = []
    n = D.shape[0]
    if len(keep_idx) > n - 1:
        raise UnidentifiableTermsError(f"{n} observations cannot identify the {len(keep_idx)} terms that are always "
                                       f"kept ({[names[j] for j in sorted(keep_idx)]}); add observations",
                                       [names[j] for j in sorted(keep_idx)])
    try:
        if len(names) > n - MIN_START_DOF:
            raise UnidentifiableTermsError("too few observations for the whole library", [])
        current = set(range(len(names)))
        res = fitter.fit(current)
    except UnidentifiableTermsError:
        current = set()
        order = sorted(keep_idx) + [j for j in range(len(names)) if j not in keep_idx]
        for j in order:
            if j not in keep_idx and len(current) + 1 > n - MIN_START_DOF:
                history.append({
                    "step": 0, "action": "skip", "term": names[j],
                    "reason": f"{n} observations would leave fewer than {MIN_START_DOF} residual degrees of "
                              "freedom with it: the data cannot test it", "dependent_terms": [],
                })
                continue
            try:
                check_identifiable(D[:, sorted(current | {j})], [names[i] for i in sorted(current | {j})])
            except UnidentifiableTermsError as e:
                if j in keep_idx:
                    raise
                history.append({
                    "step": 0, "action": "skip", "term": names[j],
                    "reason": "rank deficient with the terms before it", "dependent_terms": list(e.terms),
                })
                continue
            current.add(j)
        res = fitter.fit(current)
    value = np.nan if criterion == "f_test" else _crit_value(res, criterion)
    history.append(_row(0, "start", ",".join(res.names), res, criterion, value))
    step = 0
    while len(current) > 1:
        step += 1
        best = None
        for j in sorted(current - keep_idx):
            cand = fitter.fit(current - {j})  # a sub-design of a full-rank design is full rank
            key = cand.ss_res if criterion == "f_test" else _score(cand, criterion)
            if best is None or key < best[0]:
                best = (key, j, cand)
        if best is None:
            break
        _, j, cand = best
        F = pval = None
        if criterion == "f_test":
            F = (cand.ss_res - res.ss_res) / res.ms_res if res.ms_res > 0 else np.inf
            pval = float(scipy.special.fdtrc(1, res.dof, F))
            accept = pval > alpha
        else:
            accept = _score(cand, criterion) < _score(res, criterion)
        if not accept:
            break
        current.discard(j)
        res = cand
        value = pval if criterion == "f_test" else _crit_value(res, criterion)
        history.append(_row(step, "remove", names[j], res, criterion, value, F))
    return SelectionResult(list(res.names), res, history, criterion, alpha)

