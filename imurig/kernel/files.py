"""Recording files by their type: ``.h5`` (the project format) or ``.csv`` (the lab format)."""
from __future__ import annotations

from pathlib import Path

from imurig.kernel.errors import RecordingError
from imurig.kernel.labcsv import read_csv
from imurig.kernel.recording import Recording, load_h5


def load(path) -> Recording:
    """Load a recording from ``.h5`` (project format) or ``.csv`` (lab format)."""
    p = Path(path)
    if p.suffix.lower() in (".h5", ".hdf5"):
        return load_h5(p)
    if p.suffix.lower() == ".csv":
        return read_csv(p)
    raise RecordingError(f"unknown recording type '{p.suffix}' for {p}; use .h5 or .csv")
