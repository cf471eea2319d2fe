"""The layers hold: `lint-imports` passes on the contracts in pyproject.toml.

The design card's top-level folders (rigs/, sensors/, calibration/, flights/, assets/) install
inside the `imurig` namespace through setuptools' package-dir mapping, which import-linter's
module finder cannot see. The check therefore lays the installed tree out as links in a
temporary folder (imurig/ with rigs, sensors, ... beside its own subpackages) and runs
`lint-imports` against that tree with the repository's pyproject.toml.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MAPPED = ("rigs", "sensors", "calibration", "flights", "assets")


def package_tree(dest: Path) -> Path:
    """A link tree of the `imurig` package as it installs; returns the folder to put on sys.path."""
    pkg = dest / "imurig"
    pkg.mkdir(parents=True)
    for entry in (ROOT / "imurig").iterdir():
        if entry.name != "__pycache__":
            (pkg / entry.name).symlink_to(entry)
    for name in MAPPED:
        (pkg / name).symlink_to(ROOT / name)
    return dest


def lint_imports(tmp: Path) -> subprocess.CompletedProcess:
    exe = shutil.which("lint-imports", path=str(Path(sys.executable).parent)) or shutil.which("lint-imports")
    if exe is None:
        pytest.fail("lint-imports is not installed: pip install -e '.[test]' installs it (import-linter)")
    env = dict(os.environ, PYTHONPATH=str(package_tree(tmp)))
    return subprocess.run([exe, str(ROOT / "pyproject.toml"), "--no-cache"], cwd=tmp, env=env,
                          capture_output=True, text=True, timeout=300)


def test_layers_and_no_cycles(tmp_path):
    run = lint_imports(tmp_path)
    assert run.returncode == 0, run.stdout[-6000:] + run.stderr[-2000:]


if __name__ == "__main__":  # `python tests/test_architecture.py`: the same check, with lint-imports' report
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        r = lint_imports(Path(d))
        print(r.stdout, r.stderr)
        raise SystemExit(r.returncode)
