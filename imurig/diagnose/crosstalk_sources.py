"""Leak sources of the tilt-table crosstalk test where the scan order is unknown.

A file without ``adc.scan_list`` does not say which channel is converted before an accelerometer,
so every logged voltage channel outside the triad and the temperatures is a candidate source
(:func:`imurig.diagnose.samples.leak_sources`; the engine scans them, its max-statistic threshold
counting the choice). Two kinds of source cannot be used as logged:

- **at the rail**: a source whose per-position value sits at the converter's end code at some
  positions (:func:`imurig.diagnose.samples.at_rail`) logged the rail, not the voltage that leaked.
  Where the source measures a field fixed in the lab (a magnetometer), its value at position i is

      v_i = a + sum_{l, c} M_lc e_l,c(i),    e_l(i) = the lab axis l in the triad's axes at position i,

  linear in the 9 components of the three lab axes (e_z = the reference's gravity direction,
  e_x = -(d ref / d theta_zero) / g, e_y = e_z x e_x). Fitted on the positions within the rails,
  it gives the clipped positions' values when it holds to ``MAX_FIELD_RMS`` of the source's
  spread; otherwise the source is not tested;
- **absorbed**: a source whose column keeps less than ``MIN_SOURCE_RETAINED`` of its centred norm
  outside the twin's columns X0 (the survey's table-zero errors, the linear terms) is not tested
  on that axis: the twin would absorb such a leak (a magnetometer axis' horizontal field along the
  accelerometer's own axis is a theta-zero error's column).
"""
from __future__ import annotations

import numpy as np

from imurig.diagnose.samples import leak_sources

#: the least fraction of a leak source's column (centred) that must lie outside the twin's columns
MIN_SOURCE_RETAINED = 0.01
#: the largest RMS misfit of the lab-fixed-field model, relative to the source's spread, to fill its clipped positions
MAX_FIELD_RMS = 1e-3

#: a leak from another axis of the triad, which the position means cannot tell from a misalignment
TRIAD_LEAK_VS_MISALIGNMENT = {
    "effects": ["adc_crosstalk", "axis_misalignment"],
    "note": "with the scan order unknown, crosstalk from the triad's own other axes is not tested: its column "
            "(the other axis' per-position voltage) is an affine function of that axis' reading, i.e. the "
            "misalignment's column m_jk; only sources outside the triad (magnetometer, ...) can be named"}


def lab_axes_basis(ref: np.ndarray, J: np.ndarray) -> np.ndarray | None:
    """(m, 10): a constant and the three lab axes' components in the triad's axes at each position,
    from the reference ref (m, 3) and its theta-zero derivative J[:, :, 0]; None when they are not
    an orthonormal pair (a table whose theta is not the first rotation)."""
    g = np.linalg.norm(ref, axis=1, keepdims=True)
    ez, ex = ref / g, -J[:, :, 0] / g
    if not (np.allclose(np.linalg.norm(ex, axis=1), 1.0, atol=1e-4) and np.all(np.abs(np.sum(ex * ez, 1)) < 1e-4)):
        return None
    return np.column_stack([np.ones(ref.shape[0]), ex, np.cross(ez, ex), ez])


def fill_at_rail(v: np.ndarray, rail: np.ndarray, basis: np.ndarray | None) -> tuple[np.ndarray | None, float]:
    """(v with its positions at the rail replaced by the lab-fixed-field fit, the fit's relative RMS),
    or (None, rms) when the fit is not possible or does not hold (module doc)."""
    ok = ~rail
    if basis is None or ok.sum() < basis.shape[1] + 5:
        return None, float("nan")
    coef, *_ = np.linalg.lstsq(basis[ok], v[ok], rcond=None)
    r = v[ok] - basis[ok] @ coef
    spread = float(np.std(v[ok]))
    rel = float(np.sqrt(np.mean(r ** 2)) / spread) if spread > 0 else float("inf")
    if np.linalg.matrix_rank(basis[ok]) < np.linalg.matrix_rank(basis) or not rel <= MAX_FIELD_RMS:
        return None, rel
    out = np.array(v, float)
    out[rail] = basis[rail] @ coef
    return out, rel


def unknown_scan_sources(raw, rec100, medians, cache: dict, ref: np.ndarray, J: np.ndarray,
                         triad: tuple[str, ...]) -> tuple[tuple, dict]:
    """(sources to test, report) for a file without a scan order; a source at the rail whose
    lab-fixed-field fit holds gets its clipped positions filled in ``cache`` (name -> column).
    ``raw``: the record as logged (:func:`imurig.diagnose.raw_record.as_raw`: its ``at_rail``)."""
    sources, clipped, filled = [], {}, {}
    basis = lab_axes_basis(ref, J)
    for k in leak_sources(rec100, triad):
        rail = raw.at_rail(k, medians(k))
        if not rail.any():
            sources.append(k)
            continue
        v, rel = fill_at_rail(medians(k), rail, basis)
        if v is None:
            clipped[k] = {"positions_at_rail": int(rail.sum()), "field_fit_relative_rms": rel}
            continue
        cache[k] = v
        sources.append(k)
        filled[k] = {"positions_at_rail": int(rail.sum()), "field_fit_relative_rms": rel}
    report = {"crosstalk_sources_tested": sources}
    if filled:
        report["crosstalk_sources_filled"] = {
            **filled, "note": "at the positions where these sources sit at the converter's rail, their value is "
                              "the fit of a field fixed in the lab (constant + the lab axes' components in the triad's "
                              "axes) to their other positions"}
    if clipped:
        report["crosstalk_sources_clipped"] = {
            **clipped, "note": "not tested as leak sources: at those positions the logged value is the converter's "
                               "rail, not the voltage that would leak, and a field fixed in the lab does not fit "
                               "their other positions"}
    return tuple(sources), report


def identifiable_sources(sources, medians, X0: np.ndarray) -> tuple[tuple, dict]:
    """(testable, absorbed) leak sources of one axis: absorbed ones keep less than
    ``MIN_SOURCE_RETAINED`` of their centred norm outside X0, ||(I - P_X0) v|| / ||v - mean||
    (the fraction is returned per source)."""
    if not sources:
        return (), {}
    Q, _ = np.linalg.qr(X0)
    keep, absorbed = [], {}
    for k in sources:
        v = np.asarray(medians(k), float)
        spread = np.linalg.norm(v - v.mean())
        frac = float(np.linalg.norm(v - Q @ (Q.T @ v)) / spread) if spread > 0 else 0.0
        if frac >= MIN_SOURCE_RETAINED:
            keep.append(k)
        else:
            absorbed[k] = frac
    return tuple(keep), absorbed


def absorbed_note(ch: str, absorbed: dict) -> dict:
    return {"effects": ["adc_crosstalk", "survey/twin terms"], "sources": absorbed,
            "note": f"a leak into '{ch}' from {sorted(absorbed)} is not tested: those channels' per-position values "
                    f"keep less than {MIN_SOURCE_RETAINED:g} of their spread outside the twin's columns (the "
                    "fraction left is given per source), so the twin's terms would absorb such a leak"}
