"""Saturation and clipping: the converter (or the sensor's output stage) cannot go beyond its range.

    v'(t) = min(max(v(t), -range_V), +range_V)                       [V],  on ``channel``

Stage "analog" (applied per line before the converter; the simulator's DAQ clips its codes too).

Diagnosis (:class:`~imurig.sensors.effects.views.RawChannelView`, the channel as logged): a clip
is a flat top, a run of samples held at the record's extreme level L (max or min) within
q / 2 (q: the ADC step; 1e-9 |L| for unquantised values). Without clipping, k equal samples in a
row at one level have probability about P^(k-1), P = min(1, q / (2 sqrt(pi) s)) the chance that a
first difference of white noise s (from the second differences, free of a slow signal's slope:
s = 1.4826 MAD(diff2) / sqrt(6), floored at q / sqrt(12)) rounds to zero; runs of at least k_min = max(3, 1 + log(alpha / n) / log P)
samples are flat tops. Where the step exceeds the noise (P near 1: every sample repeats its code)
a run proves nothing, and only the converter's known range can: the level must lie within 1.5 q
of +-range_V. The finding reports the level (V), the clipped fraction of the record, the number
of runs and the first clipped time.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from imurig.sensors.effects.base import ChainContext, Effect, Param
from imurig.sensors.effects.views import RawChannelView


def _runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(starts, lengths) of the runs of True in ``mask``."""
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    starts, stops = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
    return starts, stops - starts


@dataclass
class Saturation(Effect):
    """Clipping of ``channel`` at +-``range_V`` (V)."""

    enabled: bool = False
    channel: str = "acc_x"
    range_V: float = 5.0

    name: ClassVar[str] = "saturation"
    stage: ClassVar[str] = "analog"
    physics: ClassVar[str] = "the channel is clipped at the end of its range (flat tops at a constant level)"
    seed_section: ClassVar[str] = "2 (the DAQ's +-5 V range)"
    seed_says: ClassVar[str] = "– (the seed's signals stay inside the converter's range)"
    params: ClassVar[tuple] = (Param("level_V", "V"), Param("fraction", "1"))
    views: ClassVar[tuple] = (RawChannelView.kind,)
    finding_key: ClassVar[str] = "finding_saturation"

    def lines(self, names, ctx: ChainContext | None = None) -> list[str]:
        if not self.enabled:
            return []
        if self.channel not in names:
            raise ValueError(f"saturation on '{self.channel}', which is not an analog line; choose one of {sorted(names)}")
        return [self.channel]

    def inject(self, v: np.ndarray, ctx: ChainContext | None = None, rng: np.random.Generator | None = None) -> np.ndarray:
        """v clipped to [-range_V, +range_V] (module doc)."""
        return np.clip(v, -self.range_V, self.range_V) if self.enabled else v

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        """{level_V}: the clip level on ``channel`` (0 where nothing is clipped)."""
        c = (truth.get("chain") or {}).get("saturation") or {}
        on = bool(c.get("enabled")) and (channel is None or channel == c.get("channel"))
        return {"level_V": float(c["range_V"]) if on else 0.0}

    def test(self, view: RawChannelView) -> dict:
        """The flat-top test at both extremes (module doc); 'finding' when one holds."""
        x = np.asarray(view.samples, float)
        n = x.size
        if n < 10:
            return {}
        q = float(view.quantum_V or 0.0)
        d2 = np.diff(x, 2)                    # a slow signal's slope drops out; white noise: var 6 s^2
        s = max(1.4826 * float(np.median(np.abs(d2 - np.median(d2)))) / np.sqrt(6), q / np.sqrt(12))
        P = 1.0 if s <= 0 else min(1.0, q / (2 * np.sqrt(np.pi) * s)) if q > 0 else 0.0
        k_min = 3 if P <= 0 else (np.inf if P >= 0.5 else max(3, int(np.ceil(1 + np.log(view.alpha / n) / np.log(P)))))
        out = {"saturation_noise_V": s, "saturation_min_run": None if not np.isfinite(k_min) else int(k_min)}
        best = None
        for L in (float(np.max(x)), float(np.min(x))):
            tol = max(0.5 * q, 1e-9 * abs(L))
            starts, lengths = _runs(np.abs(x - L) <= tol)
            at_range = view.range_V is not None and abs(L) >= float(view.range_V) - 1.5 * q
            keep = lengths >= (2 if at_range else k_min)
            if not keep.any():
                continue
            m = int(lengths[keep].sum())
            if best is None or m > best["samples"]:
                best = {"effect": self.name, "physics": f"'{view.channel}' is clipped at {L:.6g} V (flat tops)",
                        "level_V": L, "fraction": m / n, "samples": m, "runs": int(keep.sum()),
                        "first_time_s": float(np.asarray(view.time_s)[starts[keep][0]]),
                        "evidence": "at the converter's range" if at_range else
                                    f"runs of >= {int(k_min)} equal samples where the noise ({s:.3g} V) resolves the step"}
        if best is not None:
            out["finding"] = best
        elif not np.isfinite(k_min) and view.range_V is None:
            out["saturation_tested"] = "no: the ADC step exceeds the noise and the converter's range is unknown"
        return out
