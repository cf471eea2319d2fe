"""Exact order statistics (np.median's values, not estimates) of numbers that are read in passes
over a file, in memory bounded by a limit on distinct values, not by how many there are.

A :class:`RankSearch` holds a bracket [lo, hi] that should contain the wanted ranks (first from a
strided subsample's quantiles with a wide margin). A pass counts the values below lo exactly and
keeps the distinct values inside the bracket with their counts. When the wanted ranks fall inside
and at most ``limit`` distinct values were kept, the order statistics are exact; otherwise the
bracket is narrowed to the histogram bins that hold the ranks (or widened to the values' range
when a rank fell outside), and another pass is asked for. Each pass counts from scratch, so a
poor first bracket costs passes, never a wrong value.
"""
from __future__ import annotations

import numpy as np

#: distinct values kept inside a bracket before it is narrowed instead
LIMIT = 1 << 20
#: histogram bins of a bracket, for narrowing it
BINS = 4096


class RankSearch:
    """The values of ranks ``ranks`` (0-based, ascending order) of ``m`` numbers fed in passes."""

    def __init__(self, m: int, ranks, sample: np.ndarray, margin: float = 12.0, limit: int = LIMIT):
        self.m, self.ranks, self.limit = int(m), sorted(int(r) for r in ranks), int(limit)
        s = np.sort(np.asarray(sample, float))
        if s.size:
            p = np.array([self.ranks[0], self.ranks[-1]]) / max(self.m - 1, 1)
            w = margin * np.sqrt(0.25 / s.size) + 1.0 / s.size
            i = np.clip(np.round((p + np.array([-w, w])) * (s.size - 1)).astype(int), 0, s.size - 1)
            self.lo, self.hi = float(s[i[0]]), float(s[i[1]])
        else:
            self.lo, self.hi = -np.inf, np.inf
        self.result: list[float] | None = None
        self._range = (np.inf, -np.inf)
        self.begin()

    def begin(self) -> None:
        """Start a pass."""
        self._below, self._kept, self._distinct, self._over = 0, [], 0, False
        self._hist = np.zeros(BINS, np.int64) if np.isfinite(self.lo) and np.isfinite(self.hi) and \
            self.hi > self.lo else None

    def feed(self, v: np.ndarray) -> None:
        """The next values of the pass."""
        if v.size == 0:
            return
        self._range = (min(self._range[0], float(v.min())), max(self._range[1], float(v.max())))
        self._below += int(np.count_nonzero(v < self.lo))
        inside = v[(v >= self.lo) & (v <= self.hi)]
        if self._hist is not None:
            self._hist += np.histogram(inside, BINS, (self.lo, self.hi))[0]
        if not self._over and inside.size:
            self._kept.append(np.unique(inside, return_counts=True))
            self._distinct += self._kept[-1][0].size
            if self._distinct > self.limit:
                self._kept = [self._merged()]
                self._distinct = self._kept[0][0].size
                self._over = self._distinct > self.limit
                if self._over:
                    self._kept = []

    def _merged(self):
        vals = np.concatenate([k[0] for k in self._kept])
        cnts = np.concatenate([k[1] for k in self._kept])
        u, inv = np.unique(vals, return_inverse=True)
        return u, np.bincount(inv, weights=cnts).astype(np.int64)

    def end(self) -> bool:
        """Close the pass: True when the order statistics are found (:attr:`result`), else the
        bracket is moved and another pass is needed."""
        u, c = self._merged() if self._kept else (np.zeros(0), np.zeros(0, np.int64))
        inside = int(c.sum()) if not self._over else int(self._hist.sum()) if self._hist is not None else 0
        miss = any(r < self._below or r >= self._below + inside for r in self.ranks)
        if not miss and not self._over:
            cum = self._below + np.cumsum(c)
            self.result = [float(u[np.searchsorted(cum, r, side="right")]) for r in self.ranks]
            return True
        if miss or self._hist is None:
            self.lo, self.hi = self._range
        else:
            cum = self._below + np.cumsum(self._hist)
            j = [int(np.searchsorted(cum, r, side="right")) for r in self.ranks]
            edges = np.linspace(self.lo, self.hi, BINS + 1)
            # one bin more on each side: np.histogram's bin of a value near an edge may differ from linspace's
            self.lo, self.hi = float(edges[max(min(j) - 1, 0)]), float(edges[min(max(j) + 2, BINS)])
        self.begin()
        return False

    def median(self) -> float:
        """np.median's value from ranks (m - 1) // 2 and m // 2."""
        a, b = self.result[0], self.result[-1]
        return float(np.mean(np.array([a, b]))) if self.m % 2 == 0 else float(b)


def median_search(m: int, sample: np.ndarray, **kw) -> RankSearch:
    """A :class:`RankSearch` for np.median of m values."""
    return RankSearch(m, ((m - 1) // 2, m // 2), sample, **kw)
