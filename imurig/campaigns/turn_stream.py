"""The turn-table campaign streamed: rig rows -> sensor chain -> HDF5 file and what the analysis reads, in pieces.

    TurnTable.run (truth as states, rows on demand: :class:`imurig.rigs.turn_run.TurnRun`)
      -> measure_stream (:mod:`imurig.sensors.stream`: FOG triad, Q-Flex, slip rings, converter codes, timers)
      -> sinks, piece by piece: the HDF5 recording (:class:`imurig.kernel.h5write.H5RowWriter`), and
         :class:`TurnTap`, which keeps the converter's codes of the gyros and the index pulse (int16; volts =
         code * lsb_V), the spin angle at the display's 10 Hz rows and the rows of the figure's window

What the analysis gets is the record's acquisition windows (:func:`window_record`): the rows inside each
step's window (and the one before it, where the ADC timer sees an edge), with the gyro and pulse volts,
the timers' events and the full record's contiguous blocks (``meta["block_start_s"]``, which the gyro
fit's noise model reads, :func:`imurig.calibration.gyro.segment_covariance`). Its per-window statistics
are those of the whole record, bit for bit (the same rows, the same volts). A lab the streamed chain does
not model (:func:`imurig.sensors.stream.unsupported`) runs the whole-record chain instead, with the same
outputs; the Delft 2005 preset's scale instability streams (:mod:`imurig.sensors.stream_force`).
"""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from imurig.calibration.gyro import GYRO
from imurig.campaigns.tilt_stream import _Collect
from imurig.kernel import random_streams
from imurig.kernel.h5write import H5RowWriter
from imurig.kernel.outputs import atomic_write
from imurig.kernel.recording import Recording, save_h5
from imurig.sensors.accelerometer import AXES
from imurig.sensors.stream import measure_stream, unsupported

#: the display's rate (Hz): one pose row in every fs / DISPLAY_HZ (:mod:`imurig.reports.turn_table_rrd`)
DISPLAY_HZ = 10.0


class TurnTap:
    """A sink that keeps what the analysis and the figures read (module doc): per channel of ``kept`` its
    codes (int16, the whole record), the spin angle at every k-th row of each contiguous block, and the
    temp_box volts and spin angle over the rows [fig_a, fig_b)."""

    def __init__(self, run, kept, k: int, fig_rows: tuple[int, int]):
        n = run.n
        self.codes = {c: np.empty(n, np.int16) for c in kept}
        starts = [int(x) for x in run.off[:-1]]
        self.pose_rows = np.concatenate([np.arange(a, b, k) for a, b in zip(starts, run.off[1:])])
        self.pose_spin = np.empty(self.pose_rows.size)
        self.fig_a, self.fig_b = fig_rows
        self.fig = {"temp_box": np.empty(self.fig_b - self.fig_a), "spin_angle": np.empty(self.fig_b - self.fig_a)}

    def rows(self, a, b, time_s, channels, codes, truth):
        for c, x in self.codes.items():
            x[a:b] = codes[c]
        lo, hi = np.searchsorted(self.pose_rows, [a, b])
        self.pose_spin[lo:hi] = truth["spin_angle"][self.pose_rows[lo:hi] - a]
        lo, hi = max(a, self.fig_a), min(b, self.fig_b)
        if lo < hi:
            self.fig["spin_angle"][lo - self.fig_a:hi - self.fig_a] = truth["spin_angle"][lo - a:hi - a]
            if "temp_box" in codes:
                self.fig["temp_box"][lo - self.fig_a:hi - self.fig_a] = codes["temp_box"][lo - a:hi - a]

    def volts(self, name: str, a: int, b: int, q: float) -> np.ndarray:
        """Rows [a, b) of a kept channel in volts (code * q, float64: the collected record's values)."""
        return _volts(self.codes[name][a:b], q)


def _volts(codes: np.ndarray, q: float) -> np.ndarray:
    out = np.empty(codes.shape)
    np.multiply(codes, q, out=out)
    return out


class TapRows:
    """The .rrd's rows of a streamed record (:class:`imurig.reports.turn_table_rrd.Rows`-like): its contiguous
    blocks, ``time(a, b)`` (from the run's t0, dt: its truth's states let go), ``channel(name, a, b)`` (a kept
    channel's volts, code * q) and ``spin_at(rows)`` (the spin angle at the display's rows). Picklable (plain
    arrays): it can be sent to the process that writes the .rrd."""

    def __init__(self, run, codes: dict, q: float, pose_rows: np.ndarray, pose_spin: np.ndarray):
        self.run, self.codes, self.q, self.pose_rows, self.pose_spin = run, codes, q, pose_rows, pose_spin
        self.blocks = [slice(int(a), int(b)) for a, b in zip(run.off[:-1], run.off[1:])]
        self.sample_rate_hz = float(run.meta["sample_rate_hz"])

    def time(self, a: int, b: int) -> np.ndarray:
        return self.run.time_rows(a, b)

    def channel(self, name: str, a: int, b: int) -> np.ndarray:
        return _volts(self.codes[name][a:b], self.q)

    def spin_at(self, idx) -> np.ndarray:
        return self.pose_spin[np.searchsorted(self.pose_rows, idx)]


def _rows_of(run, times: np.ndarray) -> np.ndarray:
    """The first row at or after each of ``times`` (s): searchsorted over the record's time, mounting by mounting."""
    out = np.empty(len(times), int)
    for m in range(len(run.t0)):
        a, b = int(run.off[m]), int(run.off[m + 1])
        t = run.time_rows(a, b)
        inside = (times >= t[0] - run.dt / 2) & (times <= t[-1] + run.dt / 2) if m else times <= t[-1] + run.dt / 2
        out[inside] = a + np.searchsorted(t, times[inside], side="left")
    return out


def stream_campaign(camp, h5_path=None, overwrite: bool = False, keep: bool = False, check: bool = True,
                    streams: tuple[str, str] = ("campaign/turn-table/rig", "campaign/turn-table/sensor-chain")
                    ) -> SimpleNamespace:
    """Simulate the campaign ``camp`` (:class:`imurig.campaigns.turn_table.TurnTableCampaign`) in pieces.

    Returns ``rec`` (the acquisition windows' record, :func:`window_record`), ``rows`` (the .rrd's rows,
    :class:`imurig.reports.turn_table_rrd.Rows`-like), ``fig`` (a record of the fastest step's window: the
    slip-ring figure), n (samples), streamed (False: the whole-record chain ran, see ``why``) and
    ``recording`` (the whole Recording with ``keep`` or on the whole-record chain, else None); writes the
    HDF5 recording to ``h5_path`` if given. ``check``: refuse a schedule that cannot identify the campaign's
    model first; ``streams``: the rig's and the sensor chain's random streams (a study's own)."""
    if check:
        camp.check_identifiable()
    else:
        camp.protocol.validate()
    table, lab, _ = camp.build()
    ss = random_streams.seed_sequence(streams[1], camp.seed)
    run = table.run(camp.protocol, camp.start_time, random_streams.generator(streams[0], camp.seed))
    why = unsupported(lab, run)
    if why:
        rec = camp._measured(lab, run.recording(), ss)
        if h5_path is not None:
            save_h5(rec, h5_path, overwrite=overwrite)
        rows = SimpleNamespace(blocks=rec.blocks(), time=lambda a, b: rec.time_s[a:b],
                               channel=lambda n, a, b: rec.channels[n][a:b],
                               spin_at=rec.truth_signals["spin_angle"].__getitem__, sample_rate_hz=rec.sample_rate_hz)
        return SimpleNamespace(rec=rec, rows=rows, fig=rec, n=rec.n, streamed=False, why=why, recording=rec)
    scan = list(lab.adc.scan_list)
    q = lab.adc.lsb_V
    fs = float(run.meta["sample_rate_hz"])
    seg = run.segments
    i_fig = int(np.argmax(np.abs(seg["rate_dial"])))
    bounds = _rows_of(run, np.concatenate([seg["start_s"], seg["stop_s"]]))
    lo, hi = bounds[:len(seg["start_s"])], bounds[len(seg["start_s"]):]
    kept = [c for c in (*GYRO, "pulse") if c in scan]
    tap = TurnTap(run, kept, max(1, int(round(fs / DISPLAY_HZ))), (lo[i_fig], hi[i_fig]))
    chan_names = list(run.units) + [c for c in scan if c not in run.units]
    truth_units = {**run.truth_units, "T_imu": "K"}
    if lab.people.enabled:
        truth_units.update({f"f_dist_C_{a}": "m/s^2" for a in AXES})
    sinks = [tap] + ([_Collect(run.n, {c: q for c in scan})] if keep else [])
    info = {}

    def simulate(extra=()):
        info.update(measure_stream(lab, run, ss, sinks + list(extra)))
        info["meta"]["campaign"] = {"name": "turn-table", **camp.to_dict()}
        info["truth"]["seed"] = camp.seed
        info.update(segments=run.segments, segment_units=run.segment_units)
        return set() if info["f_dist_nonzero"] else {f"f_dist_C_{a}" for a in AXES if lab.people.enabled}

    if h5_path is not None:
        import h5py  # heavy: loaded when a file is written

        def writer(tmp):
            with h5py.File(tmp, "w") as f:
                w = H5RowWriter(f, run.n, {c: ((np.int16, "V", q) if c in scan else (np.float64, run.units[c], None))
                                           for c in chan_names}, truth_units, run.segments, run.segment_units)
                try:
                    info["drop"] = simulate([w])
                    w.finish(info["meta"], info["truth"], sorted(info["drop"]), info["events"])
                finally:
                    w.close()

        atomic_write(h5_path, writer, overwrite)
    else:
        info["drop"] = simulate()
    run.source = None   # the truth's states (~0.25 GB): no longer needed, the times are made from t0, dt
    rec = window_record(run, tap, info, lo, hi, q)
    fig = _fig_record(run, tap, info, i_fig, q)
    rows = TapRows(run, tap.codes, q, tap.pose_rows, tap.pose_spin)
    return SimpleNamespace(rec=rec, rows=rows, fig=fig, n=run.n, streamed=True, why=None,
                           recording=sinks[1].recording(info, info["drop"]) if keep else None)


def window_record(run, tap: TurnTap, info: dict, lo: np.ndarray, hi: np.ndarray, q: float) -> Recording:
    """The acquisition windows' record (module doc): rows [lo_i - 1, hi_i) of each step i (merged where they
    meet), time, the kept channels in volts, the segments, events, metadata and truth of the record."""
    ranges = _merged(zip(np.maximum(lo - 1, 0), hi))
    time = np.concatenate([run.time_rows(a, b) for a, b in ranges])
    channels = {c: np.concatenate([tap.volts(c, a, b, q) for a, b in ranges]) for c in tap.codes}
    meta = dict(info["meta"])
    meta["block_start_s"] = [float(run.t0[m]) for m in range(len(run.t0))]
    meta["rows"] = "the acquisition windows of a record of {} samples".format(run.n)
    return Recording(time_s=time, channels=channels, units={c: "V" for c in channels}, segments=dict(run.segments),
                     segment_units=dict(run.segment_units), meta=meta, truth=info["truth"],
                     channel_quantum={c: q for c in channels}, events=info["events"])


def _merged(spans) -> list[tuple[int, int]]:
    """The row ranges [a, b) covered by ``spans`` (pairs a, b; empty ones dropped), sorted, those that overlap
    or meet merged into one."""
    out: list[list[int]] = []
    for a, b in sorted((int(a), int(b)) for a, b in spans if b > a):
        if out and a <= out[-1][1]:
            out[-1][1] = max(out[-1][1], b)
        else:
            out.append([a, b])
    return [(a, b) for a, b in out]


def _fig_record(run, tap: TurnTap, info: dict, i: int, q: float) -> Recording:
    """The rows of step ``i``'s window (the fastest step): temp_box volts and the spin angle (the slip-ring figure)."""
    a, b = tap.fig_a, tap.fig_b
    seg = {k: np.asarray(v)[i:i + 1] for k, v in run.segments.items()}
    return Recording(time_s=run.time_rows(a, b), channels={"temp_box": tap.fig["temp_box"] * q},
                     units={"temp_box": "V"}, segments=seg, segment_units=dict(run.segment_units),
                     meta=dict(info["meta"]), truth=info["truth"],
                     truth_signals={"spin_angle": tap.fig["spin_angle"]}, truth_units={"spin_angle": "rad"})
