"""A rig's truth signals over a record as pieces, filled as the rig's moves are stepped: constants where it
rests, rows or knots (linear between them) where it moves; any sample range on demand, waiting for the
moves it reads (:func:`imurig.rigs.tilt_truth.stitched_pieces` makes them for the tilt table).

The moves may be filled in another thread, or in a forked process whose copy relays them here
(:meth:`TruthPieces.relay`, :meth:`TruthPieces.receive`).
"""
from __future__ import annotations

import threading

import numpy as np


class TruthPieces:
    """The truth signals ``names`` (e.g. :data:`imurig.rigs.tilt_truth.SIGNALS`) over ``n`` samples as
    pieces: constants in the windows, MuJoCo rows (every sample stepped) or knots (linear between them) in
    the moves. :meth:`rows` gives any sample range, the same values as the whole arrays would hold.

    The moves may be filled after :meth:`done` (in another thread, in record order): :meth:`rows` waits
    until every sample it reads is filled (:meth:`filled`), or raises what the filling raised."""

    def __init__(self, n: int, names: tuple[str, ...]):
        self.n, self.names = n, tuple(names)
        self._holds: list[tuple[int, int, dict]] = []
        self._slots: dict[int, list] = {}  # move start -> [start, stop, knots (None: rows), values]
        self._hold_at: dict[int, dict] = {}
        self._cond = threading.Condition()
        self._filled_to, self._error = 0, None
        self._relay, self._outbox = None, []

    def hold(self, a: int, b: int, values: dict) -> None:
        """Samples [a, b) hold the constants ``values`` (name -> float)."""
        self._holds.append((a, b, values))
        self._hold_at[a] = values

    def value_at(self, i: int, name: str) -> float:
        """The held value of ``name`` at sample ``i`` (a window's first sample)."""
        return self._hold_at[i][name]

    def expect(self, a: int, b: int) -> None:
        """Samples [a, b) are a move, filled later by :meth:`move`."""
        self._slots[a] = [a, b, None, None]

    def move(self, a: int, b: int, knots: np.ndarray | None, values: dict) -> None:
        """Samples [a, b) of a move: ``values`` name -> rows (b - a,) (``knots`` None), or name -> values at
        the sample offsets ``knots`` plus the value at b (linear in between)."""
        if self._relay is not None:   # filled in another process's copy (:meth:`relay`)
            self._outbox.append((a, b, knots, values))
            return
        slot = self._slots.setdefault(a, [a, b, None, None])
        slot[2], slot[3] = knots, values

    def done(self) -> "TruthPieces":
        self._pieces = sorted([(a, b, None, v) for a, b, v in self._holds] + list(self._slots.values()),
                              key=lambda p: p[0])
        self._starts = np.array([p[0] for p in self._pieces], dtype=np.int64)
        return self

    def filled(self, upto: int) -> None:
        """Every sample before ``upto`` is filled."""
        if self._relay is not None:
            moves, self._outbox = self._outbox, []
            self._relay(("moves", moves, int(upto)))
            return
        with self._cond:
            self._filled_to = max(self._filled_to, int(upto))
            self._cond.notify_all()

    def fail(self, error: BaseException) -> None:
        """Filling the moves failed: :meth:`rows` raises it."""
        if self._relay is not None:
            self._relay(("failed", f"{type(error).__name__}: {error}"))
            return
        with self._cond:
            self._error = error
            self._cond.notify_all()

    def relay(self, send) -> None:
        """Make this copy (in a forked process that steps the moves) fill the original in the process it was
        forked from: each :meth:`move` is kept, and each :meth:`filled` sends ``("moves", [(a, b, knots,
        values), ...], upto)`` through ``send``, each :meth:`fail` ``("failed", message)``, for
        :meth:`receive` there."""
        self._relay, self._outbox = send, []

    def receive(self, recv) -> None:
        """Fill these pieces from a relaying copy (:meth:`relay`): ``recv()`` gives its messages until the last
        move is filled; its failure, or its end before then, fails these pieces (:meth:`fail`)."""
        try:
            while self._filled_to < self.n:
                msg = recv()
                if msg[0] == "failed":
                    self.fail(RuntimeError(msg[1]))
                    return
                for a, b, knots, values in msg[1]:
                    self.move(a, b, knots, values)
                self.filled(msg[2])
        except (EOFError, OSError) as e:
            self.fail(RuntimeError(f"the process stepping the moves ended before the last one ({e!r})"))

    def rows(self, a: int, b: int) -> dict:
        """Truth signals over samples [a, b): name -> (b - a,) float64 (waiting for their moves)."""
        if self._filled_to < b:
            with self._cond:
                self._cond.wait_for(lambda: self._error is not None or self._filled_to >= b)
        if self._error is not None:
            raise RuntimeError(f"the tilt table's moves (MuJoCo) failed: {self._error}") from self._error
        out = {k: np.empty(b - a) for k in self.names}
        first = max(int(np.searchsorted(self._starts, a, side="right")) - 1, 0)
        for lo, hi, knots, vals in self._pieces[first:]:
            if lo >= b:
                break
            s, e = max(lo, a), min(hi, b)
            if s >= e:
                continue
            for k in self.names:
                v = vals[k]
                if np.ndim(v) == 0:
                    out[k][s - a:e - a] = v
                elif knots is None:
                    out[k][s - a:e - a] = v[s - lo:e - lo]
                else:
                    out[k][s - a:e - a] = np.interp(np.arange(s - lo, e - lo, dtype=float), knots, v)
        return out
