"""The turn-table campaign in rerun: the table spinning, the IMU frame, the index pulses,
raw gyro volts and calibrated rates (10 Hz block means), references per step."""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import rerun.blueprint as rrb

from imurig.calibration.gyro import AXES, GYRO
from imurig.calibration.sensitivity import nominal_sensitivity
from imurig.kernel.recording import Recording
from imurig.rigs.mujoco_rig import load_model
from imurig.rigs.tilt_table import _quat_wxyz
from imurig.rigs.turn_table import MOUNTS, TurnTableErrors
from imurig.reports.rrd_layout import layout, readable, rig_view, series_view, summary_view, symmetric_range
from imurig.reports.tilt_table_rrd import parameter_table
from imurig.reports.viz import (RrdWriter, body_path, break_gaps, log_body_poses, log_frame_axes, log_mujoco_model,
                                log_scalars, log_text)

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


def blueprint(model, residual_range=None) -> rrb.Blueprint:
    """Left: the table with the camera on the IMU, the index pulses, the parameter table. Right:
    measured volts, calibrated rates over the reference, residuals per step."""
    return layout(rrb.Horizontal(
        rrb.Vertical(rig_view(model, "turn table", distance_m=1.0),
                     series_view("index pulses (one per revolution)", ["/signals/pulses/**"]), summary_view(),
                     row_shares=[3, 1, 2]),
        rrb.Vertical(series_view("measured: gyro volts (10 Hz means)", ["/signals/raw/**"]),
                     series_view("calibrated (10 Hz means) over the reference per step, °/s",
                                 ["/signals/calibrated/**", "/signals/reference/**"]),
                     series_view("residuals per step (calibrated − reference)", ["/signals/residuals/**"],
                                 y_range=residual_range)),
        column_shares=[2, 3]))


def write_rrd(path, rec: Recording, res: dict, overwrite: bool = True, rows: Rows | None = None) -> None:
    """Write ``path``: the table turning (10 Hz), raw volts and calibrated rates (10 Hz block
    means), the reference rate and the residual of each step, the index pulses, the summary. ``rows``:
    the record's rows (default: those of ``rec``; the streamed campaign's ``rec`` holds its windows only)."""
    model = load_model("turn_table.xml")
    rows = rows or Rows.of(rec)
    k = max(1, int(round((getattr(rows, "sample_rate_hz", None) or rec.sample_rate_hz) / DISPLAY_HZ)))
    # poses: the angle is sampled (not averaged) so the table turns smoothly in the viewer
    idx = np.concatenate([np.arange(b.start, b.stop, k) for b in rows.blocks])
    if rows.spin_at is None:
        return
    t_pose = np.concatenate([rows.time(b.start, b.stop)[::k] for b in rows.blocks])
    qpos = rows.spin_at(idx)[:, None]
    runs = rec.meta.get("runs", ["r_up"])
    tt = (rec.truth or {}).get("rig", {}).get("turn_table", {})
    e = TurnTableErrors(**{k_: v for k_, v in tt.items() if k_ in TurnTableErrors.__dataclass_fields__})
    block_of = np.searchsorted([rows.time(b.start, b.start + 1)[0] for b in rows.blocks], t_pose, side="right") - 1
    q_run = np.array([_quat_wxyz(e.wobble_rotation() @ MOUNTS[r]) for r in runs])
    mount_q = q_run[np.minimum(block_of, len(runs) - 1)]
    cal = res["main"]
    resid = {f"w_{a}": np.degrees(cal.results_[a].residuals_) for a in AXES}
    k_r, unit = readable(np.concatenate(list(resid.values())), "deg/s")
    resid = {n: v * k_r for n, v in resid.items()}
    bp = blueprint(model, symmetric_range(*resid.values()))
    with RrdWriter(path, recording_name="turn-table campaign", overwrite=overwrite, blueprint=bp) as w:
        log_mujoco_model(w, model)
        log_body_poses(w, model, t_pose, qpos, body_quat_overrides={"imu_mount": mount_q})
        log_frame_axes(w, body_path(model, model.body("imu_mount").id), length=0.15)
        t, raw = block_means(rows, list(GYRO), k)
        log_scalars(w, "signals/raw", *break_gaps(t, raw), {c: "V" for c in GYRO}, role="measured")
        c = calibrated_block_means(rows, cal, k, sensitivity=None if cal.sensitivity_ is not None else
                                   nominal_sensitivity(rec, cal.SPEC)[0])
        units = {f"w_{a}": "deg/s" for a in AXES}
        mid = 0.5 * (res["windows"].segments["start_s"] + res["windows"].segments["stop_s"])
        log_scalars(w, "signals/reference", mid, {f"w_{a}": np.degrees(res["reference"][:, j])
                                                  for j, a in enumerate(AXES)}, units, role="truth", points=True,
                    labels={f"w_{a}": f"w_{a} reference [deg/s]" for a in AXES})
        w_cal = {f"w_{a}": np.degrees(c[f"gyro_cal_{a}"]) for a in AXES}
        log_scalars(w, "signals/calibrated", *break_gaps(t, w_cal), units,
                    role="calibrated")
        log_scalars(w, "signals/residuals", mid, resid, {n: unit for n in resid}, role="residual", points=True)
        for i, (name, ev) in enumerate(rec.events.items()):
            if name.startswith("pulse_") and ev.size:
                log_scalars(w, "signals/pulses", ev, {name: np.ones_like(ev)}, {name: "1"}, role="measured",
                            points=True)
        log_text(w, "summary", parameter_table("Turn-table gyro calibration", res["parameters"]))
