"""The commands on recordings, yours or simulated: ``imurig calibrate``, ``apply``, ``diagnose``,
``convert`` and ``info``."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from imurig.cli.campaigns import print_summary
from imurig.kernel.errors import ImurigError, OutputExistsError
from imurig.kernel.csvstream import csv_to_h5
from imurig.kernel.filerecord import FileRecord, open_file_record
from imurig.kernel.files import load
from imurig.kernel.h5stream import h5_info, h5_to_csv
from imurig.kernel.infer import inference_report, warning_banner
from imurig.kernel.labcsv import write_csv
from imurig.kernel.outputs import OutputFolder
from imurig.kernel.recording import save_h5

H5_SUFFIXES = (".h5", ".hdf5")


def add_recording_parsers(sub) -> None:
    """The five commands on the ``imurig`` subparsers ``sub``."""
    cal = sub.add_parser("calibrate", help="calibrate a recording (yours or simulated)",
                         formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    cal.add_argument("recording", help=".csv (lab format, see README), .mat (MATLAB) or .h5")
    _lab_options(cal, rig=False)
    cal.add_argument("--rig", default=None,
                     choices=["tilt-table", "turn-table", "six-face", "thermal", "magnetometer"],
                     help="default: the recording's '# rig:' line, else inferred from its set-points "
                          "(none: six-face, a box on its six faces and rotated about each axis)")
    cal.add_argument("--model", default=None,
                     choices=["auto", "physical", "linear", "cross", "seed_final", "paper_eq2", "paper_eq3",
                              "stepwise", "backward"],
                     help="default: the rig's (tilt and turn table: physical; six-face: auto, the linear model "
                          "plus the terms the faces identify)")
    cal.add_argument("--statistic", default="huber", choices=["huber", "median", "mean"],
                     help="tilt table: per-position statistic (huber: robust M-estimate at 95 %% Gaussian "
                          "efficiency; median: the seed's)")
    cal.add_argument("--timer", default="auto", choices=["auto", "adc", "hp6700", "gps_mark"],
                     help="turn table: the timer of the once-per-round pulses (auto: the HP counter's events, "
                          "another timer's, else the ADC pulse channel)")
    cal.add_argument("--rotation-deg", type=float, default=360.0,
                     help="six-face: the known angle of each hand rotation")
    cal.add_argument("--out", default="imurig-out/calibration")
    cal.add_argument("--overwrite", action="store_true")
    cal.set_defaults(func=_run_calibrate)

    app = sub.add_parser("apply", help="apply a calibration.json to a recording (adds acc_cal_* or gyro_cal_*)")
    app.add_argument("calibration", help="calibration.json from a report folder")
    app.add_argument("recording", help=".csv or .h5")
    app.add_argument("--out", required=True, help="output recording, .h5 or .csv")
    app.add_argument("--overwrite", action="store_true")
    app.set_defaults(func=_run_apply)

    dg = sub.add_parser("diagnose", help="locate where a recording and its simulated twin differ, name the physics",
                        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    dg.add_argument("recording", help="a recording (.h5/.csv), a table in the appendix-B format, or 'simona' "
                                      "for the shipped appendix-B recording")
    dg.add_argument("--out", default="imurig-out/diagnosis")
    dg.add_argument("--overwrite", action="store_true")
    dg.add_argument("--seed", type=int, default=0, help="seed of the threshold simulations")
    dg.add_argument("--twin-model", default=None, choices=["physical", "own_axis", "linear", "nominal", "calibrated"],
                    help="the twin's model: tilt table physical (default) / own_axis / linear (terms it lacks, "
                         "misalignment or nonlinearity, join the candidate effects); magnetometer nominal (default: "
                         "per-axis gains) / calibrated (full linear calibration); a choice that does not fit the "
                         "recording's rig is refused. Default: the recording's meta['diagnose_twin'], else the rig's "
                         "default")
    dg.add_argument("--twin-without-earth-rate", action="store_true",
                    help="turn table: a twin whose reference leaves the Earth's rate out (as many labs do)")
    _lab_options(dg)
    dg.set_defaults(func=_run_diagnose)

    conv = sub.add_parser("convert", help="convert between HDF5 and the lab CSV format")
    conv.add_argument("input", help="a recording (.h5, .csv or .mat)")
    conv.add_argument("output", help="the converted file: .csv (lab format) or .h5")
    conv.add_argument("--overwrite", action="store_true")
    conv.set_defaults(func=_run_convert)

    info = sub.add_parser("info", help="summarise a recording")
    info.add_argument("recording", help="a recording (.h5, .csv or .mat)")
    _lab_options(info)
    info.set_defaults(func=_run_info)


def _lab_options(p, rig: bool = True) -> None:
    """What a lab file (.csv, .mat) may lack and the import cannot infer."""
    g = p.add_argument_group("lab files (.csv, .mat): what the file does not say")
    if rig:
        g.add_argument("--rig", default=None, help="tilt_table, turn_table ... (default: the file's '# rig:' line)")
    g.add_argument("--site", default=None, help="a named site (delft) when the file has no '# site:' line")
    g.add_argument("--pulse-channel", default=None, metavar="NAME",
                   help="the channel holding the index pulse (default: 'pulse', i.e. a column pulse_V)")


def _load(a):
    """The recording named on the command line, with the lab options."""
    rig = a.rig.replace("-", "_") if a.rig else None
    return load(a.recording, rig=rig, site=a.site, pulse_channel=a.pulse_channel)


def _run_calibrate(a):
    # heavy (matplotlib, the campaigns' MuJoCo rigs): loaded when the command runs, not for --help
    from imurig.reports import calibrate_rigs as cr

    rec = _load(a).validate()
    rec.meta.setdefault("source", Path(a.recording).name)
    rig = a.rig or cr.infer_rig(rec)
    model = cr.check_model(rig, a.model)
    try:
        _calibrate_rig(a, rec, rig, model, cr)
    except ImurigError as e:
        if a.recording not in str(e) and e.args:
            e.args = (f"{a.recording}: {e.args[0]}",) + e.args[1:]     # say which file, keep the error's kind
        raise
    except (ValueError, np.linalg.LinAlgError) as e:  # a fit the data cannot carry: a message, not a traceback
        raise ImurigError(f"{a.recording}: the {rig} calibration (model {model}) cannot be fitted to these data: "
                          f"{e}") from None


def _calibrate_rig(a, rec, rig: str, model: str, cr) -> None:
    if rig == "tilt-table":
        return _calibrate_tilt_table(a, rec, model)
    if not (a.rotation_deg > 0):
        raise ImurigError(f"--rotation-deg must be positive, got {a.rotation_deg}")
    with OutputFolder(a.out, overwrite=a.overwrite) as out:
        if rig == "turn-table":
            s = cr.calibrate_turn_table(rec, out, model, a.timer)
        elif rig == "six-face":
            s = cr.calibrate_six_face(rec, out, model, a.rotation_deg)
        elif rig == "thermal":
            s = cr.calibrate_thermal(rec, out)
        else:
            s = cr.calibrate_magnetometer(rec, out)
    _print_parameters(s, a.out)


def _print_parameters(s: dict, out) -> None:
    for n in s.get("notes", []):
        print(f"- {n}")
    print(f"{'parameter':28s} {'estimate':>14s} {'std.err':>10s} {'z':>6s}")
    for p in s["parameters"]:
        z = "–" if p.get("z") is None else f"{p['z']:+.2f}"
        est = "–" if p["estimate"] is None else f"{p['estimate']:+.6e}"
        se = "–" if p["std_error"] is None else f"{p['std_error']:.2e}"
        print(f"{p['name']:28s} {est:>14s} {se:>10s} {z:>6s}")
    print(f"report: {Path(out) / 'report.md'}")


def _calibrate_tilt_table(a, rec, model):
    from imurig.reports.tilt_table import _report_md, analyse, make_figures, summary_dict

    with OutputFolder(a.out, overwrite=a.overwrite) as out:
        res = analyse(rec, model, a.statistic)
        figs = make_figures(out, rec, res)
        files = {"report": "report.md", "summary": "summary.json", "calibration": "calibration.json",
                 **{f"figure_{k}": v for k, v in figs.items()}}
        out.write_json("calibration.json", res["main"].to_dict())
        s = summary_dict(None, rec, res, {}, files)
        imported, section = inference_report(rec.meta)
        s.update(imported)
        out.write_json("summary.json", s)
        md = _report_md(None, rec, res, figs, {})
        head, _, rest = md.partition("\n")
        banner = warning_banner(rec.meta)
        out.write_text("report.md", head + "\n" + (f"\n{banner}" if banner else "") + rest
                       + ("\n" + section if section else ""))
    print_summary(s, a.out)


def _run_apply(a):
    # scipy.signal (the calibration's preprocessing): loaded when the command runs, not for --help
    from imurig.calibration.accelerometer import AccelerometerCalibration
    from imurig.calibration.gyro import GyroCalibration
    from imurig.calibration.turned_axis import KIND as TURNED_KIND

    try:
        d = json.loads(Path(a.calibration).read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ImurigError(f"cannot read calibration {a.calibration}: {e}; give the calibration.json of a report "
                          "folder") from None
    kinds = {c.SPEC.json_kind: c for c in (AccelerometerCalibration, GyroCalibration)}
    kind = d.get("kind") if isinstance(d, dict) else None
    if kind == TURNED_KIND:
        raise ImurigError(f"{a.calibration}: a one-axis turn-table calibration (the gyro the table turned) is not "
                          "applied by `imurig apply` yet; use TurnedAxisCalibration.apply from Python")
    try:
        cal = kinds.get(kind, AccelerometerCalibration).from_dict(d)
    except (ValueError, KeyError) as e:
        raise ImurigError(f"{a.calibration}: {e}") from None
    rec = cal.apply(load(a.recording).validate())
    dst = Path(a.out)
    writer = write_csv if dst.suffix.lower() == ".csv" else save_h5
    writer(rec, dst, overwrite=a.overwrite)
    sp = cal.SPEC
    print(f"wrote {dst} with channels " + ", ".join(sp.cal_prefix + x for x in sp.axes) + f" ({sp.quantity_unit})")


def _run_diagnose(a):
    # heavy (the twins' MuJoCo rigs, matplotlib, rerun): loaded when the command runs, not for --help
    from imurig.calibration.simona import read_simona
    from imurig.reports.diagnosis import _findings_rows, run

    if a.recording == "simona":
        rec = read_simona()
    elif a.recording.lower().endswith(".csv") and _is_appendix_b(a.recording):
        rec = read_simona(a.recording)
    else:
        rec = _open_for_diagnosis(a)
    # the twin: the recording's own meta["diagnose_twin"] (if any), overridden by the flags given
    try:
        d = run(rec, a.out, overwrite=a.overwrite, seed=a.seed, twin_model=a.twin_model,
                earth_rate=False if a.twin_without_earth_rate else None)
    except ImurigError as e:
        if a.recording not in str(e) and e.args and not isinstance(e, OutputExistsError):
            e.args = (f"{a.recording}: {e.args[0]}",) + e.args[1:]     # say which file, keep the error's kind
        raise
    except (ValueError, np.linalg.LinAlgError) as e:  # a comparison the data cannot carry: a message, not a traceback
        raise ImurigError(f"{a.recording}: the diagnosis cannot compare these data with a twin: {e}") from None
    finally:
        if isinstance(rec, FileRecord):
            rec.close()
    for r in _findings_rows(d):
        print(f"- {r[1]} ({r[0]}): {r[2]}\n    {r[3]}")
    print(f"report: {Path(a.out) / 'report.md'}; machine-readable: {Path(a.out) / 'diagnosis.json'}")
    print(f"verdict: {d['verdict']}")


def _open_for_diagnosis(a):
    """The recording to diagnose: a tilt- or turn-table .h5 (or a lab .csv that declares its structure) read in
    row ranges (:class:`imurig.kernel.filerecord.FileRecord`: memory of the 100 Hz working record, not
    of the file; a CSV's temporary HDF5 file beside the report folder, not in a temporary folder that
    may be held in memory); any other recording loaded whole, after an estimate of the memory it needs."""
    from imurig.diagnose.dispatch import STREAMED, record_kind

    if not (a.rig or a.site or a.pulse_channel):
        parent = Path(a.out).resolve().parent
        f = open_file_record(a.recording, tmp_dir=parent if parent.is_dir() else None)
        if f is not None:
            if record_kind(f) in STREAMED:
                return f
            try:
                return f.load().validate()
            finally:
                f.close()
    return _load(a).validate()


def _is_appendix_b(path) -> bool:
    if not Path(path).is_file():          # missing or a folder: the loader below says so
        return False
    with open(path, encoding="utf-8", errors="replace") as fh:
        for line in fh:
            if not line.startswith("#"):
                return line.strip().startswith("rate_dial_dps,") and "measured_round_s" in line
    return False


def _run_convert(a):
    dst = Path(a.output)
    if dst.suffix.lower() == ".csv" and Path(a.input).suffix.lower() in H5_SUFFIXES:
        h5_to_csv(a.input, dst, overwrite=a.overwrite)        # row chunks: memory bounded, not the file's
        print(f"wrote {dst}")
        return
    if dst.suffix.lower() in H5_SUFFIXES and Path(a.input).suffix.lower() == ".csv" \
            and csv_to_h5(a.input, dst, overwrite=a.overwrite) is not None:   # row blocks (else None: whole file)
        print(f"wrote {dst}")
        return
    rec = load(a.input)
    if dst.suffix.lower() == ".csv":
        write_csv(rec, dst, overwrite=a.overwrite)
    elif dst.suffix.lower() in (".h5", ".hdf5"):
        save_h5(rec, dst, overwrite=a.overwrite)
    else:
        raise ImurigError(f"output must end in .csv or .h5, got {dst.name}")
    print(f"wrote {dst}")


def _run_info(a):
    if Path(a.recording).suffix.lower() in H5_SUFFIXES:   # metadata, shapes and chunked passes: bounded memory
        print(json.dumps(h5_info(a.recording), indent=2, default=float))
        return
    rec = _load(a)
    info = {"samples": rec.n, "duration_s": float(rec.time_s[-1] - rec.time_s[0]),
            "sample_rate_hz": rec.sample_rate_hz, "blocks": len(rec.blocks()),
            "channels": {k: rec.units[k] for k in rec.channels}, "segments": rec.n_segments,
            "segment_columns": sorted(rec.segments), "meta_keys": sorted(rec.meta),
            "has_truth": rec.truth is not None, "inferred": rec.meta.get("inferred", {}),
            "import_warnings": rec.meta.get("import_warnings", [])}
    print(json.dumps(info, indent=2, default=float))
