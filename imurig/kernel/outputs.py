"""Output files written safely: strict JSON, one file at a time or a whole folder at once.

- :func:`to_json` / :func:`clean_json`: numpy-aware JSON; ``clean_json`` replaces non-finite
  floats by None so that a summary.json is strict JSON;
- :func:`atomic_write`: one file, written to a temporary name and renamed when complete;
- :class:`OutputFolder`: a report folder, written to a hidden temporary folder and renamed
  onto its path on success.

An existing output is refused (OutputExistsError) unless ``overwrite`` is given.
"""
from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from imurig.kernel.errors import OutputExistsError


def _json_default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.bool_):
        return bool(o)
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o)}")


def to_json(obj) -> str:
    return json.dumps(obj, default=_json_default, sort_keys=True)


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


def atomic_write(path: Path, writer, overwrite: bool) -> Path:
    """Run ``writer(tmp_path)`` then rename onto ``path``; never leaves a half-written file.

    Raises OutputExistsError if ``path`` exists and ``overwrite`` is false.
    """
    path = Path(path)
    if path.exists() and not overwrite:
        raise OutputExistsError(f"{path} exists; pass overwrite=True (CLI: --overwrite) to replace it")
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix="." + path.name + ".", suffix=".part", dir=path.parent)
    os.close(fd)
    try:
        writer(Path(tmp))
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise
    return path


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
