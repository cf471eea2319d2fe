"""imurig.reports.figure_process: figure jobs drawn in a forked child, in order, with their errors reported."""
from __future__ import annotations

import multiprocessing
import sys

import numpy as np
import pytest

from imurig.kernel.outputs import OutputFolder
from imurig.reports.figure_process import FigureProcess

#: a platform guard: on Linux (CI) fork is there and every case runs
FORK = "fork" in multiprocessing.get_all_start_methods()
needs_fork = pytest.mark.skipif(not FORK, reason="no fork on this platform")


def _write(out, name, text):
    """A 'figure': a text file (the child writes it into the parent's folder)."""
    out.file(name).write_text(text)
    return name


def _fail(out, *_):
    raise ValueError("no data to draw")


@pytest.mark.parametrize("fork", [pytest.param(True, marks=needs_fork), False])
def test_jobs_from_the_fork_and_the_pipe_are_drawn_in_order(tmp_path, monkeypatch, fork):
    if not fork:   # where fork is missing, the jobs are drawn in this process as they are given
        monkeypatch.setattr(multiprocessing, "get_all_start_methods", lambda: ["spawn"])
    big = list(range(100_000))   # the child has it from the fork (a local: it could not be pickled by reference)
    with OutputFolder(tmp_path / "out") as out:
        figures = FigureProcess(out, [("a", _write, ("a.txt", str(len(big)))), ("b", _write, ("b.txt", "b"))])
        assert (figures.child is not None) == fork
        figures.draw("c", _write, "c.txt", "given later")
        figs = figures.wait()
    assert list(figs) == ["a", "b", "c"]
    assert (tmp_path / "out" / "a.txt").read_text() == "100000"
    assert (tmp_path / "out" / "c.txt").read_text() == "given later"


@needs_fork
def test_a_failing_figure_fails_the_wait(tmp_path):
    out = OutputFolder(tmp_path / "out")
    with pytest.raises(RuntimeError, match="ValueError: no data to draw"):
        with out:
            figures = FigureProcess(out, [("a", _write, ("a.txt", "a"))])
            figures.draw("b", _fail)
            figures.wait()


@needs_fork
def test_cancel_ends_the_child(tmp_path):
    with OutputFolder(tmp_path / "out") as out:
        figures = FigureProcess(out)
        child = figures.child
        figures.cancel()
        assert not child.is_alive() and figures.wait() == {}


def _value(out, x):
    """A job that draws nothing and returns a value (a study's results)."""
    return {"x": x, "pyplot": "matplotlib.pyplot" in sys.modules}


@needs_fork
def test_a_job_returns_its_value_and_pyplot_loads_only_when_asked(tmp_path):
    """Also: a child forked later does not hold an earlier child's job pipe open (waited first, it would hang)."""
    loaded = "matplotlib.pyplot" in sys.modules   # a child has what this process had at the fork
    with OutputFolder(tmp_path / "out") as out:
        bare = FigureProcess(out, [("v", _value, (3,))], pyplot=False)
        drawing = FigureProcess(out, [("v", _value, ([4],))])
        assert bare.wait() == {"v": {"x": 3, "pyplot": loaded}}
        assert drawing.wait() == {"v": {"x": [4], "pyplot": True}}


def _size(out, x):
    """A job that returns the size and the sum of what it was sent, and whether it can write to it."""
    return int(x.size), int(x.sum(dtype=np.int64)), bool(x.flags.writeable)


def _unpicklable(out, x):
    return x


@needs_fork
def test_a_job_sent_beside_arrives_whole_and_in_order(tmp_path):
    """``beside``: a large job sent from a thread while this process goes on; the next job follows it on the
    pipe, and ``wait`` has both."""
    with OutputFolder(tmp_path / "out") as out:
        figures = FigureProcess(out, pyplot=False)
        big = np.arange(8_000_000, dtype=np.int16)   # 16 MB: more than a pipe holds; its bytes sent out of band
        figures.draw("big", _size, big, beside=True)
        figures.draw("after", _write, "after.txt", "after")
        assert figures.wait() == {"big": (big.size, int(big.sum(dtype=np.int64)), True), "after": "after.txt"}


@needs_fork
def test_a_job_that_cannot_be_sent_beside_fails_the_next_call(tmp_path):
    out = OutputFolder(tmp_path / "out")
    with pytest.raises(RuntimeError, match="sending a job to the figure process failed"):
        with out:
            figures = FigureProcess(out, pyplot=False)
            figures.draw("lambda", _unpicklable, lambda: None, beside=True)   # a lambda cannot be pickled
            try:
                figures.wait()
            finally:
                figures.cancel()
