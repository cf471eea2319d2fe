"""A turn-table record's rows as the .rrd shows them, without rerun: its 10 Hz block means, raw and calibrated.

The .rrd's process (:mod:`imurig.reports.turn_table_rrd`) logs them; the campaign's process can make the
calibrated ones itself (numpy only) while the .rrd's process logs the rest."""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from imurig.calibration.sensitivity import nominal_sensitivity
from imurig.kernel.recording import Recording

#: the display's rate (Hz): block means of fs / DISPLAY_HZ samples
DISPLAY_HZ = 10.0


@dataclass
class Rows:
    """What the .rrd reads of a turn-table record, row range by row range: its contiguous blocks (slices),
    ``time(a, b)`` and ``channel(name, a, b)`` (rows [a, b)), ``spin_at(rows)`` the spin angle at given rows.
    :meth:`of` reads a whole Recording; the streamed campaign gives its own (kept codes, on-demand times)."""

    blocks: list
    time: Callable
    channel: Callable
    spin_at: Callable | None

    @classmethod
    def of(cls, rec: Recording, source: str = "channels") -> "Rows":
        data = rec.channels if source == "channels" else rec.truth_signals
        spin = rec.truth_signals.get("spin_angle")
        return cls(rec.blocks(), lambda a, b: rec.time_s[a:b], lambda n, a, b: data[n][a:b],
                   None if spin is None else spin.__getitem__)


def block_means(rec: Recording | Rows, names, k: int, source="channels", blocks_per_piece: int = 4096):
    """Means over consecutive blocks of k samples (within contiguous blocks): (times, {name: means}); a
    few thousand blocks at a time (each block's mean alone: the same values as at once)."""
    rows = Rows.of(rec, source) if isinstance(rec, Recording) else rec
    ts, out = [], {n: [] for n in names}
    for a, b in _pieces(rows.blocks, k, blocks_per_piece):
        ts.append(rows.time(a, b).reshape(-1, k).mean(axis=1))
        for n in names:
            out[n].append(rows.channel(n, a, b).reshape(-1, k).mean(axis=1))
    return (np.concatenate(ts) if ts else np.empty(0)), {n: np.concatenate(v) if v else np.empty(0)
                                                          for n, v in out.items()}


def _pieces(blocks, k: int, blocks_per_piece: int):
    """Row ranges [a, b) of whole k-sample blocks within each contiguous block, ``blocks_per_piece`` at a time."""
    for blk in blocks:
        m = (blk.stop - blk.start) // k
        for i in range(0, m, blocks_per_piece):
            yield blk.start + i * k, blk.start + min(m, i + blocks_per_piece) * k


def calibrated_block_means(rec: Recording | Rows, cal, k: int, blocks_per_piece: int = 256,
                           sensitivity=None) -> dict:
    """The calibrated rates' means over the blocks of :func:`block_means` (name -> means): ``cal.apply``'s
    values, the calibration applied to every sample, ``blocks_per_piece`` blocks at a time (never to the
    whole record at once, whose design matrix alone would take ~1 GB for the seed's campaign; 256 blocks of
    100 rows keep a piece's design matrix in the cache: ~2.8x less CPU than 1024 on the seed's campaign and
    less than 64, whose pieces pay more calls; the same values, each block's mean taken alone)."""
    spec = cal.SPEC
    rows = Rows.of(rec) if isinstance(rec, Recording) else rec
    s = cal.sensitivity_ if cal.sensitivity_ is not None else \
        (sensitivity if sensitivity is not None else nominal_sensitivity(rec, spec)[0])
    s = np.asarray(s, float)
    out = {f"{spec.cal_prefix}{a}": [] for a in spec.axes}
    for a, b in _pieces(rows.blocks, k, blocks_per_piece):
        f = cal.predict(np.stack([rows.channel(c, a, b) for c in spec.channels], axis=1) / s)
        for q, name in enumerate(out):
            out[name].append(f[:, q].reshape(-1, k).mean(axis=1))
    return {n: np.concatenate(v) if v else np.empty(0) for n, v in out.items()}


def display_step(rows, rec) -> int:
    """Samples per displayed row: fs / :data:`DISPLAY_HZ` (fs the rows' rate, else the record's)."""
    return max(1, int(round((getattr(rows, "sample_rate_hz", None) or rec.sample_rate_hz) / DISPLAY_HZ)))


def calibrated_means(rows: Rows, rec, cal) -> dict:
    """The calibrated rates' 10 Hz block means of ``rows`` (:func:`calibrated_block_means` at the display's
    step), with the record's nominal sensitivity where the calibration has none."""
    return calibrated_block_means(rows, cal, display_step(rows, rec), sensitivity=None if cal.sensitivity_ is not None
                                  else nominal_sensitivity(rec, cal.SPEC)[0])
