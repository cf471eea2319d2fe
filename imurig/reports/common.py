"""Report helpers: output folders written atomically, Markdown tables, published seed figures."""
from __future__ import annotations

import json
import os
import shutil
import tempfile
import tomllib
from importlib import resources
from pathlib import Path

import numpy as np

from imurig.kernel.errors import OutputExistsError
from imurig.kernel.recording import to_json


def published_figures() -> dict:
    """The seed's published figures (assets/published_figures.toml)."""
    text = resources.files("imurig.assets").joinpath("published_figures.toml").read_text()
    return tomllib.loads(text)


class OutputFolder:
    """Write a report folder atomically: everything goes to a hidden temp folder that is
    renamed onto ``path`` on success. An existing ``path`` is refused unless ``overwrite``."""

    def __init__(self, path, overwrite: bool = False):
        self.path = Path(path)
        self.overwrite = overwrite
        if self.path.exists() and not overwrite:
            raise OutputExistsError(f"{self.path} exists; choose another --out or pass --overwrite to replace it")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.tmp = Path(tempfile.mkdtemp(prefix="." + self.path.name + ".", dir=self.path.parent))

    def file(self, name: str) -> Path:
        return self.tmp / name

    def write_json(self, name: str, obj) -> Path:
        p = self.file(name)
        p.write_text(json.dumps(json.loads(to_json(obj)), indent=2, allow_nan=False) + "\n")
        return p

    def write_text(self, name: str, text: str) -> Path:
        p = self.file(name)
        p.write_text(text)
        return p

    def commit(self) -> Path:
        if self.path.exists():
            if not self.overwrite:
                raise OutputExistsError(f"{self.path} appeared while writing; pass --overwrite")
            old = self.path.with_name("." + self.path.name + ".old")
            if old.exists():
                shutil.rmtree(old)
            os.replace(self.path, old)
            os.replace(self.tmp, self.path)
            shutil.rmtree(old)
        else:
            os.replace(self.tmp, self.path)
        return self.path

    def abort(self):
        shutil.rmtree(self.tmp, ignore_errors=True)

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            self.commit()
        else:
            self.abort()
        return False


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


def clean_json(obj):
    """Replace non-finite floats by None so that summary.json is strict JSON."""
    if isinstance(obj, dict):
        return {k: clean_json(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [clean_json(v) for v in obj]
    if isinstance(obj, (float, np.floating)):
        return float(obj) if np.isfinite(obj) else None
    if isinstance(obj, np.ndarray):
        return clean_json(obj.tolist())
    if isinstance(obj, np.integer):
        return int(obj)
    return obj


def save_products(out: OutputFolder, rec, res, write_rrd, save_recording: bool = True, rrd: bool = True,
                  stage=None) -> dict:
    """Write the recording (HDF5) and the rerun file of a campaign into ``out``; returns the
    files written. ``write_rrd(path, rec, res)`` is the campaign's own rerun writer;
    ``stage(name)`` is called before each (progress display)."""
    from imurig.kernel.recording import save_h5

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
