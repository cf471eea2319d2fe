"""The nominal sensitivity of a sensor triad's channels, whatever unit they come in (volts, ADC
counts, or SI units already scaled by the maker): the indicated quantity is u = x / s_nom (SI)."""
from __future__ import annotations

import numpy as np

from imurig.kernel.errors import RecordingError
from imurig.kernel.recording import Recording


def nominal_sensitivity(rec: Recording, spec, channels=None) -> tuple[np.ndarray, str]:
    """(nominal sensitivity s (3,), channel unit) so that the indicated quantity is u = x / s (SI).

    What is assumed, by the channels' unit (all three the same):
    - ``V``: volts per SI unit from the metadata ``spec.sensitivity_key`` (required);
    - ``1`` (ADC counts): counts per SI unit from the metadata key with ``_V_per_`` replaced by
      ``_counts_per_`` (e.g. ``acc_nominal_sensitivity_counts_per_m_s2``), else ``spec.sensitivity_key``;
    - the triad's own SI unit (m/s^2, rad/s: values already scaled by the maker): s = 1 (SI per SI),
      and the calibration fits the errors that remain.
    """
    channels = spec.channels if channels is None else channels
    missing = [c for c in channels if c not in rec.channels]
    if missing:
        raise RecordingError(f"recording lacks channel(s) {missing}; it has {sorted(rec.channels)}. Add them "
                             f"(CSV columns such as '{missing[0]}_V', '{missing[0]}_counts' or in SI units)")
    units = {rec.units[c] for c in channels}
    if len(units) != 1:
        raise RecordingError(f"the {spec.kind} channels {list(channels)} come in different units "
                             f"{sorted(units)}; give all three in one unit (V, counts or {spec.quantity_unit})")
    unit = units.pop()
    if unit == spec.quantity_unit:
        return np.ones(3), unit
    if unit not in ("V", "1"):
        raise RecordingError(f"the {spec.kind} channels are in {unit}; give them in V, ADC counts or "
                             f"{spec.quantity_unit}")
    keys = [spec.sensitivity_key.replace("_V_per_", "_counts_per_")] * (unit == "1") + [spec.sensitivity_key]
    s = next((rec.meta[k] for k in keys if rec.meta.get(k) is not None), None)
    if s is None:
        per = "volts" if unit == "V" else "ADC counts"
        raise RecordingError(f"the recording has no '{keys[0]}' metadata ({per} per {spec.quantity_unit} of "
                             f"each {spec.kind}{spec.sensitivity_hint if unit == 'V' else ''}); add it as "
                             f"'# {keys[0]}: [s_1, s_2, s_3]' or pass it")
    s = np.broadcast_to(np.asarray(s, float), (3,)).copy()
    if not np.all(np.isfinite(s)) or np.any(s == 0):
        raise RecordingError(f"the nominal sensitivity '{keys[0]}' = {s.tolist()} must be finite and non-zero")
    return s, unit
