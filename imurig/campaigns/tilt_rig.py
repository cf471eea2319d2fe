"""The tilt table of a campaign, and its run (MuJoCo for the moves) started ahead, beside the imports.

:func:`build_table` is the rig part of :meth:`imurig.campaigns.tilt_table.TiltTableCampaign.build`: the
table's errors and the lab's inclinometer survey, drawn from the campaign's seeded streams ``table`` and
``survey`` (:mod:`imurig.kernel.random_streams`). It needs the rig's module only (MuJoCo and numpy), not
the sensor chain and the calibration (scipy: ~2 CPU-s of imports), so the command line can start the run
before it loads them:

    ahead = RigAhead.start(seed=..., protocol=..., start_time=..., lab=...)   # a thread: the table's run
    from imurig.campaigns.tilt_table import TiltTableCampaign                # imports, beside MuJoCo
    run = ahead.take(camp)   # the run, if made for this campaign's settings, else None

MuJoCo's rollouts run without the interpreter lock, so the imports (which hold it) and the moves share
the two cores; the moves go on, in record order, while the stream starts (its truth rows wait for the
moves they read). The run is what ``table.run(protocol, start_time, generator("campaign/tilt-table/rig",
seed))`` gives in the campaign itself: the same streams, the same data bit for bit.
"""
from __future__ import annotations

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
    def start(cls, wait_s: float = PYTHON_WAIT_S, **settings) -> "RigAhead":
        """Start the run of the campaign with these settings (:data:`RIG_FIELDS`; the defaults of
        :class:`imurig.campaigns.tilt_table.TiltTableCampaign` for those not given). Returns when the run is
        made and MuJoCo starts stepping its moves (or after ``wait_s``): the run's own Python work (the
        commands, ~0.5 CPU-s) is done before the caller's imports, which would otherwise take turns with it
        for the interpreter lock."""
        d = {"start_time": "2005-06-14T18:00:00+02:00", "draw_table_errors": True, "survey_accuracy_arcsec": 2.0,
             "site": Site(), "lab": "quiet", **settings}
        ahead = cls(d)
        ahead._thread.start()
        ahead._ready.wait(wait_s)
        return ahead

    def _work(self) -> None:
        s, jobs = self.settings, []
        try:
            table = build_table(s["seed"], s["protocol"], s["draw_table_errors"], s["survey_accuracy_arcsec"],
                                s["site"], s["lab"])
            self._result = (table, run_table(table, s["protocol"], s["start_time"], s["seed"], jobs.append))
        except BaseException as e:   # given to the caller of take()
            self._error = e
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
