"""The command line: ``imurig COMMAND``."""
import os

# one BLAS thread per process, set before numpy loads: the campaigns' linear algebra is small (eigh of a
# few hundred positions), where a thread pool fighting over a shared 2-core machine costs 10-100x
# (measured: eigh of 720 x 720, 2.6 CPU-s with the pool at load 8, 0.09 s with one thread)
for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import multiprocessing  # noqa: E402
import sys  # noqa: E402
import threading  # noqa: E402

from imurig.cli.main import main  # noqa: E402  (after the thread settings)

__all__ = ["main", "run"]


def run() -> None:
    """The ``imurig`` console command: :func:`main`, then the process ends with its exit code.

    When the command has returned with nothing left running (no other non-daemon thread, no child
    process) and every output is closed and committed, the interpreter's teardown (freeing every module
    and array one by one: ~0.25 s after a campaign) does no work anyone waits for, so the process ends
    at once (``os._exit``) after flushing the standard streams. Otherwise it exits as usual."""
    code = main()
    quiet = all(t.daemon or t is threading.main_thread() for t in threading.enumerate()) and \
        not multiprocessing.active_children()
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except (BrokenPipeError, ValueError):   # a closed reader: what was printed is all it takes
        quiet = False
    if quiet:
        os._exit(code)
    sys.exit(code)
