"""The tilt table of a campaign, and its run (MuJoCo for the moves) started ahead, beside the imports.

:func:`build_table` is the rig part of :meth:`imurig.campaigns.tilt_table.TiltTableCampaign.build`: the
table's errors and the lab's inclinometer survey, drawn from the campaign's seeded streams ``table`` and
``survey`` (:mod:`imurig.kernel.random_streams`). It needs the rig's module only (MuJoCo and numpy), not
the sensor chain and the calibration (scipy: ~2 CPU-s of imports), so the command line can start the run
before it loads them:

    ahead = RigAhead.start(seed=..., protocol=..., start_time=..., lab=...)   # the run; its moves forked
    from imurig.campaigns.tilt_table import TiltTableCampaign                # imports, beside MuJoCo
    run = ahead.take(camp)   # the run, if made for this campaign's settings, else None

The run is made in the caller's thread (the servo commands, ~0.3 CPU-s); its MuJoCo moves are stepped in a
forked process, with an interpreter lock of its own, so that the imports (which hold this one's) and the
moves use the two cores; the moves go on, in record order, while the stream starts, their rows sent back
and filled in here (its truth rows wait for the moves they read). Where fork is missing (or with
``process=False``) a thread makes the run and steps the moves, taking turns with the imports for the lock.
The run is what ``table.run(protocol, start_time, generator("campaign/tilt-table/rig", seed))`` gives in the
campaign itself: the same streams, the same data bit for bit.
"""
from __future__ import annotations

import multiprocessing
import threading
from dataclasses import replace

from imurig.kernel import random_streams
from imurig.kernel.site import Site
from imurig.kernel.units import ARCSEC
from imurig.rigs.tilt_table import TableSurvey, TiltTable, TiltTableErrors, TiltTableProtocol

#: longest wait (s) in :meth:`RigAhead.start` for MuJoCo to start stepping
PYTHON_WAIT_S = 5.0
#: the campaign's settings that decide the rig's run (TiltTableCampaign fields)
RIG_FIELDS = ("seed", "protocol", "start_time", "draw_table_errors", "survey_accuracy_arcsec", "site", "lab")


def build_table(seed: int, protocol: TiltTableProtocol, draw_table_errors: bool = True,
                survey_accuracy_arcsec: float = 2.0, site: Site | None = None, lab: str = "quiet") -> TiltTable:
    """The campaign's tilt table: its errors (stream ``table``; none with ``draw_table_errors`` false),
    the survey of them (stream ``survey``, accuracy in arcsec), the Delft 2005 lab's setting resolution
    for ``lab`` "delft-2005"."""
    errors = (TiltTableErrors.draw(random_streams.generator("table", seed), protocol.runs) if draw_table_errors
              else TiltTableErrors(phi_zero_rad={r: 0.0 for r in protocol.runs}, theta_zero_rad=0.0,
                                   level_x_rad=0.0))
    survey = TableSurvey.measure(errors, random_streams.generator("survey", seed), survey_accuracy_arcsec * ARCSEC)
    if lab != "quiet":   # the preset's module is heavy (the lab's effects): loaded for its lab only
        from imurig.campaigns.delft_2005 import Delft2005, check_lab

        check_lab(lab)
        errors = replace(errors, setting_resolution_rad=Delft2005.fitted().setting_error_rad)
    return TiltTable(errors=errors, survey=survey, site=site if site is not None else Site())


def run_table(table: TiltTable, protocol: TiltTableProtocol, start_time: str, seed: int, defer=None):
    """The table's run of the protocol (:meth:`TiltTable.run`) on the campaign's stream
    ``campaign/tilt-table/rig``; ``defer``: MuJoCo's moves later (:meth:`TiltTable.run`)."""
    return table.run(protocol, start_time, random_streams.generator("campaign/tilt-table/rig", seed), defer)


class RigAhead:
    """The rig run of a campaign's settings (:data:`RIG_FIELDS`), made in a background thread from
    :meth:`start`; :meth:`take` gives it to the campaign with the same settings (waiting for it)."""

    def __init__(self, settings: dict):
        self.settings = {k: settings.get(k) for k in RIG_FIELDS}
        self._result = self._error = None
        self._ready = threading.Event()
        self._thread = threading.Thread(target=self._work, name="tilt-rig-ahead", daemon=True)

    @classmethod
    def start(cls, wait_s: float = PYTHON_WAIT_S, process: bool = True, **settings) -> "RigAhead":
        """Start the run of the campaign with these settings (:data:`RIG_FIELDS`; the defaults of
        :class:`imurig.campaigns.tilt_table.TiltTableCampaign` for those not given). Returns when the run is
        made and MuJoCo starts stepping its moves: in a forked process (``process``, where fork exists), else
        in a thread (then after ``wait_s`` at most). The run's own Python work (the commands) is done before
        the caller's imports, which would otherwise take turns with it for the interpreter lock."""
        d = {"start_time": "2005-06-14T18:00:00+02:00", "draw_table_errors": True, "survey_accuracy_arcsec": 2.0,
             "site": Site(), "lab": "quiet", **settings}
        ahead = cls(d)
        if process and "fork" in multiprocessing.get_all_start_methods():
            ahead._fork()
            return ahead
        ahead._thread.start()
        ahead._ready.wait(wait_s)
        return ahead

    def _fork(self) -> None:
        """The run made here (the caller's thread), its moves stepped in a forked process (its own interpreter
        lock: beside the caller's imports and the stream, not taking turns with them), their rows sent back
        and filled in by a thread here (:meth:`imurig.rigs.truth_pieces.TruthPieces.receive`)."""
        jobs = []
        try:
            self._run(jobs)
        finally:
            self._ready.set()
        if not jobs:   # no run (its error is kept for take()), or no moves
            return
        pieces = self._result[1].truth_source   # the pieces the moves fill (TruthPieces)
        ctx = multiprocessing.get_context("fork")
        recv, send = ctx.Pipe(duplex=False)
        child = ctx.Process(target=_step_moves, args=(jobs, pieces, send), name="tilt-rig-moves", daemon=True)
        child.start()
        send.close()

        def receive():
            try:
                pieces.receive(recv.recv)
            finally:
                recv.close()
                child.join()

        threading.Thread(target=receive, name="tilt-rig-moves-received", daemon=True).start()

    def _run(self, jobs: list) -> None:
        s = self.settings
        try:
            table = build_table(s["seed"], s["protocol"], s["draw_table_errors"], s["survey_accuracy_arcsec"],
                                s["site"], s["lab"])
            self._result = (table, run_table(table, s["protocol"], s["start_time"], s["seed"], jobs.append))
        except BaseException as e:   # given to the caller of take()
            self._error = e

    def _work(self) -> None:
        jobs = []
        try:
            self._run(jobs)
        finally:
            self._ready.set()
        for job in jobs:   # the moves, in record order; a failure reaches the truth's reader (TruthPieces.rows)
            try:
                job()
            except BaseException:
                pass

    def take(self, camp) -> tuple | None:
        """(table, run) if this run was made for ``camp``'s settings, else None (the campaign runs its own);
        raises what the run raised. Waits for the run, not for its moves: MuJoCo steps them on in this
        thread, beside the stream, whose truth rows wait for the moves they read."""
        self._ready.wait()
        if any(getattr(camp, k) != v for k, v in self.settings.items()):
            return None
        if self._error is not None:
            raise self._error
        return self._result


def _step_moves(jobs, pieces, conn) -> None:
    """The forked process of :meth:`RigAhead._fork`: MuJoCo's moves, their rows sent to the parent's pieces."""
    pieces.relay(conn.send)
    for job in jobs:   # a failure is sent by the job (TruthPieces.fail)
        try:
            job()
        except BaseException:
            pass
    conn.close()
