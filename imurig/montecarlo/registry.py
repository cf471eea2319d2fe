"""The campaigns a Monte-Carlo study can run, and the contract they keep.

A campaign is an object with

    name : str                                  e.g. "tilt-table"
    default_params() -> dict                    JSON-ready schedule and settings (SI / lab units as named)
    validate(params) -> dict                    complete, checked params (ImurigError subclass on bad input)
    sources() -> {name: Source}                 error sources a distributions file may set
    run(params, seed, distributions, estimator) -> {"rows": [...], "info": {...}}
    lab_time(params) -> dict                    lab time of the schedule (seed Table 4.7 style)
    schedules() -> {label: params overrides}    the design-of-experiments variants it compares

``run`` draws every error of one virtual lab from ``seed`` (a numpy SeedSequence), simulates
the campaign, estimates and returns parameter rows ``{name, unit, injected, estimate,
std_error, z, within_bound, crlb}`` (the project's parameter-row schema plus the run's
Cramér-Rao bound). ``estimator`` (optional) replaces the campaign's own calibration:
``estimator(recording) -> [{name, estimate, std_error}, ...]``; the campaign fills in the
injected values, z and the bound for the names it knows (:mod:`imurig.montecarlo.rows`).

The registry is a plain table: the built-in campaigns are registered by the one list in
:mod:`imurig.montecarlo` (the package), so importing any part of the package fills it.
Register a new campaign (e.g. your own rig) with :func:`register`; ``imurig montecarlo
NAME`` then runs it.
"""
from __future__ import annotations

from imurig.kernel.errors import ConfigError

CAMPAIGNS: dict[str, object] = {}


def register(campaign) -> object:
    """Add a campaign object to the registry (returns it, so it can decorate an instance)."""
    CAMPAIGNS[campaign.name] = campaign
    return campaign


def get(name: str):
    if name not in CAMPAIGNS:
        raise ConfigError(f"unknown Monte-Carlo campaign {name!r}; available: {sorted(CAMPAIGNS)}")
    return CAMPAIGNS[name]


def names() -> list[str]:
    return sorted(CAMPAIGNS)
