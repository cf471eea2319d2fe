"""Report helpers: Markdown tables, published seed figures, a campaign's recording and rerun files.

Output folders written atomically (``OutputFolder``) and strict JSON (``clean_json``) live in
:mod:`imurig.kernel.outputs`; they are imported here for the report modules that still take
them from this module.
"""
from __future__ import annotations

import tomllib
from importlib import resources

import numpy as np

from imurig.kernel.outputs import OutputFolder, clean_json
from imurig.kernel.recording import save_h5

__all__ = ["OutputFolder", "clean_json", "fmt", "md_figures_and_run", "md_table", "published_figures",
           "save_products"]


def published_figures() -> dict:
    """The seed's published figures (assets/published_figures.toml)."""
    text = resources.files("imurig.assets").joinpath("published_figures.toml").read_text()
    return tomllib.loads(text)


def fmt(v, digits: int = 6) -> str:
    if v is None:
        return "–"
    if isinstance(v, (bool, np.bool_)):
        return "yes" if v else "**NO**"
    if isinstance(v, (int, np.integer)):
        return str(v)
    if isinstance(v, (float, np.floating)):
        if not np.isfinite(v):
            return "–"
        if 0.999 < abs(v) < 1.0:  # correlation coefficients: show the digits that matter
            return f"{v:.10f}"
        return f"{v:.{digits}g}"
    return str(v)


def md_table(header: list[str], rows: list[list]) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    for r in rows:
        out.append("| " + " | ".join(fmt(c) for c in r) + " |")
    return "\n".join(out) + "\n"


def save_products(out: OutputFolder, rec, res, write_rrd, save_recording: bool = True, rrd: bool = True,
                  stage=None) -> dict:
    """Write the recording (HDF5) and the rerun file of a campaign into ``out``; returns the
    files written. ``write_rrd(path, rec, res)`` is the campaign's own rerun writer;
    ``stage(name)`` is called before each (progress display)."""
    files = {}
    if save_recording:
        if stage:
            stage("recording.h5")
        save_h5(rec, out.file("recording.h5"), overwrite=True)
        files["recording"] = "recording.h5"
    if rrd:
        if stage:
            stage("campaign.rrd")
        write_rrd(out.file("campaign.rrd"), rec, res)
        files["rrd"] = "campaign.rrd"
    return files


def md_figures_and_run(figs: dict, keys, timing: dict | None) -> str:
    """The closing sections every campaign report shares: its figures, then the run's figures."""
    parts = ["\n## Figures\n"] + [f"![{k}]({figs[k]})\n" for k in keys if k in figs]
    if timing:
        parts += ["\n## Run\n", md_table(["step", "value"], [[k, v] for k, v in timing.items()])]
    return "\n".join(parts)
