"""imurig: a virtual calibration rig for inertial measurement units.

    imurig campaign tilt-table            simulate, calibrate and report the seed's protocol
    imurig campaign turn-table            gyro calibration, timers, arm beyond 1 g, SIMONA
    imurig campaign thermal               thermal chamber: bias/scale vs temperature, hysteresis
    imurig campaign magnetometer          IGRF field, two-step ellipse/ellipsoid, compass swing, heading
    imurig simona                         the SIMONA table (appendix B) beside its virtual twin
    imurig calibrate REC --rig tilt-table calibrate your own recording (CSV or HDF5)
    imurig apply CAL.json REC --out OUT   apply a calibration to a new recording
    imurig diagnose REC                   where recording and twin differ; names the physics left out
    imurig concealed list|write|all       the concealed-effect suite as recordings, to diagnose
    imurig convert IN OUT                 HDF5 <-> lab CSV
    imurig info REC                       what a recording holds
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from imurig.kernel.errors import ImurigError


def _floats(text: str) -> tuple[float, ...]:
    try:
        return tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None


def _words(text: str) -> tuple[str, ...]:
    return tuple(v.strip() for v in text.split(",") if v.strip())


def _add_tilt_table(sub):
    from imurig.rigs.tilt_table import TiltTableProtocol

    d = TiltTableProtocol()
    p = sub.add_parser("tilt-table", help="accelerometer calibration on the two-axis tilt table (seed 4.3)",
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter,
                       description="Simulate the tilt-table campaign, calibrate the accelerometers and write a "
                                   "report folder (report.md, summary.json, recording.h5, campaign.rrd).")
    p.add_argument("--out", default="imurig-out/tilt-table", help="report folder")
    p.add_argument("--overwrite", action="store_true", help="replace an existing report folder")
    p.add_argument("--seed", type=int, default=2005, help="master random seed (same seed, same data)")
    p.add_argument("--theta", type=_floats, default=d.theta_deg, metavar="DEG,...", help="tilt angles")
    p.add_argument("--phi", type=_floats, default=d.phi_deg, metavar="DEG,...", help="rotation angles")
    p.add_argument("--runs", type=_words, default=d.runs, metavar="MOUNT,...", help="mountings: z_down, z_up")
    p.add_argument("--dwell", type=float, default=d.dwell_s, help="seconds acquired per position")
    p.add_argument("--rate", type=float, default=d.sample_rate_hz, help="ADC sample rate, Hz")
    p.add_argument("--start-time", default="2005-06-14T18:00:00+02:00",
                   help="local start time (ISO 8601); the pump runs in working hours 07:30-17:30")
    p.add_argument("--model", default="physical", choices=["physical", "linear", "cross", "seed_final", "stepwise", "backward"],
                   help="main calibration model")
    p.add_argument("--mux-khz", type=float, default=20.0, help="ADC multiplexing frequency, kHz")
    p.add_argument("--grounding", default="NRSE", choices=["GRSE", "NRSE", "DIFF"], help="ADC wiring")
    p.add_argument("--no-pump", action="store_true", help="switch the basement pump off entirely")
    p.add_argument("--no-people", action="store_true", help="no door/chair transients")
    p.add_argument("--loose-cable", action="store_true", help="the faulty y-channel connector of seed 4.3.3")
    p.add_argument("--no-crosstalk", action="store_true", help="ideal multiplexer settling")
    p.add_argument("--ideal-sensors", action="store_true", help="no drawn sensor errors (datasheet nominal)")
    p.add_argument("--no-rrd", action="store_true", help="skip the rerun file")
    p.add_argument("--no-recording", action="store_true", help="skip saving recording.h5")
    p.set_defaults(func=_run_tilt_table)


def _add_turn_table(sub):
    from imurig.rigs.turn_table import TurnTableProtocol

    d = TurnTableProtocol()
    p = sub.add_parser("turn-table", help="gyro calibration on the Genisco C181 turn table (seed 4.4)",
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter,
                       description="Simulate the final gyro calibration (and, unless --no-studies, the timer "
                                   "study of Fig. 4.20, accelerometers beyond 1 g on the arm, and the SIMONA "
                                   "comparison of Fig. 4.19) and write a report folder.")
    p.add_argument("--out", default="imurig-out/turn-table", help="report folder")
    p.add_argument("--overwrite", action="store_true", help="replace an existing report folder")
    p.add_argument("--seed", type=int, default=2005, help="master random seed")
    p.add_argument("--rates", type=_floats, default=d.dial_rates_dps, metavar="DPS,...",
                   help="dial rates (the table turns at 5/6 of them on 50 Hz mains)")
    p.add_argument("--directions", type=_floats, default=d.directions, metavar="1,-1")
    p.add_argument("--mounts", type=_words, default=d.mounts, metavar="AXIS_up,...",
                   help="which IMU axis points up the table axis: p_up, q_up, r_up, p_down, ...")
    p.add_argument("--min-window", type=float, default=d.min_window_s, help="least seconds of whole rounds per step")
    p.add_argument("--timer", default="hp6700", choices=["hp6700", "gps_mark", "adc"])
    p.add_argument("--model", default="physical", choices=["physical", "linear", "seed_final", "stepwise", "backward"])
    p.add_argument("--mains-hz", type=float, default=50.0, help="mains frequency of the synchronous motor")
    p.add_argument("--no-slip-rings", action="store_true", help="no slip-ring noise")
    p.add_argument("--no-studies", action="store_true", help="skip the timer, arm and SIMONA studies")
    p.add_argument("--no-rrd", action="store_true")
    p.add_argument("--no-recording", action="store_true")
    p.set_defaults(func=_run_turn_table)


def _run_turn_table(a):
    from imurig.campaigns.turn_table import TurnTableCampaign
    from imurig.reports.turn_table import run
    from imurig.rigs.turn_table import TurnTableProtocol

    proto = TurnTableProtocol(dial_rates_dps=a.rates, directions=tuple(int(d) for d in a.directions),
                              mounts=a.mounts, min_window_s=a.min_window)
    camp = TurnTableCampaign(protocol=proto, seed=a.seed, timer=a.timer, model=a.model, mains_hz=a.mains_hz,
                             slip_rings=not a.no_slip_rings)
    print(f"imurig: turn-table campaign, {len(proto.steps())} steps, seed {a.seed} -> {a.out}", file=sys.stderr)
    s = run(camp, a.out, overwrite=a.overwrite, rrd=not a.no_rrd, save_recording=not a.no_recording,
            studies=not a.no_studies)
    _print_summary(s, a.out)
    if s.get("timer_study"):
        print("timer residual envelopes (deg/s): " + ", ".join(
            f"{k}={v['envelope_dps']:.4f}" for k, v in s["timer_study"]["timers"].items()))
    if s.get("simona"):
        print("SIMONA own scale factor (mV/(deg/s)) real/virtual: " + ", ".join(
            f"{g}={s['simona']['real'][g]['scale_mV_per_dps']:.3f}/{s['simona']['virtual'][g]['scale_mV_per_dps']:.3f}"
            for g in "pqr"))


def _run_simona(a):
    from imurig.calibration.simona import SimonaCalibration, read_simona
    from imurig.calibration.simona_report import plot_fig_4_19, simona_markdown
    from imurig.campaigns.turn_table import simona_virtual
    from imurig.reports.common import OutputFolder

    real = read_simona(a.csv)
    virt = simona_virtual(a.seed)
    with OutputFolder(a.out, overwrite=a.overwrite) as out:
        plot_fig_4_19(out.file("fig_4_19_simona.png"), real, virt, gyro=a.gyro)
        md = "# SIMONA gyro calibration: real (appendix B) and virtual\n\n" + simona_markdown(
            SimonaCalibration().fit(real).summary_, SimonaCalibration().fit(virt).summary_) + "\n![fig](fig_4_19_simona.png)\n"
        out.write_text("report.md", md)
    print(md)


def _add_thermal(sub):
    from imurig.rigs.thermal_chamber import ThermalProfile

    d = ThermalProfile()
    p = sub.add_parser("thermal", help="thermal-chamber calibration, two cycles, six attitudes (seed 4.5)",
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--out", default="imurig-out/thermal")
    p.add_argument("--overwrite", action="store_true")
    p.add_argument("--seed", type=int, default=2005)
    p.add_argument("--low", type=float, default=d.low_C, help="lowest set-point, C")
    p.add_argument("--high", type=float, default=d.high_C, help="highest set-point, C")
    p.add_argument("--step", type=float, default=d.step_C, help="set-point step, C")
    p.add_argument("--cycles", type=int, default=d.cycles)
    p.add_argument("--soak", type=float, default=d.soak_s, help="soak time per set-point, s")
    p.add_argument("--no-rrd", action="store_true")
    p.add_argument("--no-recording", action="store_true")
    p.set_defaults(func=_run_thermal)


def _run_thermal(a):
    from imurig.campaigns.thermal import ThermalCampaign
    from imurig.reports.thermal import run
    from imurig.rigs.thermal_chamber import ThermalProfile

    prof = ThermalProfile(low_C=a.low, high_C=a.high, step_C=a.step, cycles=a.cycles, soak_s=a.soak)
    prof.validate()
    print(f"imurig: thermal campaign, {len(prof.setpoints())} set-points, seed {a.seed} -> {a.out}", file=sys.stderr)
    s = run(ThermalCampaign(profile=prof, seed=a.seed), a.out, overwrite=a.overwrite, rrd=not a.no_rrd,
            save_recording=not a.no_recording)
    _print_params(s["parameters"])
    for k, v in s["hysteresis"].items():
        print(f"hysteresis {k}: measured gap {v['measured_gap_m_s2']:.3e}, injected {v['injected_hysteresis_m_s2']:.3e} m/s^2")
    print(f"report: {Path(a.out) / 'report.md'}")


def _print_params(params):
    print(f"{'parameter':30s} {'injected':>13s} {'estimate':>13s} {'std.err':>9s} {'z':>6s}")
    for p in params:
        inj = "–" if p.get("injected") is None else f"{p['injected']:+.5e}"
        z = "–" if p.get("z") is None else f"{p['z']:+.2f}"
        print(f"{p['name']:30s} {inj:>13s} {p['estimate']:+.5e} {p['std_error']:.2e} {z:>6s}")


def _add_magnetometer(sub):
    p = sub.add_parser("magnetometer", help="IGRF field, two-step ellipse/ellipsoid, compass swing, heading (seed 4.6-4.7)",
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--out", default="imurig-out/magnetometer")
    p.add_argument("--overwrite", action="store_true")
    p.add_argument("--seed", type=int, default=2005)
    p.add_argument("--start-time", default="2005-06-21T10:00:00+02:00", help="date and time (for IGRF)")
    p.add_argument("--hard-iron-nT", type=float, default=6000.0, help="largest hard-iron bias per axis")
    p.add_argument("--noise-nT", type=float, default=5.0)
    p.add_argument("--no-rrd", action="store_true")
    p.add_argument("--no-recording", action="store_true")
    p.set_defaults(func=_run_magnetometer)


def _run_magnetometer(a):
    from imurig.campaigns.magnetometer import MagnetometerCampaign
    from imurig.reports.magnetometer import run

    camp = MagnetometerCampaign(seed=a.seed, start_time=a.start_time, hard_iron_max_nT=a.hard_iron_nT,
                                noise_nT=a.noise_nT)
    print(f"imurig: magnetometer campaign, seed {a.seed} -> {a.out}", file=sys.stderr)
    s = run(camp, a.out, overwrite=a.overwrite, rrd=not a.no_rrd, save_recording=not a.no_recording)
    ig = s["igrf"]
    print(f"IGRF: H = {ig['horizontal_nT']:.1f} nT (paper {ig['published_horizontal_nT']:.0f}), "
          f"F = {ig['total_nT']:.1f} nT (paper {ig['published_total_nT']:.0f})")
    _print_params(s["parameters"])
    for k, v in s["heading_error_deg"].items():
        print(f"heading error {k:36s} RMS {v['rms']:.3f} deg, max {v['max_abs']:.3f} deg")
    print(f"report: {Path(a.out) / 'report.md'}")


def _run_tilt_table(a):
    from imurig.campaigns.tilt_table import TiltTableCampaign
    from imurig.reports.tilt_table import run
    from imurig.rigs.tilt_table import TiltTableProtocol

    proto = TiltTableProtocol(theta_deg=a.theta, phi_deg=a.phi, runs=a.runs, dwell_s=a.dwell,
                              sample_rate_hz=a.rate)
    camp = TiltTableCampaign(protocol=proto, seed=a.seed, start_time=a.start_time, model=a.model,
                             mux_frequency_hz=a.mux_khz * 1e3, grounding=a.grounding, pump=not a.no_pump,
                             people=not a.no_people, loose_cable=a.loose_cable, crosstalk=not a.no_crosstalk,
                             draw_sensor_errors=not a.ideal_sensors)
    print(f"imurig: tilt-table campaign, {proto.n_positions} positions, seed {a.seed} -> {a.out}", file=sys.stderr)
    s = run(camp, a.out, overwrite=a.overwrite, rrd=not a.no_rrd, save_recording=not a.no_recording)
    _print_summary(s, a.out)


def _print_summary(s: dict, out):
    print(f"{'parameter':22s} {'injected':>14s} {'estimate':>14s} {'std.err':>10s} {'z':>6s}")
    main = s["models"].get("main", {}).get("axes") if "main" in s["models"] else None
    for p in s["parameters"]:
        inj = "–" if p["injected"] is None else f"{p['injected']:+.6e}"
        z = "–" if p["z"] is None else f"{p['z']:+.2f}"
        print(f"{p['name']:22s} {inj:>14s} {p['estimate']:+.6e} {p['std_error']:.2e} {z:>6s}")
    if main:
        print("sigma_res (m/s^2): " + ", ".join(f"{a}={main[a]['sigma_res']:.3e}" for a in "xyz"))
    else:
        print("sigma_res (deg/s): " + ", ".join(f"{a}={57.29578 * m['sigma_res_rad_s']:.3e}"
                                                for a, m in s["models"].items()))
    if s.get("timing"):
        print("timing: " + ", ".join(f"{k}={v}" for k, v in s["timing"].items()))
    print(f"report: {Path(out) / 'report.md'}")


def _run_calibrate(a):
    from imurig.reports.tilt_table import analyse, make_figures, summary_dict, _report_md
    from imurig.kernel.recording import load
    from imurig.reports.common import OutputFolder

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
    _print_summary(s, a.out)


def _run_apply(a):
    from imurig.calibration.accelerometer import AccelerometerCalibration
    from imurig.calibration.gyro import GyroCalibration
    from imurig.kernel.labcsv import write_csv
    from imurig.kernel.recording import load, save_h5

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
    from imurig.reports.diagnosis import run

    if a.recording == "simona":
        from imurig.calibration.simona import read_simona

        rec = read_simona()
    elif a.recording.lower().endswith(".csv") and _is_appendix_b(a.recording):
        from imurig.calibration.simona import read_simona

        rec = read_simona(a.recording)
    else:
        from imurig.kernel.recording import load

        rec = load(a.recording).validate()
    # the twin: the recording's own meta["diagnose_twin"] (if any), overridden by the flags given
    d = run(rec, a.out, overwrite=a.overwrite, seed=a.seed, twin_model=a.twin_model,
            earth_rate=False if a.twin_without_earth_rate else None)
    from imurig.reports.diagnosis import _findings_rows

    for r in _findings_rows(d):
        print(f"- {r[1]} ({r[0]}): {r[2]}\n    {r[3]}")
    print(f"report: {Path(a.out) / 'report.md'}")


def _is_appendix_b(path) -> bool:
    with open(path, encoding="utf-8") as fh:
        for line in fh:
            if not line.startswith("#"):
                return line.strip().startswith("rate_dial_dps,") and "measured_round_s" in line
    return False


def _run_convert(a):
    from imurig.kernel.labcsv import write_csv
    from imurig.kernel.recording import load, save_h5

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
    from imurig.kernel.recording import load

    rec = load(a.recording)
    info = {"samples": rec.n, "duration_s": float(rec.time_s[-1] - rec.time_s[0]),
            "sample_rate_hz": rec.sample_rate_hz, "blocks": len(rec.blocks()),
            "channels": {k: rec.units[k] for k in rec.channels}, "segments": rec.n_segments,
            "segment_columns": sorted(rec.segments), "meta_keys": sorted(rec.meta),
            "has_truth": rec.truth is not None}
    print(json.dumps(info, indent=2))


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="imurig", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="command", required=True)
    camp = sub.add_parser("campaign", help="simulate a calibration campaign and report it")
    csub = camp.add_subparsers(dest="campaign", required=True)
    _add_tilt_table(csub)
    _add_turn_table(csub)
    _add_thermal(csub)
    _add_magnetometer(csub)

    sim = sub.add_parser("simona", help="the SIMONA gyro table (appendix B): real data beside the virtual twin",
                         formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    sim.add_argument("--csv", default=None, help="a table in the appendix-B format (default: the shipped one)")
    sim.add_argument("--gyro", default="p", choices=["p", "q", "r"])
    sim.add_argument("--seed", type=int, default=2005)
    sim.add_argument("--out", default="imurig-out/simona")
    sim.add_argument("--overwrite", action="store_true")
    sim.set_defaults(func=_run_simona)

    from imurig.cli.montecarlo import add_montecarlo_parser
    add_montecarlo_parser(sub)

    from imurig.cli.flight import add_flight_parser
    add_flight_parser(sub)

    from imurig.concealed.cases import add_concealed_parser
    add_concealed_parser(sub)

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

    from imurig.cli.scoring import add_scoring_parsers
    add_scoring_parsers(sub)
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        args.func(args)
    except ImurigError as e:
        print(f"imurig: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
