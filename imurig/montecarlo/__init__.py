"""Monte-Carlo accuracy studies on dask.distributed: error distributions, Cramér-Rao bounds, coverage, design of experiments.

The built-in campaigns are registered here, in one list; :func:`register` adds your own.
"""
from imurig.montecarlo.engine import (
    Study,
    StudyInterrupted,
    load_study,
    reproduce_run,
    run_seed,
    run_study,
)
from imurig.montecarlo.flight import FLIGHT
from imurig.montecarlo.registry import get, names, register
from imurig.montecarlo.tilt import TILT_TABLE
from imurig.montecarlo.turn import TURN_TABLE

BUILTIN_CAMPAIGNS = (TILT_TABLE, TURN_TABLE, FLIGHT)
for _campaign in BUILTIN_CAMPAIGNS:
    register(_campaign)

__all__ = ["BUILTIN_CAMPAIGNS", "Study", "StudyInterrupted", "get", "load_study", "names", "register",
           "reproduce_run", "run_seed", "run_study"]
