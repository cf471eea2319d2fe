"""Every legend names every line: in the flight's error figure and the magnetometer diagnosis'
residual figure, every panel has a legend and every line and span in it carries a label."""
from __future__ import annotations

from types import SimpleNamespace as NS

import matplotlib
import numpy as np

matplotlib.use("Agg")
from matplotlib.figure import Figure  # noqa: E402


def _capture(monkeypatch) -> list:
    """Collect every figure saved (the report functions close theirs after saving)."""
    figs = []
    orig = Figure.savefig

    def savefig(self, *a, **k):
        figs.append(self)
        return orig(self, *a, **k)

    monkeypatch.setattr(Figure, "savefig", savefig)
    return figs


def _unnamed(fig) -> list[str]:
    """'panel i: artist' for every line or span without a label, and every panel without a legend."""
    out = []
    for i, ax in enumerate(fig.axes):
        if ax.get_legend() is None:
            out.append(f"panel {i}: no legend")
        for art in [*ax.get_lines(), *ax.patches, *ax.collections]:
            if art.get_label().startswith("_"):
                out.append(f"panel {i}: {art}")
    return out


def test_flight_error_figure_names_every_line(tmp_path, monkeypatch):
    from imurig.kernel.outputs import OutputFolder
    from imurig.reports.flight import fig_errors_consistency

    rng = np.random.default_rng(4)
    t = np.arange(0.0, 60.0, 0.1)
    runs = {}
    for name in ("uncalibrated", "calibrated"):
        err = {k: rng.normal(0, 1e-3, t.size) for k in ("roll_rad", "pitch_rad", "heading_rad")}
        err.update(pos_N_m=rng.normal(0, 1.0, (t.size, 3)), nees=rng.chisquare(9, t.size))
        runs[name] = (NS(time_s=t, P_diag=np.full((t.size, 15), 1e-4)), err, None)
    figs = _capture(monkeypatch)
    with OutputFolder(tmp_path / "f") as folder:
        fig_errors_consistency(folder, runs)
    assert len(figs) == 1 and _unnamed(figs[0]) == []


def test_magnetometer_diagnosis_figure_names_every_line(tmp_path, monkeypatch):
    from imurig.kernel.outputs import OutputFolder
    from imurig.reports.diagnosis_magnetometer import _figure

    rng = np.random.default_rng(5)
    t = np.arange(0.0, 100.0)
    field = rng.normal(0, 2e4, (t.size, 3))
    d = {"series": {"time_s": t, "recording_nT": field + 3.0, "twin_nT": field, "corrected_twin_nT": field + 3.0},
         "noise": {"block_sigma_predicted_nT": [1.0, 1.0, 1.0]}}
    figs = _capture(monkeypatch)
    with OutputFolder(tmp_path / "d") as out:
        _figure(out, d)
    assert len(figs) == 1 and _unnamed(figs[0]) == []
