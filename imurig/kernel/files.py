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
    if p.suffix.lower() in (".h5", ".hdf5"):
        return load_h5(p)
    if p.suffix.lower() == ".csv":
        return read_csv(p, rig=rig, site=site, pulse_channel=pulse_channel)
    if p.suffix.lower() == ".mat":
        return read_mat(p, rig=rig, site=site, pulse_channel=pulse_channel)
    raise RecordingError(f"unknown recording type '{p.suffix}' for {p}; use .h5, .csv or .mat")
