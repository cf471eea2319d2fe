"""The commands on recordings, yours or simulated: ``imurig calibrate``, ``apply``, ``diagnose``,
``convert`` and ``info``."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from imurig.cli.campaigns import print_summary
from imurig.kernel.errors import ImurigError
from imurig.kernel.files import load
from imurig.kernel.labcsv import write_csv
from imurig.kernel.outputs import OutputFolder
from imurig.kernel.recording import save_h5


def add_recording_parsers(sub) -> None:
    """The five commands on the ``imurig`` subparsers ``sub``."""
    cal = sub.add_parser("calibrate", help="calibrate a recording (yours or simulated)",
                         formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    cal.add_argument("recording", help=".csv (lab format, see README) or .h5")
    cal.add_argument("--rig", default="tilt-table")
    cal.add_argument("--model", default="physical",
                     choices=["physical", "linear", "cross", "seed_final", "stepwise", "backward"])
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
    dg.set_defaults(func=_run_diagnose)

    conv = sub.add_parser("convert", help="convert between HDF5 and the lab CSV format")
    conv.add_argument("input")
    conv.add_argument("output")
    conv.add_argument("--overwrite", action="store_true")
    conv.set_defaults(func=_run_convert)

    info = sub.add_parser("info", help="summarise a recording")
    info.add_argument("recording")
    info.set_defaults(func=_run_info)


def _run_calibrate(a):
    # heavy (matplotlib, the campaigns' MuJoCo rigs): loaded when the command runs, not for --help
    from imurig.reports.tilt_table import _report_md, analyse, make_figures, summary_dict

    rec = load(a.recording).validate()
    if a.rig != "tilt-table":
        raise ImurigError(f"rig {a.rig!r} is not supported yet; use --rig tilt-table")
    with OutputFolder(a.out, overwrite=a.overwrite) as out:
        res = analyse(rec, a.model)
        figs = make_figures(out, rec, res)
        files = {"report": "report.md", "summary": "summary.json", "calibration": "calibration.json",
                 **{f"figure_{k}": v for k, v in figs.items()}}
        out.write_json("calibration.json", res["main"].to_dict())
        s = summary_dict(None, rec, res, {}, files)
        out.write_json("summary.json", s)
        out.write_text("report.md", _report_md(None, rec, res, figs, {}))
    print_summary(s, a.out)


def _run_apply(a):
    # scipy.signal (the calibration's preprocessing): loaded when the command runs, not for --help
    from imurig.calibration.accelerometer import AccelerometerCalibration
    from imurig.calibration.gyro import GyroCalibration

    try:
        d = json.loads(Path(a.calibration).read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise ImurigError(f"cannot read calibration {a.calibration}: {e}") from None
    kinds = {c.SPEC.json_kind: c for c in (AccelerometerCalibration, GyroCalibration)}
    try:
        cal = kinds.get(d.get("kind"), AccelerometerCalibration).from_dict(d)
    except (ValueError, KeyError) as e:
        raise ImurigError(str(e)) from None
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
        rec = load(a.recording).validate()
    # the twin: the recording's own meta["diagnose_twin"] (if any), overridden by the flags given
    d = run(rec, a.out, overwrite=a.overwrite, seed=a.seed, twin_model=a.twin_model,
            earth_rate=False if a.twin_without_earth_rate else None)
    for r in _findings_rows(d):
        print(f"- {r[1]} ({r[0]}): {r[2]}\n    {r[3]}")
    print(f"report: {Path(a.out) / 'report.md'}; machine-readable: {Path(a.out) / 'diagnosis.json'}")
    print(f"verdict: {d['verdict']}")


def _is_appendix_b(path) -> bool:
    with open(path, encoding="utf-8") as fh:
        for line in fh:
            if not line.startswith("#"):
                return line.strip().startswith("rate_dial_dps,") and "measured_round_s" in line
    return False


def _run_convert(a):
    rec = load(a.input)
    dst = Path(a.output)
    if dst.suffix.lower() == ".csv":
        write_csv(rec, dst, overwrite=a.overwrite)
    elif dst.suffix.lower() in (".h5", ".hdf5"):
        save_h5(rec, dst, overwrite=a.overwrite)
    else:
        raise ImurigError(f"output must end in .csv or .h5, got {dst.name}")
    print(f"wrote {dst}")


def _run_info(a):
    rec = load(a.recording)
    info = {"samples": rec.n, "duration_s": float(rec.time_s[-1] - rec.time_s[0]),
            "sample_rate_hz": rec.sample_rate_hz, "blocks": len(rec.blocks()),
            "channels": {k: rec.units[k] for k in rec.channels}, "segments": rec.n_segments,
            "segment_columns": sorted(rec.segments), "meta_keys": sorted(rec.meta),
            "has_truth": rec.truth is not None}
    print(json.dumps(info, indent=2))
