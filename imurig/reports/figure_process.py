"""Figures (or any job) run in a forked process, on a second core, beside this process's work.

matplotlib holds the interpreter lock while it draws: in a thread it would take turns with the
simulation, the .rrd writer and the studies; in a forked child it runs beside them. The child starts with
what the parent had at the fork (nothing pickled) and runs jobs in the order they are given; later jobs
(a study's results, the rows of a record) are sent over a pipe. A job returns a file name or any picklable
value. Where fork is not available, each job runs here when it is given.

    figures = FigureProcess(out, [("residuals", _fig_residuals, (res,))])  # fork: the child has res
    ...                                     # the .rrd, the studies
    figures.draw("timers", _fig_timers, ts) # a study's results: pickled to the child
    writer.draw("rrd_start", _start, rows, beside=True)   # large: sent from a thread while this one works on
    files = figures.wait()                  # name -> file; raises if a figure failed
"""
from __future__ import annotations

import multiprocessing
import pickle
import threading
import weakref

#: the parent's ends of every live child's pipes: a child forked later closes its copies of them, so that no
#: child holds another's job pipe open (that child would then never see the end of its jobs)
_PARENT_ENDS: "weakref.WeakSet" = weakref.WeakSet()
#: the first message of a job sent with its buffers out of band: (this, number of buffers), then the pickle,
#: then each buffer (:meth:`FigureProcess._send`)
_OUT_OF_BAND = "imurig.figure_process.out_of_band"


class FigureProcess:
    """A forked child that draws figure jobs ``fn(out, *args) -> file name`` (module doc): ``first``, the
    jobs (name, fn, args) it has from the fork, then those given to :meth:`draw`. A job may return any
    picklable value (a study's results beside its figures). ``pyplot``: load matplotlib's pyplot (Agg) in the
    child before the first job (False for jobs that draw nothing, e.g. the .rrd)."""

    def __init__(self, out, first=(), pyplot: bool = True):
        self.out, self.child, self.figs = out, None, {}
        self._sending: threading.Thread | None = None   # a job being sent beside this process's work
        self._send_error: BaseException | None = None
        if "fork" not in multiprocessing.get_all_start_methods():
            if pyplot:
                import matplotlib  # heavy: loaded when figures are drawn

                matplotlib.use("Agg")
            for name, fn, args in first:
                self.draw(name, fn, *args)
            return
        ctx = multiprocessing.get_context("fork")
        jobs, self._jobs = ctx.Pipe(duplex=False)
        self._answer, send = ctx.Pipe(duplex=False)
        others = list(_PARENT_ENDS)
        self.child = ctx.Process(target=_child, args=(jobs, [self._jobs, *others], send, out, list(first), pyplot),
                                 daemon=True)
        self.child.start()
        send.close()
        jobs.close()
        _PARENT_ENDS.update((self._jobs, self._answer))

    def draw(self, name: str, fn, *args, beside: bool = False) -> None:
        """Draw ``fn(out, *args)`` (a module-level function returning the file it wrote) as figure ``name``.
        ``beside``: send the job (e.g. a record's rows, ~0.1 GB) from a thread, so that this process goes on
        while the child reads it; the next job, :meth:`wait` and :meth:`cancel` wait for it to be sent."""
        if self.child is None:
            self.figs[name] = fn(self.out, *args)
            return
        self._sent()
        if beside:
            self._sending = threading.Thread(target=self._send, args=((name, fn, args),), name=f"send {name}",
                                             daemon=True)
            self._sending.start()
        else:
            self._jobs.send((name, fn, args))

    def _send(self, job) -> None:
        """Send ``job`` with its arrays' buffers out of band (pickle protocol 5): each array's bytes go to the
        pipe from the array itself, not copied into one pickle first (~0.1 GB less in this process)."""
        try:
            buffers = []
            head = pickle.dumps(job, protocol=5, buffer_callback=buffers.append)
            raws = [b.raw() for b in buffers]
            self._jobs.send((_OUT_OF_BAND, [r.nbytes for r in raws]))
            self._jobs.send_bytes(head)
            for r in raws:
                self._jobs.send_bytes(r)
        except BaseException as e:   # raised by the next draw, wait or cancel
            self._send_error = e

    def _sent(self) -> None:
        """Wait for a job sent beside (:meth:`draw`); raise what sending it raised."""
        if self._sending is not None:
            self._sending.join()
            self._sending = None
        if self._send_error is not None:
            e, self._send_error = self._send_error, None
            raise RuntimeError(f"sending a job to the figure process failed: {e}") from e

    def cancel(self) -> None:
        """No more figures (an error in the parent): the child ends on the closed pipe."""
        if self.child is not None:
            if self._sending is not None:
                self._sending.join()
                self._sending, self._send_error = None, None
            self._jobs.close()
            self.child.join()
            self.child = None

    def wait(self) -> dict:
        """The figures drawn: name -> file (raises if drawing failed)."""
        if self.child is None:
            return self.figs
        self._sent()
        self._jobs.close()
        return answer(self.child, self._answer)


def answer(child, conn) -> dict:
    """The figures a figure process ``child`` sends on ``conn`` (name -> file), after it ends; a RuntimeError
    with its message if it failed or ended without an answer."""
    try:
        figs = conn.recv()
    except EOFError:
        figs = "the figure process ended without an answer"
    child.join()
    if not isinstance(figs, dict) or child.exitcode:
        raise RuntimeError(f"drawing the figures failed: {figs}")
    return figs


def _child(jobs, parent_ends, send, out, first, pyplot: bool = True) -> None:
    for end in parent_ends:   # the parent's ends (this child's and earlier children's), copied by the fork:
        end.close()           # closed here, so the parent closing each ends its child's recv()
    figs = {}
    try:
        if pyplot:
            import matplotlib  # loaded while the parent works

            matplotlib.use("Agg")
            import matplotlib.pyplot  # noqa: F401
        for name, fn, args in first:
            figs[name] = fn(out, *args)
        while True:
            try:
                job = jobs.recv()
                if job[0] == _OUT_OF_BAND:   # a job sent beside, its buffers out of band (FigureProcess._send)
                    head, buffers = jobs.recv_bytes(), [bytearray(n) for n in job[1]]   # writable, as pickled arrays are
                    for b in buffers:
                        jobs.recv_bytes_into(b)
                    job = pickle.loads(head, buffers=buffers)
            except EOFError:   # the parent's last job given (or the parent stopped)
                break
            name, fn, args = job
            figs[name] = fn(out, *args)
        send.send(figs)
    except Exception as e:  # reported by the parent, which fails the run
        send.send(f"{type(e).__name__}: {e}")
    finally:
        send.close()
