"""A report's output made in a forked process (a core of its own), started before the fits.

The child first runs ``early = load(out, rec100)`` (heavy imports: matplotlib for the figures, rerun for
the .rrd; the figures, or the .rrd's entities, that need no fits) while the parent fits, then waits for
the fits the parent gives (:meth:`Beside.give`), makes its output with ``work(out, rec100, fits, early)``
and sends back what that returns (e.g. name -> file). Two of them (the figures,
the .rrd) and the parent's fits share the two cores. The child starts with what the parent had at the fork
(the 100 Hz record: nothing pickled but the fits). Where fork is not available, ``work(out, rec100,
fits, None)`` runs in :meth:`Beside.give`, here.

    figures = Beside(out, rec100, draw_record, draw_fits, "drawing the figures")
    ...                                  # the fits
    figures.give({"main": cal, ...})     # pickled to the child
    files = figures.wait()               # what draw returned; raises if it failed
"""
from __future__ import annotations

import multiprocessing

#: the parent's ends of every open Beside's pipes: a later fork inherits them, and closes its copies (an
#: earlier child sees the end of its pipe only when every copy of the parent's end is closed)
_PARENT_ENDS: list = []


class Beside:
    """``work(out, rec100, fits, early)`` in a forked child that ran ``early = load(out, rec100)`` first
    (module doc); ``what`` names the work in an error."""

    def __init__(self, out, rec100, load, work, what: str):
        self.out, self.rec100, self.work, self.what = out, rec100, work, what
        self.child, self.result = None, None
        if "fork" not in multiprocessing.get_all_start_methods():
            return
        ctx = multiprocessing.get_context("fork")
        fits, self._give = ctx.Pipe(duplex=False)
        self._answer, send = ctx.Pipe(duplex=False)
        self.child = ctx.Process(target=_child, args=(fits, send, out, rec100, load, work, self._ends()),
                                 daemon=True)
        self.child.start()
        send.close()
        fits.close()
        _PARENT_ENDS.extend(self._ends())

    def _ends(self) -> tuple:
        return (self._give, self._answer)

    def give(self, fits) -> None:
        """Start the work on ``fits`` (pickled to the child)."""
        if self.child is None:
            self.result = self.work(self.out, self.rec100, fits, None)
            return
        self._give.send(fits)
        self._close_give()

    def cancel(self) -> None:
        """No fits (an error in the parent): the child ends on the closed pipe, doing nothing (or, given them
        before the error, when its work is done)."""
        if self.child is not None:
            self._close_give()
            self.child.join()
            self._forget()

    def wait(self):
        """What ``work`` returned (raises a RuntimeError naming ``what`` if it failed)."""
        if self.child is None:
            return self.result
        try:
            got = self._answer.recv()
        except EOFError:
            got = None
        self.child.join()
        self._forget()
        if not isinstance(got, tuple) or self.child.exitcode:
            raise RuntimeError(f"{self.what} failed: {got[1] if isinstance(got, list) else 'the process ended'}")
        return got[0]

    def _close_give(self) -> None:
        if not self._give.closed:
            self._give.close()

    def _forget(self) -> None:
        for c in self._ends():
            if c in _PARENT_ENDS:
                _PARENT_ENDS.remove(c)
            if not c.closed:
                c.close()


def _child(fits, send, out, rec100, load, work, own) -> None:
    for c in _PARENT_ENDS + list(own):   # copies of the parent's ends (this one's and earlier ones')
        c.close()
    try:
        early = load(out, rec100)
        try:
            got = fits.recv()
        except EOFError:   # the parent stopped before the fits (an error there): nothing to do
            if hasattr(early, "abort"):   # e.g. an .rrd writer opened early: its temporary file removed
                early.abort()
            return
        send.send((work(out, rec100, got, early),))
    except Exception as e:  # reported by the parent, which fails the run
        send.send([None, f"{type(e).__name__}: {e}"])
    finally:
        send.close()
