"""The sensor chain of :mod:`imurig.sensors.chain`, streamed: rows in pieces of STREAM_CHUNK samples,
memory bounded by the piece, not the record; the converter's output as integer codes.

The same stages and the same physics as :meth:`imurig.sensors.chain.ImuLab.measure`, row piece by
row piece:

    rig rows (time, set-points, truth f_C, w_C, B_C ...)
      specific_force: people transients (their resonator's state carried from piece to piece)
      sensor:         Q-Flex triad (noise-free lines; their slopes from the neighbouring rows; the
                      current-noise bands' shaping filters carried), fluxgate, FOG triad (its rate noise's
                      filter carried, restarted per contiguous block), temperature sensors
      analog:         the rig's analog lines (the turn table's index pulse); slip rings on every IMU line
                      while the table turns (:mod:`imurig.sensors.stream_turn`); a loose cable on its line
      conversion:     DAQ-6036E: common mode, skew, crosstalk (slot 0 from the last slot of the
                      previous scan, across pieces), noise, rounding  -> codes (int16), V = code * lsb
      -> sinks: ``rows(a, b, time_s, channels, codes, truth_signals)`` for each piece, in order
      events:         timers tag the rig's pulses (small: at once)

Every stage draws from its own stream (:func:`imurig.sensors.noise.child_rng`, the same names as the
whole-record chain), piece by piece; the normal draws of the sensors and the converter are made ahead
in a thread of their own, the same calls in the same order (:mod:`imurig.sensors.stream_draws`). The
pieces are a fixed STREAM_CHUNK = 2^16 rows, part of the data's definition: one seed gives the same
data bit for bit. The draws come piece by piece (the whole-record chain takes some band by band or
channel by channel over the whole record, others in 2^18-row pieces), so the realisation of the noise
differs from the whole-record chain's; the distributions are the same.

:func:`unsupported` names what the streamed chain does not do (the whole-record chain does): the lever
arm's terms, a thermal chamber, pump vibration in working hours, a persistent cable fault, GRSE hum,
averaged logging. The lab's own specific-force effects and the gyros' scale instability stream through
:mod:`imurig.sensors.stream_force`; a converter line's slow settling tail row by row (its idle input at a
piece's first row: the previous piece's last scan). A loose cable's spikes (analog stage, on its one line) stream, their
rectangles carried across pieces (:class:`_Cable`).
"""
from __future__ import annotations

from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np
from scipy import signal

from imurig.kernel.site import parse_time
from imurig.sensors.accelerometer import AXES
from imurig.sensors.effects.base import ChainContext
from imurig.sensors.effects.building_vibration import working_mask
from imurig.sensors.gyro import AXES as GYRO_AXES
from imurig.sensors.noise import child_rng, sampled_bands
from imurig.sensors.stream_draws import BandNoise as _Noise, Drawer
from imurig.sensors.stream_force import LabForce, LabLines, unsupported_effects
from imurig.sensors.stream_slopes import Gradient
from imurig.sensors.stream_turn import GyroNoiseRows, SlipRows, block_starts

#: rows per piece (part of the data's definition: the streams are drawn piece by piece)
STREAM_CHUNK = 1 << 16
#: pieces whose front (rig rows, disturbances, sensor lines) is made ahead, in a worker thread
AHEAD = 2
#: people transients below this (m/s^2) are cut to 0 (:class:`_People`)
RING_FLOOR = 1e-30


def _hours(start, t: np.ndarray, t0: float) -> np.ndarray:
    """Local hour of day of the samples ``t`` (s) of a record that starts at ``start`` (its first sample t0)."""
    return (start.hour + start.minute / 60 + start.second / 3600 + (t - t0) / 3600.0) % 24.0


def unsupported(lab, run) -> str | None:
    """Why ``lab`` cannot stream the rig record ``run`` (a :class:`imurig.rigs.tilt_table.TiltRun` or
    :class:`imurig.rigs.turn_run.TurnRun`), or None."""
    adc = lab.adc
    scan = set(adc.scan_list)
    bad = unsupported_effects(lab.effects)
    if bad:
        return "the lab effect(s) " + ", ".join(bad)
    if lab.cable.enabled and lab.cable.channel not in scan:
        return "a loose cable on a line that is not scanned"
    if "T_air" in run.truth_units:
        return "a thermal chamber"
    if lab.accelerometers.lever_arm().active:
        return "the accelerometers' lever arm"
    if adc.averaging != 1 or adc.bits > 16:
        return "averaged logging or a converter of more than 16 bits"
    if adc.grounding == "GRSE" and adc.ground_loop_V > 0:
        return "GRSE mains hum"
    if any(line not in run.truth_units for line in run.meta.get("analog_lines", [])):
        return "an analog line the rig does not give"
    if lab.pump.enabled and _pump_on(lab.pump, run):
        return "pump vibration in working hours"
    return None


def _pump_on(pump, run) -> bool:
    """Whether any sample of ``run`` falls in the pump's working hours. Within a piece the hour grows with
    the time: a piece whose [first, last] hours miss the working hours has no sample in them (a piece
    across midnight is checked sample by sample)."""
    start, t0 = parse_time(run.meta["start_time"]), float(run.time_rows(0, 1)[0])
    t1 = float(run.time_rows(run.n - 1, run.n)[0])
    h0, h1 = _hours(start, np.array([t0, t1]), t0)
    if t1 - t0 < 86400.0 and h1 >= h0 and (h1 < pump.work_start_h or h0 >= pump.work_stop_h):
        return False   # the whole record, within one day, is outside the working hours
    for a in range(0, run.n, STREAM_CHUNK):
        b = min(run.n, a + STREAM_CHUNK)
        h0, h1 = _hours(start, run.time_rows(a, a + 1), t0)[0], _hours(start, run.time_rows(b - 1, b), t0)[0]
        if h1 >= h0 and (h1 < pump.work_start_h or h0 >= pump.work_stop_h):
            continue
        if working_mask(_hours(start, run.time_rows(a, b), t0), pump.work_start_h, pump.work_stop_h).any():
            return True
    return False


@dataclass
class _Cable:
    """A loose cable's spikes (:class:`imurig.sensors.effects.cable_fault_spikes.LooseCable`), piece by
    piece: per piece the Bernoulli draws of the starts, then the lengths and the amplitudes (the effect's
    order); v = cumsum of the steps +a_e at t_e and -a_e at t_e + L_e, its level and the steps that fall
    beyond the piece carried to the next (a spike across a boundary stays one rectangle)."""

    eff: object
    fs: float
    rng: np.random.Generator
    level: float = 0.0
    pending: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def rows(self, m: int) -> np.ndarray:
        e = self.eff
        starts = np.flatnonzero(self.rng.random(m) < e.rate_hz / self.fs)
        lengths = np.maximum(1, (self.rng.uniform(e.min_duration_s, e.max_duration_s, starts.size) * self.fs)
                             .astype(int)) if starts.size else np.zeros(0, int)
        amps = self.rng.normal(0, e.amplitude_V, starts.size) if starts.size else np.zeros(0)
        delta = np.zeros(max(m, self.pending.size, int((starts + lengths).max(initial=0))) + 1)
        delta[:self.pending.size] += self.pending
        np.add.at(delta, starts, amps)
        np.add.at(delta, starts + lengths, -amps)
        delta[0] += self.level
        v = np.cumsum(delta[:m])
        self.level, self.pending = float(v[-1]), delta[m:].copy()
        return v


@dataclass
class _People:
    """People transients (:class:`imurig.sensors.effects.people_transients.PeopleTransients`), piece by piece:
    per piece the Bernoulli draws, then the events' directions and sizes; the resonator's state carried."""

    eff: object
    fs: float
    rng: np.random.Generator | None
    zi: np.ndarray | None = None

    def rows(self, hour: np.ndarray) -> np.ndarray | None:
        e = self.eff
        m = hour.size
        if not e.enabled or e.frequency_hz >= self.fs / 2:
            return None
        on = working_mask(hour, e.work_start_h, e.work_stop_h)
        rate = np.where(on, e.rate_per_hour_working, e.rate_per_hour_evening) / 3600.0 / self.fs
        events = np.flatnonzero(self.rng.random(m) < rate)
        impulses = np.zeros((m, 3))
        if events.size:
            d = self.rng.normal(size=(events.size, 3))
            d /= np.linalg.norm(d, axis=1, keepdims=True)
            impulses[events] = d * np.abs(self.rng.normal(0, e.peak_m_s2, size=(events.size, 1)))
        r, w = e.resonator(self.fs)
        b, a = [0.0, r * np.sin(w)], [1.0, -2 * r * np.cos(w), r * r]
        if self.zi is None:
            self.zi = np.zeros((2, 3))
        if not events.size and not np.any(self.zi):
            return None
        y, self.zi = signal.lfilter(b, a, impulses, axis=0, zi=self.zi)
        # the ring below RING_FLOOR is cut: no physical meaning, and it keeps the arithmetic of every later
        # stage off subnormal numbers (~100x slower), which a decay over a 2^16-row piece reaches
        y[np.abs(y) < RING_FLOOR] = 0.0
        self.zi[np.abs(self.zi) < RING_FLOOR] = 0.0
        return y


def measure_stream(lab, run, seed: np.random.SeedSequence, sinks) -> dict:
    """Stream the sensor chain of ``lab`` over the rig record ``run`` into ``sinks`` (module doc).

    Each sink's ``rows(a, b, time_s, channels, codes, truth_signals)`` gets the samples [a, b): the
    rig's set-point channels (float64), the converter's codes per scanned channel (int16; volts = code *
    ``lsb_V``) and the truth signals (float64: the rig's, ``T_imu``, and ``f_dist_C_*`` when a
    disturbance is on). Returns {meta, truth, units, quantum, truth_units, f_dist_nonzero}: the
    record's metadata and truth as :meth:`ImuLab.measure` writes them.
    """
    why = unsupported(lab, run)
    if why:
        raise ValueError(f"the streamed sensor chain does not model {why}; use ImuLab.measure")
    adc = lab.adc.validate()
    fs = float(run.meta["sample_rate_hz"])
    start, t0 = parse_time(run.meta["start_time"]), float(run.time_rows(0, 1)[0])
    acc = lab.accelerometers
    scan = adc.scan_list
    people = _People(lab.people, fs, child_rng(seed, lab.people.stream) if lab.people.enabled else None)
    if any(e.stage == "specific_force" for e in lab.effects):   # after the people transients (sensors/stream_force.py)
        people = LabForce(people, lab.effects, run, seed, lambda t: _hours(start, t, t0), STREAM_CHUNK)
    noise = _Noise(sampled_bands(acc.current_noise(averaged=bool(run.meta.get("averaged_logging"))).bands, fs,
                                 bool(run.meta.get("averaged_logging"))) if acc.noise_enabled else [],
                   fs, child_rng(seed, "accelerometers"))
    rngs = {"magnetometer": child_rng(seed, "magnetometer"), "adc": child_rng(seed, "adc")}
    cable = _Cable(lab.cable, fs, child_rng(seed, lab.cable.line_stream(lab.cable.channel))) \
        if lab.cable.enabled else None
    rngs.update({k: child_rng(seed, k) for k in lab.temp_sensors if k in scan})
    gyro = GyroNoiseRows(lab.gyros.noise(), lab.gyros.scale_V_per_rad_s, fs, child_rng(seed, "gyros")) \
        if any(c.startswith("gyro_") for c in scan) else None
    imu = [c for c in scan if c.split("_")[0] in ("acc", "mag", "gyro") or c in lab.temp_sensors]
    slip = SlipRows(lab.slip_rings, {k: child_rng(seed, lab.slip_rings.line_stream(k)) for k in imu}) \
        if lab.slip_rings.enabled and "spin_angle" in run.truth_units else None
    sens = dict(zip((f"acc_{a}" for a in AXES), acc.nominal_sensitivity_V_per_m_s2()))
    lines = LabLines(lab.effects, scan, seed, fs) if any(e.stage == "analog" for e in lab.effects) else None
    state = SimpleNamespace(saturated={}, last_in=None, f_dist_nonzero=False)
    pieces = [(a, min(run.n, a + STREAM_CHUNK)) for a in range(0, run.n, STREAM_CHUNK)]
    drawer = Drawer(lab, rngs, noise)
    draws = [None] * len(pieces)

    def draw_ahead(upto: int) -> None:   # the draws of pieces [0, upto], in piece order
        nonlocal drawn
        while drawn <= min(upto, len(pieces) - 1):
            a, b = pieces[drawn]
            draws[drawn] = dpool.submit(drawer.piece, b - a)
            drawn += 1

    # the noise draws run ahead in one worker thread, the fronts in another (each stream drawn in piece
    # order), the backs here
    drawn = 0
    with ThreadPoolExecutor(1) as pool, ThreadPoolExecutor(1) as dpool:
        draw_ahead(AHEAD + 1)
        ahead = SimpleNamespace(gyro=gyro, slip=slip)   # drawn in the fronts' worker, in piece order
        fronts = deque(pool.submit(_front, lab, run, p, people, draws[j], start, t0, fs, sens, ahead)
                       for j, p in enumerate(pieces[:AHEAD]))
        prev, cur = None, fronts.popleft().result()
        for i, _ in enumerate(pieces):
            draw_ahead(i + AHEAD + 1)
            if i + AHEAD < len(pieces):
                fronts.append(pool.submit(_front, lab, run, pieces[i + AHEAD], people, draws[i + AHEAD], start, t0,
                                          fs, sens, ahead))
            nxt = fronts.popleft().result() if fronts else None
            _emit(lab, sinks, prev, cur, nxt, SimpleNamespace(cable=cable, lines=lines),
                  draws[i].result()["adc"], state)
            draws[i] = None
            prev, cur = cur, nxt
    report = {"lsb_V": adc.lsb_V, "saturated_samples": state.saturated}
    rig = SimpleNamespace(meta=run.meta, truth=run.truth, events=run.events, truth_signals=run.truth_units)
    used = [g for p, g in (("acc", "accelerometers"), ("mag", "magnetometer"), ("gyro", "gyros"))
            if any(c.startswith(p + "_") for c in scan)]
    units = {**run.units, **{k: "V" for k in scan}}
    truth_units = {**run.truth_units, "T_imu": "K", **{f"f_dist_C_{a}": "m/s^2" for a in AXES}}
    return {"meta": lab._meta(rig, report), "truth": lab._truth(rig, seed, used), "units": units,
            "quantum": {k: adc.lsb_V for k in scan}, "truth_units": truth_units,
            "f_dist_nonzero": state.f_dist_nonzero, "events": lab._events(rig, seed)}


def _emit(lab, sinks, prev, cur, nxt, noise, rng, state) -> None:
    """The back of piece ``cur`` (its neighbours' fronts known) and its rows to every sink."""
    codes = _back(lab, prev, cur, nxt, noise, rng, state)
    if rng.left():
        raise RuntimeError(f"the converter took {rng.left()} fewer draws than were made ahead "
                           "(sensors/stream_draws.py)")
    truth = dict(cur.truth)
    truth["T_imu"] = cur.T
    if cur.f_dist is not None or lab.people.enabled:
        f = cur.f_dist if cur.f_dist is not None else np.zeros((cur.t.size, 3))
        state.f_dist_nonzero |= bool(np.any(f))
        truth.update({f"f_dist_C_{a}": f[:, j] for j, a in enumerate(AXES)})
    for s in sinks:
        s.rows(cur.a, cur.b, cur.t, cur.channels, codes, truth)


def _front(lab, run, piece, people, draws, start, t0, fs, sens, ahead) -> SimpleNamespace:
    """One piece's rig rows, disturbances, temperatures and the lines that need no neighbours: the
    accelerometers' noise-free volts and current noise (A), the fluxgate's and the temperature sensors'
    volts, the gyros' rate noise and the slip rings' noise (``ahead``: their :class:`GyroNoiseRows` and
    :class:`SlipRows`, or None). The fronts are made one after the other in piece order (one worker), so
    each stream is drawn in piece order; ``draws``: the future of the piece's noise draws (:class:`Drawer`)."""
    a, b = piece
    d = draws.result()
    t = run.time_rows(a, b)
    ts = run.truth_rows(a, b)
    hour = _hours(start, t, t0)
    f_dist = people.rows(hour) if people.rng is not None else None
    c = lab.climate
    T = 273.15 + c.temperature_C + c.self_heating_K + c.drift_C_per_h * (t - t0) / 3600
    scan = set(lab.adc.scan_list)
    lines, slope_src, nz = {}, {}, None
    if any(f"acc_{x}" in scan for x in AXES):
        nz = d["acc"]
        f = np.stack([ts[f"f_C_{x}"] for x in AXES], axis=1)
        if f_dist is not None:
            f += f_dist
        # without a drift the temperature is one value: a scalar (the same arithmetic, fewer operations)
        v = lab.accelerometers.ideal_voltage(f, float(T[0]) if c.drift_C_per_h == 0 else T, 0.0)
        for j, x in enumerate(AXES):
            slope_src[f"acc_{x}"] = v[:, j]
    if any(f"mag_{x}" in scan for x in AXES):
        B_C = np.stack([ts[f"B_C_{x}"] for x in AXES], axis=1)
        v = lab.magnetometer.output_voltage(B_C, d["magnetometer"], T)
        for j, x in enumerate(AXES):
            slope_src[f"mag_{x}"] = v[:, j]
    if any(f"gyro_{x}" in scan for x in GYRO_AXES):
        w_C = np.stack([ts[f"w_C_{x}"] for x in AXES], axis=1)
        g_sens = bool(np.any(lab.gyros.g_sensitivity_rad_s_per_m_s2))
        f_gyro = np.stack([ts[f"f_C_{x}"] for x in AXES], axis=1) + (f_dist if f_dist is not None else 0.0) \
            if g_sens else None
        v = lab.gyros.ideal_voltage(w_C, float(T[0]) if c.drift_C_per_h == 0 else T, f_gyro)
        for j, x in enumerate(GYRO_AXES):
            slope_src[f"gyro_{x}"] = v[:, j]
    for name, sensor in lab.temp_sensors.items():
        if name in scan:
            lines[name] = sensor.voltage(T, d[name])
    for line in run.meta.get("analog_lines", []):
        lines[line] = ts[line]
    # the slip rings' profile over the piece (no draws): made here, ahead, for the back's noise
    slip = ahead.slip.draw(ts["spin_angle"]) if ahead.slip is not None else None
    gyro = None
    if ahead.gyro is not None:   # the gyros' noise: blocks start after a gap (the previous piece's last time)
        t_prev = float(run.time_rows(a - 1, a)[0]) if a > 0 else None
        gyro = ahead.gyro.rows(t.size, block_starts(t, t_prev, ahead.gyro.fs))
    return SimpleNamespace(a=a, b=b, t=t, truth=ts, channels=run.channel_rows(a, b), f_dist=f_dist, T=T,
                           lines=lines, slope_src=slope_src, noise=nz, slip_noise=slip, gyro_noise=gyro)


def _back(lab, prev, cur, nxt, noise, rng, state) -> dict:
    """The piece's slopes (from its neighbours' rows), the accelerometers' and the gyros' noise, the analog
    stage (slip rings on the IMU's lines, a loose cable's spikes on its line; not in the slopes, as in the
    whole-record chain), the conversion: codes."""
    analog, slope = dict(cur.lines), {}
    lo = prev is not None
    t = np.concatenate(([prev.t[-1:]] if lo else []) + [cur.t] + ([nxt.t[:1]] if nxt else []))
    grad = Gradient(t)
    for name, v in cur.slope_src.items():
        x = np.concatenate(([prev.slope_src[name][-1:]] if lo else []) + [v] + ([nxt.slope_src[name][:1]] if nxt else []))
        slope[name] = grad(x)[int(lo):int(lo) + v.size]
        analog[name] = v
    if any(n.startswith("acc_") for n in analog):
        nz = cur.noise
        R = lab.accelerometers.load_resistor_ohm
        for j, x in enumerate(AXES):
            if f"acc_{x}" in analog and nz is not None:
                analog[f"acc_{x}"] = analog[f"acc_{x}"] + nz[:, j] * R[j]
    if cur.gyro_noise is not None:
        nz = cur.gyro_noise
        for j, x in enumerate(GYRO_AXES):
            if f"gyro_{x}" in analog:
                analog[f"gyro_{x}"] = analog[f"gyro_{x}"] + nz[:, j]
    if cur.slip_noise is not None:
        SlipRows.add(analog, cur.slip_noise)
    if noise.cable is not None:
        analog[lab.cable.channel] = analog[lab.cable.channel] + noise.cable.rows(cur.t.size)
    if noise.lines is not None:     # the lab's own analog-stage effects (sensors/stream_force.py)
        noise.lines.add(analog)
    return _convert(lab.adc, analog, slope, rng, state)


def _convert(adc, analog: dict, slope: dict, rng, state) -> dict:
    """The converter over one piece (:meth:`imurig.sensors.adc.DAQ6036E.convert`, row for row): codes per
    channel. Slot 0's crosstalk takes the last slot's input of the previous scan, across pieces."""
    m = next(iter(analog.values())).size
    common = adc.common_mode.common(np.zeros(m), rng)
    last = adc.scan_list[-1]
    ext = state.last_in is not None
    if ext:  # one leading row: the previous piece's last scan (only slot 0's crosstalk reads it)
        analog = {k: _Lead(v, state.last_in[0] if k == last else 0.0) for k, v in analog.items()}
        slope = {k: _Lead(v, 0.0) for k, v in slope.items()}
        common = np.concatenate(([state.last_in[1]], common))
    # a slow settling tail (a line's memory of the slots before it; row 0's idle input: the last scan before)
    tails = adc.slow_tails({k: (v.v if ext else v) for k, v in analog.items()},
                           common[int(ext):], sum(state.last_in) if ext else None) \
        if adc.channel_slow_settling else {}
    if ext:
        tails = {k: (e, _Lead(r, 0.0)) for k, (e, r) in tails.items()}
    a, b = int(ext), int(ext) + m
    out, held = {}, None
    for j, name in enumerate(adc.scan_list):
        nxt = adc.scan_list[j + 1] if j + 1 < len(adc.scan_list) else None
        keep = nxt is not None and not adc.ground_between and \
            adc.channel_crosstalk(nxt).coefficient(adc.mux_frequency_hz) > 0
        held_next = np.empty(b) if keep else None
        out[name] = adc._convert_rows(j, name, a, b, analog, common, slope, held, held_next, rng, state.saturated,
                                      tails.get(name), codes=True)
        held = held_next
    state.last_in = ((analog[last].v if ext else analog[last])[-1], common[-1])
    return out


class _Lead:
    """The array ``v`` with one leading value ``first`` before it, for slicing [a:b] (row 0: ``first``)
    without copying ``v``: rows [a, b) with a >= 1 are the view v[a-1:b-1]."""

    def __init__(self, v: np.ndarray, first: float):
        self.v, self.first = v, first

    def __getitem__(self, s: slice) -> np.ndarray:
        a, b = s.start or 0, self.v.size + 1 if s.stop is None else s.stop
        if a >= 1:
            return self.v[a - 1:b - 1]
        return np.concatenate(([self.first], self.v[:max(b - 1, 0)]))
