"""Recording files by their type: ``.h5`` (the project format), ``.csv`` (the lab format) or ``.mat``
(MATLAB v5 or v7.3, read like the lab CSV)."""
from __future__ import annotations

from pathlib import Path

from imurig.kernel.errors import RecordingError
from imurig.kernel.labcsv import read_csv
from imurig.kernel.matfile import read_mat
from imurig.kernel.recording import Recording, load_h5


def load(path, rig: str | None = None, site=None, pulse_channel: str | None = None) -> Recording:
    """Load a recording from ``.h5`` (project format), ``.csv`` (lab format) or ``.mat`` (MATLAB).

    ``rig``, ``site`` and ``pulse_channel`` stand in for what a lab file lacks (see
    :func:`imurig.kernel.labcsv.read_csv`); a project file carries them already."""
    p = Path(path)
    readers = {".h5": load_h5, ".hdf5": load_h5,
               ".csv": lambda q: read_csv(q, rig=rig, site=site, pulse_channel=pulse_channel),
               ".mat": lambda q: read_mat(q, rig=rig, site=site, pulse_channel=pulse_channel)}
    reader = readers.get(p.suffix.lower())
    if reader is None:
        raise RecordingError(f"unknown recording type '{p.suffix}' for {p}; use .h5, .csv or .mat")
    try:
        return reader(p)
    except RecordingError as e:
        if str(p) not in str(e) and e.args:                  # every refusal names the file
            e.args = (f"{p}: {e.args[0]}",) + e.args[1:]
        raise
