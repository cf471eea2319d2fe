"""The command line: ``imurig COMMAND``."""
import os

# one BLAS thread per process, set before numpy loads: the campaigns' linear algebra is small (eigh of a
# few hundred positions), where a thread pool fighting over a shared 2-core machine costs 10-100x
# (measured: eigh of 720 x 720, 2.6 CPU-s with the pool at load 8, 0.09 s with one thread)
for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

from imurig.cli.main import main  # noqa: E402  (after the thread settings)

__all__ = ["main"]
