"""The magnetometer diagnosis' twin: the recording's manoeuvres re-run in the IGRF field.

The manoeuvres of ``meta["manoeuvres"]`` are re-run on the MuJoCo gimbal
(:class:`imurig.rigs.mag_rig.MagRig`) at the site and time of the recording, in the IGRF field
there, with the DAQ's known channel skew (slot j of the scan is sampled j / f_mux late). It gives
the reference field in the case frame B_ref (n, 3) [nT], its rate dB/dt, and, from the gimbal's
specific force and field (TRIAD), the attitude R_CW (v_C = R_CW v_W).
"""
from __future__ import annotations

import functools
import json
from dataclasses import dataclass

import numpy as np

from imurig.kernel.errors import RecordingError
from imurig.kernel.recording import Recording
from imurig.kernel.site import Site, parse_time
from imurig.rigs import mag_rig
from imurig.rigs.mag_rig import MagRig

AXES = "xyz"
MAG = ("mag_x", "mag_y", "mag_z")
NT = 1e9


def _manoeuvres(meta: dict) -> list:
    out = []
    for m in meta.get("manoeuvres", []):
        kw = {k: v for k, v in m.items() if k != "kind"}
        kind = getattr(mag_rig, m.get("kind", ""), None)
        if kind is None:
            raise RecordingError(f"unknown manoeuvre kind {m.get('kind')!r} in the recording's metadata; "
                                 "expected LevelCircle, Tumble or CompassSwing (imurig.rigs.mag_rig)")
        if "headings_deg" in kw:
            kw["headings_deg"] = tuple(kw["headings_deg"])
        if "wobble_deg" in kw:
            kw["wobble_deg"] = 0.0  # the twin follows the commands; a taxi wobble is not a set-point
        out.append(kind(**kw))
    if not out:
        raise RecordingError("the recording's metadata lists no 'manoeuvres': the twin cannot be built "
                             "(a magnetometer recording needs meta['manoeuvres'], see imurig.rigs.mag_rig)")
    return out


def twin_key(site: dict, start_time: str, rate: float, manoeuvres: list) -> str:
    return json.dumps({"site": Site.from_dict(site).to_dict(), "start_time": start_time, "rate": float(rate),
                       "manoeuvres": manoeuvres}, sort_keys=True, default=list)


@functools.lru_cache(maxsize=2)
def twin_rig(key: str) -> Recording:
    """The gimbal run of the manoeuvres in ``key`` in the IGRF field (the twin's rig; cached)."""
    d = json.loads(key)
    return MagRig(site=Site.from_dict(d["site"]), record_rate_hz=d["rate"]).simulate(
        _manoeuvres(d), d["start_time"], np.random.default_rng(0))


@functools.lru_cache(maxsize=4)
def _twin_cached(key: str):
    d = json.loads(key)
    site = Site.from_dict(d["site"])
    rig = twin_rig(key)
    B = np.column_stack([rig.truth_signals[f"B_C_{a}"] for a in AXES])
    f = np.column_stack([rig.truth_signals[f"f_C_{a}"] for a in AXES])
    B_W = site.magnetic_field_W(parse_time(d["start_time"]))
    return rig.time_s, B, _triad(f, B, np.array([0.0, 0.0, 1.0]), B_W), B_W


def _triad(v1_C, v2_C, v1_W, v2_W) -> np.ndarray:
    """R_CW (n, 3, 3) from two vectors known in both frames (TRIAD): v_C = R_CW v_W."""
    def basis(a, b):
        t1 = a / np.linalg.norm(a, axis=-1, keepdims=True)
        t2 = np.cross(a, b)
        t2 = t2 / np.linalg.norm(t2, axis=-1, keepdims=True)
        return np.stack([t1, t2, np.cross(t1, t2)], axis=-1)   # columns t1, t2, t3
    Mc = basis(v1_C, v2_C)
    Mw = basis(v1_W[None], v2_W[None])
    return Mc @ np.swapaxes(Mw, -1, -2)


@dataclass
class Twin:
    """The twin on the recording's samples: B_ref (n, 3) [nT] with the DAQ skew, its rate
    dB (n, 3) [nT/s], R_CW (n, 3, 3), the IGRF field B_W (3,) [nT]."""

    B_ref: np.ndarray
    dB: np.ndarray
    R_CW: np.ndarray
    B_W: np.ndarray
    skew_s: np.ndarray


def build_twin(rec: Recording) -> Twin:
    """Re-run the recording's manoeuvres on the gimbal in the IGRF field (see module doc)."""
    meta = rec.meta
    for k in ("site", "start_time", "manoeuvres"):
        if k not in meta:
            raise RecordingError(f"the recording's metadata lacks '{k}': the twin is built from the site, the "
                                 "start time and the manoeuvres (imurig.rigs.mag_rig) of the recording")
    key = twin_key(meta["site"], meta["start_time"], meta.get("sample_rate_hz", rec.sample_rate_hz),
                    meta["manoeuvres"])
    t, B, R, B_W = _twin_cached(key)
    if t.size != rec.n or np.max(np.abs(t - rec.time_s)) > 0.25 / rec.sample_rate_hz:
        raise RecordingError(f"the recording's time base ({rec.n} samples) does not match its manoeuvres' "
                             f"schedule ({t.size} samples): the twin is built from meta['manoeuvres'] and "
                             "expects the rig's own time stamps")
    B = B * NT
    dB = np.gradient(B, t, axis=0)
    adc = meta.get("adc", {})
    skew = np.zeros(3)
    if adc.get("skew_enabled") and adc.get("mux_frequency_hz"):
        scan = list(adc.get("scan_list", []))
        skew = np.array([scan.index(c) / adc["mux_frequency_hz"] if c in scan else 0.0 for c in MAG])
    return Twin(B + dB * skew, dB, R, B_W * NT, skew)
