"""Output files written safely: strict JSON, one file at a time or a whole folder at once.

- :func:`to_json` / :func:`clean_json`: numpy-aware JSON; ``clean_json`` replaces non-finite
  floats by None so that a summary.json is strict JSON;
- :func:`atomic_write`: one file, written to a temporary name and renamed when complete;
- :class:`OutputFolder`: a report folder, written to a hidden temporary folder and renamed
  onto its path on success (swapped in one step when it replaces an old one).

Temporary names carry the writer's process id (``.<name>.tmp-<pid>-*``): the next run removes
those of processes that died (:func:`clean_stale`). Files and folders follow the user's umask.

An existing output is refused (OutputExistsError) unless ``overwrite`` is given.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import json
import os
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

from imurig.kernel.errors import ConfigError, OutputExistsError


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


def _umask() -> int:
    m = os.umask(0)
    os.umask(m)
    return m


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths in one step (Linux renameat2 RENAME_EXCHANGE); False where the system lacks it."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or None, use_errno=True)
        fn = libc.renameat2
    except (OSError, AttributeError):
        return False
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    at_fdcwd, rename_exchange = -100, 2
    return fn(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def clean_stale(path: Path) -> list[Path]:
    """Remove the temporary siblings ``.<name>.tmp-<pid>-*`` of ``path`` whose writing process has died
    (a killed run), and put back ``.<name>.old`` when a kill came between the two renames of a
    replacement and ``path`` is missing. Returns what was removed or restored."""
    path = Path(path)
    done = []
    if not path.parent.is_dir():
        return done
    for q in path.parent.glob(f".{path.name}.tmp-*"):
        try:
            pid = int(q.name[len(path.name) + 6:].split("-", 1)[0])
        except ValueError:
            continue
        if pid != os.getpid() and not _pid_alive(pid):
            shutil.rmtree(q, ignore_errors=True) if q.is_dir() else q.unlink(missing_ok=True)
            done.append(q)
    old = path.with_name("." + path.name + ".old")
    if old.exists() and not path.exists():
        os.replace(old, path)
        done.append(old)
    return done


def check_disk(path, need_bytes: float, what: str, fix: str, free_bytes: int | None = None) -> None:
    """Refuse (ConfigError) before anything is written when the file system that will hold ``path`` (its
    nearest existing folder) has less free space than ``need_bytes``: ``what`` would need, ``fix`` says how
    to need less. ``free_bytes``: the free space to check against (tests), else the file system's."""
    folder = Path(path).resolve()
    while not folder.is_dir() and folder != folder.parent:
        folder = folder.parent
    free = shutil.disk_usage(folder).free if free_bytes is None else int(free_bytes)
    if need_bytes > free:
        raise ConfigError(f"{what} would take about {need_bytes / 1e9:.3g} GB on disk, but only {free / 1e9:.3g} GB "
                          f"are free there; {fix}")


def atomic_write(path: Path, writer, overwrite: bool) -> Path:
    """Run ``writer(tmp_path)`` then rename onto ``path``; never leaves a half-written file.

    Raises OutputExistsError if ``path`` exists and ``overwrite`` is false.
    """
    path = Path(path)
    if path.exists() and not overwrite:
        raise OutputExistsError(f"{path} exists; pass overwrite=True (CLI: --overwrite) to replace it")
    path.parent.mkdir(parents=True, exist_ok=True)
    clean_stale(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.tmp-{os.getpid()}-", suffix=".part", dir=path.parent)
    os.close(fd)
    try:
        writer(Path(tmp))
        os.chmod(tmp, 0o666 & ~_umask())            # the user's umask, not mkstemp's 0600
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
        self.cleaned = clean_stale(self.path)       # what killed runs left behind
        if self.cleaned:
            print(f"imurig: cleaned up after a killed run: {', '.join(q.name for q in self.cleaned)}", file=sys.stderr)
        self.tmp = Path(tempfile.mkdtemp(prefix=f".{self.path.name}.tmp-{os.getpid()}-", dir=self.path.parent))
        os.chmod(self.tmp, 0o777 & ~_umask())       # the user's umask, not mkdtemp's 0700

    def file(self, name: str) -> Path:
        return self.tmp / name

    def write_json(self, name: str, obj) -> Path:
        p = self.file(name)
        # strict JSON: a value that could not be computed (NaN, inf) is written as null
        p.write_text(json.dumps(clean_json(json.loads(to_json(obj))), indent=2, allow_nan=False) + "\n")
        return p

    def write_text(self, name: str, text: str) -> Path:
        p = self.file(name)
        p.write_text(text)
        return p

    def commit(self) -> Path:
        """Put the new folder in place: in one step where the system can swap two paths (a kill at any
        moment leaves the old output or the new one); else old aside, new in, old removed (a kill
        between the renames is repaired by the next run's :func:`clean_stale`)."""
        if self.path.exists():
            if not self.overwrite:
                raise OutputExistsError(f"{self.path} appeared while writing; pass --overwrite")
            if _exchange(self.tmp, self.path):
                shutil.rmtree(self.tmp)                 # now the old output
                return self.path
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
