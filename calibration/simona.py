"""SIMONA flight-simulator IMU: rough gyro calibration on the turn table (seed section 4.4.2).

The seed's experiment: the three gyros of the SIMONA IMU sit on the Genisco C181 turn
table (clockwise). For each dial setting the table's optical once-per-round pulse starts
and stops a stopwatch (microsecond resolution) and the three gyro output voltages are
read off a voltmeter (autoscale). The data are the seed's Appendix B, Table B.1, shipped
as ``imurig.assets/simona_gyro_table_b1.csv``.

Measurement equations (SI inside; deg/s only in reported and plotted values)
---------------------------------------------------------------------------
Reference rate from the stopwatch, per row ``i`` whose round was timed::

    omega_ref_i [rad/s] = 2*pi [rad] / T_round_i [s]

and ``omega_ref_i = 0`` for the row at rest (``rate_dial = 0``, round not timed).

Own linear calibration of each gyro ``k`` in {p, q, r} (least squares over the chosen rows;
:class:`SimonaCalibration`)::

    omega_ref_i [deg/s] = beta0_k [deg/s] + beta1_k [(deg/s)/V] * V_k,i [V] + e_i

so the gyro's own scale factor is ``S_k = 1/beta1_k`` V/(deg/s), reported as
``1000/beta1_k`` mV/(deg/s) with standard error ``1000 * se(beta1_k) / beta1_k**2``
(first-order propagation).

Manufacturer's calibration (nominal sensitivity ``S_nom`` = 6 mV/(deg/s), i.e.
0.006/(pi/180) V/(rad/s), stored in the recording's meta)::

    omega_mfr_i [rad/s] = V_k,i [V] / S_nom [V/(rad/s)]        (= V / 0.006 in deg/s)

Residuals are reference minus calibrated rate (deg/s for reporting).

Row recording
-------------
:func:`read_simona` returns a *row-level* :class:`~imurig.kernel.recording.Recording`: one sample
per table row. The real table has no clock (one row per dial setting), so ``time_s`` is
just the row index 0, 1, 2, ... in seconds, and segment ``i`` spans ``[i, i + 1)`` s, i.e.
exactly sample ``i``. A virtual turn table that wants its output compared with the real
table must produce a Recording in this same format.
"""
from __future__ import annotations

import csv
import io
import math
from importlib import resources
from pathlib import Path
from typing import Self

import numpy as np

from imurig.calibration.regression import fit_ols
from imurig.kernel.errors import RecordingError
from imurig.kernel.estimator import Estimator
from imurig.kernel.recording import Recording
from imurig.kernel.units import DEG, split_column, to_si

__all__ = [
    "ASSET_NAME",
    "GYROS",
    "MANUFACTURER_SENSITIVITY_V_PER_DPS",
    "MANUFACTURER_SENSITIVITY_V_PER_RAD_S",
    "SEED_CONCLUSION",
    "read_simona",
    "measured_rate",
    "SimonaCalibration",
]

ASSET_NAME = "simona_gyro_table_b1.csv"
GYROS = ("p", "q", "r")
#: Manufacturer's nominal gyro sensitivity: 6 mV per deg/s (seed section 4.4.2, Fig. 4.19).
MANUFACTURER_SENSITIVITY_V_PER_DPS = 6e-3
MANUFACTURER_SENSITIVITY_V_PER_RAD_S = MANUFACTURER_SENSITIVITY_V_PER_DPS / DEG
SEED_CONCLUSION = "Even this rough calibration is way more accurate than the data provided by the manufacturer"

#: CSV column -> recording channel name (the unit comes from the column's suffix).
_COLUMNS = {
    "rate_dial_dps": "rate_dial",
    "rate_nominal_dps": "rate_nominal",
    "expected_round_s": "expected_round",
    "measured_round_s": "measured_round",
    "p_V": "gyro_p",
    "q_V": "gyro_q",
    "r_V": "gyro_r",
}


# ---------------------------------------------------------------------------- import
def _read_text(path) -> tuple[str, str]:
    if path is None:
        res = resources.files("imurig.assets").joinpath(ASSET_NAME)
        return res.read_text(encoding="utf-8"), f"imurig.assets/{ASSET_NAME} (seed appendix B, Table B.1)"
    p = Path(path)
    if not p.is_file():
        raise RecordingError(f"{p} does not exist or is not a file; pass the path of the SIMONA table CSV "
                             "or None for the packaged seed table")
    return p.read_text(encoding="utf-8"), str(p)


def _parse_table(text: str, source: str) -> tuple[list[str], np.ndarray]:
    """The CSV's ``#`` comments and its table (n, 7) of the :data:`_COLUMNS`, in lab units; refuses
    missing columns and non-numeric, non-finite or short rows (RecordingError naming the line)."""
    notes, body = [], []
    for line in text.splitlines():
        s = line.strip()
        if s.startswith("#"):
            notes.append(s.lstrip("#").strip())
        elif s:
            body.append(line)
    if not body:
        raise RecordingError(f"{source}: no header line (only comments or empty)")
    reader = csv.reader(io.StringIO("\n".join(body)))
    header = [h.strip() for h in next(reader)]
    missing = [c for c in _COLUMNS if c not in header]
    if missing:
        raise RecordingError(f"{source}: missing column(s) {missing}; the header has {header}. "
                             f"Expected columns: {list(_COLUMNS)}")
    idx = {c: header.index(c) for c in _COLUMNS}
    rows = []
    for lineno, fields in enumerate(reader, start=2):
        if not any(f.strip() for f in fields):
            continue
        if len(fields) != len(header):
            raise RecordingError(f"{source}: data line {lineno} has {len(fields)} fields, the header "
                                 f"has {len(header)}; fix the row")
        vals = []
        for c in _COLUMNS:
            raw = fields[idx[c]].strip()
            try:
                v = float(raw)
            except ValueError:
                raise RecordingError(f"{source}: non-numeric value {raw!r} in column '{c}' on data line "
                                     f"{lineno}; use a number with a decimal point") from None
            if not math.isfinite(v):
                raise RecordingError(f"{source}: non-finite value {raw!r} in column '{c}' on data line "
                                     f"{lineno}; drop the row or give the value")
            vals.append(v)
        rows.append(vals)
    if len(rows) < 2:
        raise RecordingError(f"{source}: {len(rows)} data row(s); at least two are needed")
    return notes, np.array(rows, dtype=float)  # (n, 7) in lab units


def read_simona(path=None) -> Recording:
    """Import the SIMONA gyro table (seed Table B.1) as a row-level Recording.

    Parameters
    ----------
    path : CSV file, or ``None`` for the packaged copy ``imurig.assets/simona_gyro_table_b1.csv``.
        ``#`` lines are free-text comments (kept in ``meta["notes"]``); the header must hold
        ``rate_dial_dps, rate_nominal_dps, expected_round_s, measured_round_s, p_V, q_V, r_V``
        (extra columns are ignored).

    Returns
    -------
    Recording with one sample per row (the table has no clock):

    * ``time_s`` = 0, 1, 2, ... (row index, s); segment ``i`` = ``[i, i + 1)`` s with
      set-points ``rate_dial`` (rad/s) and ``row`` (index);
    * channels (SI): ``rate_dial``, ``rate_nominal`` (rad/s; nominal = dial * 5/6 because the
      table's 60 Hz synchronous motor runs on 50 Hz mains), ``expected_round``,
      ``measured_round`` (s; ``expected = 2*pi / rate_nominal``), ``gyro_p``, ``gyro_q``,
      ``gyro_r`` (V), and ``round_measured`` (1 = the round was timed, 0 = not timed);
    * the table's first row (at rest) prints round times 0, meaning "not measured"; it is
      kept with ``expected_round = measured_round = 0`` s and ``round_measured = 0`` (NaN
      would not pass :meth:`Recording.validate`);
    * ``meta``: rig ``turn_table``, source, direction ``clockwise``, ``row_recording``,
      instrument, ``notes`` (the CSV comments) and
      ``gyro_nominal_sensitivity_V_per_rad_s`` (manufacturer: 6 mV/(deg/s) for p, q, r).

    Raises
    ------
    RecordingError : missing file, missing column (named), non-numeric or non-finite value
        (row and column named), a negative round time, or fewer than two rows.
    """
    text, source = _read_text(path)
    notes, table = _parse_table(text, source)
    channels, units = {}, {}
    for j, (col, name) in enumerate(_COLUMNS.items()):
        _, spec = split_column(col)
        channels[name] = to_si(table[:, j], spec)
        units[name] = spec.si
    for c in ("expected_round", "measured_round"):
        if np.any(channels[c] < 0):
            i = int(np.flatnonzero(channels[c] < 0)[0])
            raise RecordingError(f"{source}: negative round time in '{c}_s' on data row {i}; "
                                 "a round time is > 0 s, or 0 for 'not measured'")
    channels["round_measured"] = (channels["measured_round"] > 0).astype(float)
    units["round_measured"] = "1"
    n = table.shape[0]
    t = np.arange(n, dtype=float)
    sens = MANUFACTURER_SENSITIVITY_V_PER_RAD_S
    rec = Recording(
        time_s=t,
        channels=channels,
        units=units,
        segments={"start_s": t.copy(), "stop_s": t + 1.0, "rate_dial": channels["rate_dial"].copy(),
                  "row": np.arange(n)},
        segment_units={"start_s": "s", "stop_s": "s", "rate_dial": "rad/s", "row": "1"},
        meta={
            "rig": "turn_table",
            "table": "Genisco C181",
            "source": source,
            "direction": "clockwise",
            "row_recording": True,
            "time_base": "row index (the table has no clock: one row per dial setting)",
            "instrument": "voltmeter (autoscale)",
            "stopwatch": "optical once-per-round pulse, microsecond resolution",
            "notes": notes,
            "gyro_nominal_sensitivity_V_per_rad_s": {g: sens for g in GYROS},
        },
    )
    return rec.validate()


# ---------------------------------------------------------------------- reference
def measured_rate(rec: Recording) -> np.ndarray:
    """Reference rate per row from the stopwatch, rad/s: ``2*pi / measured_round``.

    Rows whose round was not timed (``round_measured == 0``, or ``measured_round == 0`` when
    that channel is absent) must be at rest (``rate_dial == 0``) and get 0 rad/s.
    Raises RecordingError for an untimed row that is not at rest (no reference exists).
    """
    rec.require({"measured_round": "s", "rate_dial": "rad/s"})
    T = rec.channels["measured_round"]
    if "round_measured" in rec.channels:
        timed = rec.channels["round_measured"] > 0.5
    else:
        timed = T > 0
    if np.any(timed & ~(T > 0)):
        i = int(np.flatnonzero(timed & ~(T > 0))[0])
        raise RecordingError(f"row {i} is marked as timed but measured_round = {T[i]!r} s; a timed round is > 0 s")
    moving = ~timed & (rec.channels["rate_dial"] != 0)
    if np.any(moving):
        raise RecordingError(f"rows {np.flatnonzero(moving).tolist()} were not timed but the table was turning "
                             "(rate_dial != 0): no reference rate; drop those rows (SimonaCalibration(rows=...))")
    return np.where(timed, 2.0 * np.pi / np.where(timed, T, 1.0), 0.0)


def _sensitivity(rec: Recording, g: str) -> float:
    s = rec.meta.get("gyro_nominal_sensitivity_V_per_rad_s", {})
    return float(s.get(g, MANUFACTURER_SENSITIVITY_V_PER_RAD_S)) if isinstance(s, dict) else float(s)


def _row_index(n: int, rows) -> np.ndarray:
    if rows is None:
        return np.arange(n)
    try:
        idx = np.arange(n)[rows]
    except (IndexError, TypeError) as exc:
        raise ValueError(f"rows must be a slice, index array or boolean mask over {n} rows: {exc}") from None
    return np.atleast_1d(idx)


# ---------------------------------------------------------------------------- fit
def _gyro_summary(rec: Recording, g: str, idx: np.ndarray, ref_dps: np.ndarray) -> dict:
    """Own and manufacturer's calibration of gyro ``g`` on rows ``idx`` (see :class:`SimonaCalibration`)."""
    V = rec.channels[f"gyro_{g}"][idx]
    X = np.column_stack([np.ones_like(V), V])
    res = fit_ols(X, ref_dps, ["1", f"V_{g}"])
    b0, b1 = res.coef_
    se0, se1 = res.std_error_
    sens = _sensitivity(rec, g)  # V/(rad/s)
    mfr_dps = V / sens / DEG
    mres = ref_dps - mfr_dps
    return {
        "result": res,
        "rows": idx,
        "voltage_V": V,
        "reference_rate_dps": ref_dps,
        "beta0_dps": float(b0),
        "beta0_se_dps": float(se0),
        "beta1_dps_per_V": float(b1),
        "beta1_se_dps_per_V": float(se1),
        "scale_mV_per_dps": float(1e3 / b1),
        "scale_se_mV_per_dps": float(1e3 * se1 / b1**2),
        "residuals_dps": res.residuals_,
        "sigma_res_dps": float(res.sigma_res),
        "max_abs_residual_dps": float(np.max(np.abs(res.residuals_))),
        "manufacturer_scale_mV_per_dps": float(sens * DEG * 1e3),
        "manufacturer_rate_dps": mfr_dps,
        "manufacturer_residuals_dps": mres,
        "manufacturer_sigma_dps": float(np.std(mres, ddof=1)),
        "manufacturer_rms_dps": float(np.sqrt(np.mean(mres**2))),
        "manufacturer_max_abs_dps": float(np.max(np.abs(mres))),
    }


class SimonaCalibration(Estimator):
    """Linear calibration of the p, q, r gyros against the stopwatch rate (seed section 4.4.2).

    For each gyro ``k``, on the selected rows::

        omega_ref [deg/s] = beta0 [deg/s] + beta1 [(deg/s)/V] * V_k [V]     (fit_ols)
        omega_mfr [deg/s] = V_k / S_nom,   S_nom = 6 mV/(deg/s) (from rec.meta)

    Setting ``rows``: the rows to use: ``None`` (all), a slice (``slice(0, -9)``: before the
    voltmeter changed range for the last nine rows; ``slice(-9, None)``: after), an index array or a mask.
    ``fit(rec)`` takes a row recording as from :func:`read_simona` (or a virtual twin in the same format).

    Fitted: ``coef_`` (3, 2) [beta0 deg/s, beta1 (deg/s)/V] per gyro p, q, r; ``results_``
    {gyro: RegressionResult (deg/s)}; ``rows_`` the row indices used; ``summary_`` {gyro: dict} with
    ``result``, ``rows``, ``voltage_V``, ``reference_rate_dps``, ``beta0_dps``, ``beta0_se_dps``,
    ``beta1_dps_per_V``, ``beta1_se_dps_per_V``, ``scale_mV_per_dps`` (= 1000/beta1),
    ``scale_se_mV_per_dps`` (= 1000 se(beta1)/beta1^2), ``residuals_dps``, ``sigma_res_dps``,
    ``max_abs_residual_dps``, ``manufacturer_scale_mV_per_dps``, ``manufacturer_rate_dps``,
    ``manufacturer_residuals_dps``, ``manufacturer_sigma_dps`` (std, ddof=1), ``manufacturer_rms_dps``,
    ``manufacturer_max_abs_dps``. :meth:`apply` adds the calibrated rates.
    """

    def __init__(self, rows=None):
        self.rows = rows

    def fit(self, rec: Recording) -> Self:
        """Fit the three gyros on the selected rows (class doc); returns self."""
        self._clear_fitted()
        rec.validate()
        rec.require({f"gyro_{g}": "V" for g in GYROS})
        idx = _row_index(rec.n, self.rows)
        ref_dps = measured_rate(rec)[idx] / DEG  # boundary: rad/s -> deg/s for reporting
        summary = {g: _gyro_summary(rec, g, idx, ref_dps) for g in GYROS}
        self.summary_ = summary
        self.results_ = {g: summary[g]["result"] for g in GYROS}
        self.coef_ = np.array([[summary[g]["beta0_dps"], summary[g]["beta1_dps_per_V"]] for g in GYROS])
        self.rows_ = idx
        return self

    def apply(self, rec: Recording) -> Recording:
        """A copy of ``rec`` with the calibrated rates ``gyro_cal_p``, ``gyro_cal_q``, ``gyro_cal_r`` (rad/s):
        omega = (beta0 + beta1 V) deg/s for every row."""
        self.check_fitted()
        rec.require({f"gyro_{g}": "V" for g in GYROS})
        channels, units = dict(rec.channels), dict(rec.units)
        for k, g in enumerate(GYROS):
            channels[f"gyro_cal_{g}"] = (self.coef_[k, 0] + self.coef_[k, 1] * rec.channels[f"gyro_{g}"]) * DEG
            units[f"gyro_cal_{g}"] = "rad/s"
        return rec.replace(channels=channels, units=units)
