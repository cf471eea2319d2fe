"""The triad calibration's file (``calibration.json``): what :class:`imurig.calibration.triad.TriadCalibration`
writes with ``to_dict`` and reads back, every part checked, with ``from_dict``.

    {"kind": "<spec.json_kind>", "version": 1, "model": ..., "statistic": ...,
     "nominal_sensitivity": [s_x, s_y, s_z] or null, "nominal_sensitivity_unit": "V/(<quantity unit>)",
     "equation": "ref_i = sum_k coef_ik * term_k(u), u = volts / nominal_sensitivity",
     "axes": {"<axis>": {"terms": ["1", "u_x", ...], "coef": [...]}, ...}}
"""
from __future__ import annotations

import numpy as np

from imurig.calibration.terms import TermLibrary


def unit_word(unit: str) -> str:
    """A channel unit as the file names it ("1": counts)."""
    return "counts" if unit == "1" else unit


def triad_dict(spec, model: str, statistic: str, sensitivity, channel_unit: str, models: dict) -> dict:
    """The file's content (module doc) for a triad ``spec`` with the inverse ``models`` {axis: (terms, coef)}."""
    return {"kind": spec.json_kind, "version": 1, "model": model,
            "statistic": statistic,
            "nominal_sensitivity": None if sensitivity is None else np.asarray(sensitivity).tolist(),
            "nominal_sensitivity_unit": f"{unit_word(channel_unit)}/({spec.quantity_unit})",
            "equation": f"ref_i [{spec.quantity_unit}] = sum_k coef_ik * term_k(u), u = volts / "
                        "nominal_sensitivity",
            "axes": {a: {"terms": n, "coef": np.asarray(c).tolist()} for a, (n, c) in models.items()}}


def read_triad_dict(d, spec) -> tuple[dict, str, str, np.ndarray | None]:
    """(models {axis: (terms, coef)}, model, statistic, nominal sensitivity (3,) or None) of the file's content
    ``d`` for a triad ``spec``; a ValueError says which part is wrong and what it must be."""
    kind = spec.json_kind
    if not isinstance(d, dict) or d.get("kind") != kind:
        got = d.get("kind") if isinstance(d, dict) else type(d).__name__
        raise ValueError(f"not an imurig {spec.kind} calibration (kind must be '{kind}', got "
                         f"{got!r}); use the calibration.json of a report folder")
    axes = d.get("axes")
    if not isinstance(axes, dict) or sorted(axes) != sorted(spec.axes):
        raise ValueError(f"'axes' must map each of {list(spec.axes)} to its terms and coefficients")
    models = {}
    for a in spec.axes:
        v = axes[a]
        terms, coef = (v.get("terms"), v.get("coef")) if isinstance(v, dict) else (None, None)
        if not isinstance(terms, list) or not isinstance(coef, list) or len(terms) != len(coef) or not terms:
            raise ValueError(f"axis {a}: 'terms' and 'coef' must be lists of the same, non-zero length")
        try:
            lib = TermLibrary.from_names(terms)
            c = np.asarray(coef, float)
        except (TypeError, ValueError) as e:
            raise ValueError(f"axis {a}: {e}") from None
        unknown = sorted(set(lib.inputs) - set(spec.inputs))
        if unknown or not np.all(np.isfinite(c)):
            raise ValueError(f"axis {a}: " + (f"unknown inputs {unknown} (known: {list(spec.inputs)})"
                                              if unknown else "coefficients must be finite numbers"))
        models[a] = (list(terms), c)
    s = d.get("nominal_sensitivity")
    try:
        sensitivity = None if s is None else np.broadcast_to(np.asarray(s, float), (3,)).copy()
    except (TypeError, ValueError):
        raise ValueError(f"'nominal_sensitivity' must be three numbers, got {s!r}") from None
    if sensitivity is not None and not np.all(np.isfinite(sensitivity) & (sensitivity != 0)):
        raise ValueError("'nominal_sensitivity' must be finite and non-zero")
    return models, str(d.get("model", "loaded")), str(d.get("statistic", "median")), sensitivity
