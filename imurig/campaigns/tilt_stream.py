"""The tilt-table campaign streamed: rig rows -> sensor chain -> HDF5 file and 100 Hz windows, in pieces.

    TiltTable.run (truth as pieces, :class:`imurig.rigs.tilt_table.TiltRun`)
      -> measure_stream (:mod:`imurig.sensors.stream`, 2^18-row pieces, ADC codes)
      -> sinks, piece by piece: the HDF5 recording (:class:`imurig.kernel.h5write.H5RowWriter`),
         the low-pass in the acquisition windows and the 100 Hz decimation
         (:class:`imurig.calibration.window_filter.WindowTap`), and optionally the whole record

No 1 kHz array of the record's length is held but ``time_s`` while the windows are located. The 100 Hz
record is what :func:`imurig.calibration.preprocess.lowpass_downsample` (``windows_only``, ``filtered``:
the :data:`ANALYSED` channels and truth signals) gives on the whole record, bit for bit, and the HDF5 file is what :func:`imurig.kernel.recording.save_h5` writes of it
(read back by ``load_h5`` to the same values). A campaign the streamed chain does not model
(:func:`imurig.sensors.stream.unsupported`) runs the whole-record chain instead, with the same outputs.
"""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from imurig.calibration.accelerometer import ACC
from imurig.calibration.preprocess import filter_design, lowpass_downsample, window_log
from imurig.calibration.window_filter import WindowTap
from imurig.campaigns.tilt_rig import run_table
from imurig.kernel.h5write import H5RowWriter
from imurig.kernel.outputs import atomic_write, check_disk
from imurig.kernel.recording import Recording, TimeFrame, save_h5
from imurig.sensors.accelerometer import AXES
from imurig.sensors.stream import measure_stream, unsupported

FILTERED_UNITS = ("m/s^2", "rad/s", "T")
#: the channels and truth signals the tilt-table analysis reads (the accelerometer calibration, its figures
#: and .rrd: the accelerometers' volts and the true specific force): the only ones low-passed in the windows;
#: the others (fluxgate, temperature sensors, the true rates and field) are decimated as sampled
ANALYSED = ACC + tuple(f"f_C_{a}" for a in AXES)


class _Collect:
    """A sink that keeps every piece: the whole record of ``n`` rows (for simulate(), tests and small
    campaigns), filled in place (no piece list, no concatenation): volts = code * lsb (float64)."""

    def __init__(self, n: int, quantum: dict):
        self.n, self.quantum, self.arrays = n, quantum, None

    def rows(self, a, b, time_s, channels, codes, truth):
        if self.arrays is None:
            self.arrays = [np.empty(self.n)] + [{k: np.empty(self.n, dtype=v.dtype) for k, v in d.items()}
                                                for d in (channels, codes, truth)]
            for k in codes:
                self.arrays[2][k] = np.empty(self.n)
        time, chans, volts, tsig = self.arrays
        time[a:b] = time_s
        for d, src in ((chans, channels), (tsig, truth)):
            for k, v in src.items():
                d[k][a:b] = v
        for k, c in codes.items():
            np.multiply(c, self.quantum[k], out=volts[k][a:b])

    def recording(self, info: dict, drop: set) -> Recording:
        time, chans, volts, tsig = self.arrays
        self.arrays = None
        q = info["quantum"]
        channels = {**chans, **volts}
        truth = {n: v for n, v in tsig.items() if n not in drop}
        return Recording(time_s=time, channels=channels,
                         units={n: info["units"][n] for n in channels}, segments=info["segments"],
                         segment_units=info["segment_units"], meta=info["meta"], truth=info["truth"],
                         truth_signals=truth, truth_units={n: info["truth_units"][n] for n in truth},
                         channel_quantum={n: q[n] for n in volts}, events=info.get("events", {}))


def stream_campaign(camp, h5_path=None, overwrite: bool = False, keep: bool = False, rig=None) -> SimpleNamespace:
    """Simulate the campaign ``camp`` (:class:`imurig.campaigns.tilt_table.TiltTableCampaign`) in pieces.

    Returns rec100 (the 100 Hz record: the :data:`ANALYSED` channels and truth low-passed in the windows,
    everything decimated elsewhere), n (1 kHz samples),
    n_segments, truth, streamed (False: the whole-record chain ran, see ``why``) and ``recording`` (the
    whole 1 kHz Recording with ``keep``, else None); writes the HDF5 recording to ``h5_path`` if given.
    ``rig``: the rig's run started ahead (:class:`imurig.campaigns.tilt_rig.RigAhead`), used if it was made
    for this campaign's settings."""
    camp.check_identifiable()
    table, lab, ss = camp.build()
    ready = rig.take(camp) if rig is not None else None
    run = ready[1] if ready else run_table(table, camp.protocol, camp.start_time, camp.seed)
    if h5_path is not None:   # the codes (2 bytes each) and ~16 bytes of time, set-points and truth per row, deflated
        check_disk(h5_path, run.n * (2 * len(lab.adc.scan_list) + 16),
                   f"the recording of {run.n:.3g} samples ({camp.protocol.n_positions} positions)",
                   "shorten the schedule (--dwell, --rate, fewer --theta/--phi) or pass --no-recording")
    why = unsupported(lab, run)
    if why:
        return _whole(camp, lab, run, ss, h5_path, overwrite, why)
    frame = TimeFrame(run.time_rows(0, run.n), run.segments)   # the rate and blocks: one median of the steps
    k, sos, log = filter_design(frame.sample_rate_hz)
    scan = list(lab.adc.scan_list)
    setpoints = set(run.meta.get("setpoints", []))
    chan_names = list(run.units) + [c for c in scan if c not in run.units]
    truth_units = {**run.truth_units, "T_imu": "K"}
    if lab.people.enabled:
        truth_units.update({f"f_dist_C_{a}": "m/s^2" for a in AXES})
    low = [n for n in chan_names if n not in setpoints and n in ANALYSED]
    tlow = [n for n, u in truth_units.items() if u in FILTERED_UNITS and n in ANALYSED]
    tap = WindowTap(frame, sos, k, chan_names, low, list(truth_units), tlow, {c: lab.adc.lsb_V for c in scan})
    del frame
    sinks = [tap] + ([_Collect(run.n, {c: lab.adc.lsb_V for c in scan})] if keep else [])
    info = {}

    def simulate(extra=()):
        return _measure(camp, lab, run, ss, sinks + list(extra), info)

    if h5_path is not None:
        import h5py  # heavy: loaded when a file is written

        def writer(tmp):
            with h5py.File(tmp, "w") as f:
                w = H5RowWriter(f, run.n, {c: ((np.int16, "V", lab.adc.lsb_V) if c in scan else
                                               (np.float64, run.units[c], None)) for c in chan_names},
                                truth_units, run.segments, run.segment_units)
                try:
                    drop = simulate([w])
                    w.finish(info["meta"], info["truth"], sorted(drop))
                finally:
                    w.close()
                info["drop"] = drop

        atomic_write(h5_path, writer, overwrite)
    else:
        info["drop"] = simulate()
    drop = info["drop"]
    meta = dict(info["meta"])
    meta["sample_rate_hz"] = log["to_hz"]
    meta["preprocessing"] = list(meta.get("preprocessing", [])) + [window_log(log, low, tlow)]
    tsig = {n: v for n, v in tap.truth.items() if n not in drop}
    rec100 = Recording(time_s=tap.time_s, channels=tap.channels, units={n: info["units"][n] for n in chan_names},
                       segments=dict(run.segments), segment_units=dict(run.segment_units), meta=meta,
                       truth=info["truth"], truth_signals=tsig, truth_units={n: truth_units[n] for n in tsig})
    return SimpleNamespace(rec100=rec100, n=run.n, n_segments=rec100.n_segments, truth=info["truth"],
                           streamed=True, why=None,
                           recording=sinks[1].recording(info, drop) if keep else None)


def _measure(camp, lab, run, ss, sinks, info: dict) -> set:
    """Stream the chain into ``sinks``; fill ``info`` (:func:`measure_stream`'s dict with the campaign's
    metadata, its seed and the segments); return the truth signals to drop (an all-zero disturbance, which
    the whole-record chain leaves out)."""
    info.update(measure_stream(lab, run, ss, sinks))
    info["meta"]["campaign"] = {"name": "tilt-table", **camp.to_dict()}
    info["truth"]["seed"] = camp.seed
    info.update(segments=run.segments, segment_units=run.segment_units)
    return set() if info["f_dist_nonzero"] else {f"f_dist_C_{a}" for a in AXES if lab.people.enabled}


def record_campaign(camp) -> Recording:
    """The whole 1 kHz Recording of the campaign ``camp``, the data ``imurig campaign tilt-table`` writes to
    recording.h5 for the same seed, bit for bit: the streamed chain's pieces collected (volts = code * lsb_V,
    float64), or the whole-record chain where the stream does not model the lab (:func:`stream_campaign`).
    No 100 Hz windows, no file."""
    camp.check_identifiable()
    table, lab, ss = camp.build()
    run = run_table(table, camp.protocol, camp.start_time, camp.seed)
    if unsupported(lab, run):
        return _whole_record(camp, lab, run, ss)
    sink, info = _Collect(run.n, {c: lab.adc.lsb_V for c in lab.adc.scan_list}), {}
    drop = _measure(camp, lab, run, ss, [sink], info)
    return sink.recording(info, drop)


def _whole_record(camp, lab, run, ss) -> Recording:
    """The whole-record chain (:meth:`imurig.sensors.chain.ImuLab.measure`) on the rig record ``run``."""
    rec = lab.measure(run.recording(), ss)
    rec.meta["campaign"] = {"name": "tilt-table", **camp.to_dict()}
    rec.truth["seed"] = camp.seed
    return rec


def _whole(camp, lab, run, ss, h5_path, overwrite, why) -> SimpleNamespace:
    """The whole-record chain (:meth:`imurig.sensors.chain.ImuLab.measure`) with the same outputs."""
    rec = _whole_record(camp, lab, run, ss)
    if h5_path is not None:
        save_h5(rec, h5_path, overwrite=overwrite)
    rec100 = lowpass_downsample(rec, windows_only=True, filtered=ANALYSED)
    return SimpleNamespace(rec100=rec100, n=rec.n, n_segments=rec.n_segments, truth=rec.truth, streamed=False,
                           why=why, recording=rec)
