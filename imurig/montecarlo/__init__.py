"""Monte-Carlo accuracy studies on dask.distributed: error distributions, Cramér-Rao bounds, coverage, design of experiments."""
from imurig.montecarlo.engine import (
           Study,
           StudyInterrupted,
           load_study,
           reproduce_run,
           run_seed,
           run_study,
)
from imurig.montecarlo.registry import get, names, register

__all__ = ["Study", "StudyInterrupted", "get", "load_study", "names", "register", "reproduce_run", "run_seed",
           "run_study"]
