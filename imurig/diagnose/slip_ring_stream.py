"""The slip-ring test (:meth:`imurig.sensors.effects.slip_rings.SlipRingNoise.test`) on windows that
come one at a time, in memory of one window, whatever their number.

``pieces()`` gives each window's (angle, residual, signal, time) afresh on every call (the turn
record reads them again from the file). The test's statistics, per the effect's own definitions:

- Brown-Forsythe within windows: each (window, bin) cell's median is a window's own; the window's
  mean of z = |r - median| too; the bins' counts, sums and sums of squares of z' add over windows
  (``brown_forsythe_from``);
- the robust noise by bin, 1.4826 median |r - median(r)| over all windows' samples of a bin: exact
  order statistics in passes (:class:`imurig.kernel.ranks.RankSearch`, one per bin, their brackets
  from a thinned subsample; at most ``LIMIT`` distinct values kept and ``FEED`` values gathered per bin);
- the refit: each bin's mean of r^2 and the variance of r^2 from sums (``refit_from``);
- the ripple: the Gram matrix of each window's detrended columns, summed (``ripple_from_gram``).

The values equal the pooled test's but for the order of the sums (rounding); the medians are exact.
A record of a single window is tested as the effect tests it (its samples are one window's).
"""
from __future__ import annotations

import numpy as np

from imurig.kernel.ranks import median_search
from imurig.sensors.effects.slip_rings import SlipRingNoise
from imurig.sensors.effects.views import TurnSampleView

#: distinct values a bin's order-statistic search keeps before it narrows its bracket instead
LIMIT = 1 << 16
#: values per bin kept (thinned by halves) to bracket its order statistics
THIN = 1 << 14
#: values per bin gathered before they are fed to its search
FEED = 1 << 14


class _Thinned:
    """Every k-th value fed, k doubling whenever more than ``THIN`` are kept (bounded, spread over all)."""

    def __init__(self):
        self.kept, self.count, self.k, self.seen = [], 0, 1, 0

    def feed(self, v: np.ndarray) -> None:
        take = v[(-self.seen) % self.k::self.k].copy()       # a view would keep the whole window
        self.seen += v.size
        self.kept.append(take)
        self.count += take.size
        if self.count > THIN:
            a = np.concatenate(self.kept)[::2]
            self.kept, self.count, self.k = [a], a.size, self.k * 2

    def values(self) -> np.ndarray:
        return np.concatenate(self.kept) if self.kept else np.zeros(0)


def streamed_slip_ring_test(eff: SlipRingNoise, view: TurnSampleView, pieces) -> dict:
    """:meth:`SlipRingNoise.test` of the pooled windows ``pieces()`` (module doc); ``view`` gives the
    channel, ``alpha`` and ``quantum_V``. {"tested": False} without a window."""
    B, h = eff.n_bins, 4
    G = np.zeros((3 + 2 * h, 3 + 2 * h))
    n_b = np.zeros(B, np.int64)
    s1, s2, g2, g4 = (np.zeros(B) for _ in range(4))
    thin = [_Thinned() for _ in range(B)]
    W = 0
    for ang, res, sig, tim in pieces():
        idx = eff.bin_index(ang)
        A = eff.ripple_columns(sig, ang, tim, h)
        G += A.T @ A
        order = np.argsort(idx, kind="stable")
        bounds = np.cumsum(np.bincount(idx, minlength=B))[:-1]
        med = np.zeros(B)
        for b, g in enumerate(np.split(res[order], bounds)):
            if g.size:
                med[b] = np.median(g)
                thin[b].feed(g)
        z = np.abs(res - med[idx])
        z = z - np.bincount(np.zeros(z.size, np.int64), z)[0] / z.size     # the window's mean, as pooled
        n_b += np.bincount(idx, minlength=B)
        s1 += np.bincount(idx, z, B)
        s2 += np.bincount(idx, z * z, B)
        g2 += np.bincount(idx, res**2, B)
        g4 += np.bincount(idx, res**4, B)
        W += 1
    if W == 0:
        return {"tested": False}
    if W == 1 or np.any(n_b < 2):          # one window (or an empty bin): the effect's own test on the samples
        parts = list(pieces())
        cat = [np.concatenate([p[k] for p in parts]) for k in range(4)]
        one = TurnSampleView(channel=view.channel, angle_rad=cat[0], residual_V=cat[1], alpha=view.alpha,
                             signal_V=cat[2], quantum_V=view.quantum_V,
                             window=np.concatenate([np.full(p[0].size, i) for i, p in enumerate(parts)]),
                             time_s=cat[3])
        return {"tested": True, **eff.test(one)}
    gm = s1 / np.maximum(n_b, 1)
    ss_within = float(np.sum(s2 - 2 * gm * s1 + n_b * gm**2))
    stat, p = eff.brown_forsythe_from(n_b, gm, ss_within, W)
    centre = _bin_medians(eff, pieces, n_b, [t.values() for t in thin], lambda b, g: g)
    mad = _bin_medians(eff, pieces, n_b, [np.abs(t.values() - centre[b]) for b, t in enumerate(thin)],
                       lambda b, g: np.abs(g - centre[b]))
    spread = 1.4826 * mad
    v = g2 / n_b
    se = np.sqrt((g4 - n_b * v**2) / (n_b - 1) / n_b)
    ripple = eff.ripple_from_gram(G, int(n_b.sum()), W, view.quantum_V, view.alpha, h)
    return {"tested": True, **eff.verdict(view, int(n_b.sum()), stat, p, spread, lambda: eff.refit_from(v, se), ripple)}


def _bin_medians(eff: SlipRingNoise, pieces, n_b: np.ndarray, samples: list, value) -> np.ndarray:
    """np.median of value(b, residuals of bin b) over all windows, per bin: passes over ``pieces()``."""
    B = eff.n_bins
    searches = [median_search(int(n_b[b]), samples[b], limit=LIMIT) for b in range(B)]
    todo = set(range(B))
    while todo:
        buf, size = [[] for _ in range(B)], np.zeros(B, np.int64)
        for ang, res, _, _ in pieces():
            idx = eff.bin_index(ang)
            order = np.argsort(idx, kind="stable")
            for b, g in enumerate(np.split(res[order], np.cumsum(np.bincount(idx, minlength=B))[:-1])):
                if b in todo and g.size:
                    buf[b].append(np.array(value(b, g)))          # a copy: a view would keep the window
                    size[b] += g.size
                    if size[b] >= FEED:                          # fed in batches: fewer, larger sorts
                        searches[b].feed(np.concatenate(buf[b]))
                        buf[b], size[b] = [], 0
        for b in todo:
            if buf[b]:
                searches[b].feed(np.concatenate(buf[b]))
        todo = {b for b in todo if not searches[b].end()}
    return np.array([s.median() for s in searches])
