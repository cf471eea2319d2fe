"""Which diagnosis a recording gets, and with which twin.

:func:`record_kind` names the kind of recording from its metadata and segments (a key of
:data:`TWIN_OPTIONS`); :func:`twin_options` gathers the twin's options (the recording's own
``meta["diagnose_twin"]``, overridden by those given) and refuses those the kind does not take;
:func:`diagnose` runs the kind's diagnosis with them.
"""
from __future__ import annotations

import numpy as np

from imurig.diagnose.magnetometer import TWIN_MODELS as MAGNETOMETER_TWIN_MODELS
from imurig.diagnose.magnetometer import diagnose_magnetometer
from imurig.diagnose.rate_table import diagnose_rate_rows
from imurig.diagnose.thermal import diagnose_thermal
from imurig.diagnose.tilt_table import TWIN_MODELS as TILT_TWIN_MODELS
from imurig.diagnose.tilt_table import diagnose_tilt_table
from imurig.diagnose.turn_table import diagnose_turn_table
from imurig.kernel.errors import ConfigError, RecordingError
from imurig.kernel.filerecord import FileRecord
from imurig.kernel.recording import Recording

#: the twin options each kind of recording understands (``meta["diagnose_twin"]``, ``--twin-model``...)
TWIN_OPTIONS = {"tilt_table": {"twin_model", "dynamics", "skew_in_twin"}, "turn_table": {"earth_rate"},
                "thermal": set(), "rate_table_rows": set(), "magnetometer": {"twin_model"}}

#: the kinds whose diagnosis reads a FileRecord in row ranges (the others load it whole)
STREAMED = ("tilt_table", "turn_table", "thermal")


def record_kind(rec: Recording) -> str:
    """The kind of recording the diagnosis dispatches on (a key of :data:`TWIN_OPTIONS`)."""
    if rec.meta.get("rig") == "mag_rig":
        return "magnetometer"
    if rec.meta.get("rig") == "turn_table" and rec.meta.get("row_recording"):
        return "rate_table_rows"
    if {"attitude", "step", "branch"} <= set(rec.segments):
        return "thermal"
    if rec.meta.get("rig") == "turn_table" or "rate_dial" in rec.segments:
        return "turn_table"
    if rec.meta.get("rig") == "tilt_table" or {"theta", "phi"} <= set(rec.segments):
        return "tilt_table"
    raise RecordingError(f"diagnosis of '{rec.meta.get('rig', 'unknown')}' recordings is not implemented yet; "
                         "this version diagnoses tilt-table, turn-table, thermal-chamber and magnetometer "
                         "recordings and turn-table row recordings in the appendix-B format "
                         "(imurig.calibration.simona.read_simona)")


def twin_options(rec: Recording, twin: dict | None = None, **given) -> dict:
    """The twin options for ``rec``: ``twin`` (default: the recording's own ``meta["diagnose_twin"]``,
    written by ``imurig concealed write``), overridden by the ``given`` ones that are not None.
    Refuses an option or a twin model that does not fit the recording's kind (ConfigError)."""
    kind = record_kind(rec)
    opts = dict(rec.meta.get("diagnose_twin") or {}) if twin is None else dict(twin)
    opts.update({k: v for k, v in given.items() if v is not None})
    unknown = set(opts) - TWIN_OPTIONS[kind]
    if unknown:
        flags = {"twin_model": "--twin-model", "earth_rate": "--twin-without-earth-rate"}
        raise ConfigError(f"twin option(s) {', '.join(flags.get(k, k) for k in sorted(unknown))} do not apply to a "
                          f"{kind.replace('_', '-')} recording; it takes "
                          + (", ".join(sorted(flags.get(k, k) for k in TWIN_OPTIONS[kind])) or "no twin options"))
    if "twin_model" in opts:
        models = MAGNETOMETER_TWIN_MODELS if kind == "magnetometer" else TILT_TWIN_MODELS
        if opts["twin_model"] not in models:
            raise ConfigError(f"twin model '{opts['twin_model']}' does not fit a {kind.replace('_', '-')} recording; "
                              f"choose one of {', '.join(models)}")
    return opts


def diagnose(rec: Recording, seed: int = 0, twin_model: str | None = None, earth_rate: bool | None = None,
             twin: dict | None = None) -> dict:
    """Dispatch on the recording's kind (:func:`record_kind`): tilt-table recordings (twin model
    ``twin_model``, default 'physical'; the slews too), turn-table recordings (twin with or without
    the Earth's rate), thermal-chamber recordings, turn-table row recordings (appendix B) and
    magnetometer recordings (twin 'nominal' or 'calibrated'). Options: :func:`twin_options`.
    A tilt-table, turn-table or thermal ``rec`` may be a :class:`imurig.kernel.filerecord.FileRecord`
    (read in row ranges, :mod:`imurig.diagnose.raw_record`, :mod:`imurig.diagnose.turn_record`; a
    thermal one a segment window at a time, :func:`imurig.calibration.preprocess.segment_statistic`);
    the other kinds are loaded whole after a memory check."""
    kind = record_kind(rec)
    o = twin_options(rec, twin, twin_model=twin_model, earth_rate=earth_rate)
    if isinstance(rec, FileRecord) and kind not in STREAMED:
        rec = rec.load().validate()             # whole, after an estimate of the memory it needs
    rng = np.random.default_rng(seed)
    if kind == "rate_table_rows":
        return {"kind": kind, **diagnose_rate_rows(rec, rng)}
    if kind == "thermal":
        return {"kind": kind, **diagnose_thermal(rec, rng)}
    if kind == "turn_table":
        return {"kind": kind, **diagnose_turn_table(rec, rng, earth_rate=o.get("earth_rate", True),
                                                               timer=str(rec.meta.get("timer", "hp6700")))}
    if kind == "magnetometer":
        return {"kind": kind, **diagnose_magnetometer(rec, rng, twin_model=o.get("twin_model", "nominal"))}
    return {"kind": kind, **diagnose_tilt_table(rec, rng, twin_model=o.get("twin_model", "physical"),
                                                dynamics=o.get("dynamics", True),
                                                skew_in_twin=o.get("skew_in_twin", True))}
