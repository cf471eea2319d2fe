"""Output folders: the old output or the new one at any moment, the user's umask, and what killed
runs leave behind cleaned by the next run."""
from __future__ import annotations

import os
import subprocess
import sys

import pytest

from imurig.kernel.errors import OutputExistsError
from imurig.kernel.outputs import OutputFolder, atomic_write


def test_replacing_an_output_swaps_it_whole(tmp_path):
    with OutputFolder(tmp_path / "r") as o:
        o.write_text("a.txt", "old")
    with pytest.raises(OutputExistsError, match="--overwrite"):
        OutputFolder(tmp_path / "r")
    with pytest.raises(RuntimeError):
        with OutputFolder(tmp_path / "r", overwrite=True) as o:
            o.write_text("a.txt", "half")
            raise RuntimeError("the run fails")
    assert (tmp_path / "r" / "a.txt").read_text() == "old" and os.listdir(tmp_path) == ["r"]
    with OutputFolder(tmp_path / "r", overwrite=True) as o:
        o.write_text("a.txt", "new")
    assert (tmp_path / "r" / "a.txt").read_text() == "new" and os.listdir(tmp_path) == ["r"]


def test_outputs_follow_the_umask(tmp_path):
    old = os.umask(0o002)
    try:
        with OutputFolder(tmp_path / "r") as o:
            o.write_text("a.txt", "x")
        atomic_write(tmp_path / "f.txt", lambda p: p.write_text("y"), overwrite=False)
    finally:
        os.umask(old)
    assert (tmp_path / "r").stat().st_mode & 0o777 == 0o775
    assert (tmp_path / "r" / "a.txt").stat().st_mode & 0o777 == 0o664
    assert (tmp_path / "f.txt").stat().st_mode & 0o777 == 0o664


def test_a_killed_run_is_cleaned_up_by_the_next(tmp_path, capsys):
    code = ("import os, sys; from imurig.kernel.outputs import OutputFolder; "
            "o = OutputFolder(sys.argv[1]); o.write_text('x', '1'); os._exit(9)")
    subprocess.run([sys.executable, "-c", code, str(tmp_path / "k")], check=False)
    left = [p for p in os.listdir(tmp_path) if p.startswith(".k.tmp-")]
    assert len(left) == 1
    with OutputFolder(tmp_path / "k") as o:
        o.write_text("x", "2")
    assert os.listdir(tmp_path) == ["k"] and "cleaned up after a killed run" in capsys.readouterr().err
    # a kill between the two renames of a replacement (old aside, new not yet in): the old comes back
    os.rename(tmp_path / "k", tmp_path / ".k.old")
    with OutputFolder(tmp_path / "other"):
        pass
    OutputFolder(tmp_path / "k", overwrite=True).abort()
    assert (tmp_path / "k" / "x").read_text() == "2" and not (tmp_path / ".k.old").exists()
