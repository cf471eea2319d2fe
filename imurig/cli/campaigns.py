"""``imurig campaign NAME`` (tilt-table, turn-table, thermal, magnetometer) and ``imurig simona``:
simulate a calibration campaign, calibrate it and write its report folder."""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from imurig.kernel.errors import ConfigError
from imurig.kernel.outputs import OutputFolder
from imurig.kernel.site import parse_time


def _floats(text: str) -> tuple[float, ...]:
    try:
        out = tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None
    if not out or not all(math.isfinite(v) for v in out):
        raise argparse.ArgumentTypeError(f"expected comma-separated finite numbers, got {text!r}")
    return out


def _iso_time(text: str) -> str:
    try:
        parse_time(text)
    except ConfigError as e:
        raise argparse.ArgumentTypeError(str(e)) from None
    return text


def _words(text: str) -> tuple[str, ...]:
    return tuple(v.strip() for v in text.split(",") if v.strip())


def add_campaign_parsers(sub, argv: list[str]) -> None:
    """``imurig campaign NAME`` and ``imurig simona`` on the ``imurig`` subparsers ``sub``.

    Every campaign is listed with its help; the arguments (whose defaults come from the rig
    protocols, whose modules load MuJoCo) are added only to the campaign ``argv`` asks for,
    so ``imurig --help`` and the other commands start without the rigs.
    """
    camp = sub.add_parser("campaign", help="simulate a calibration campaign and report it")
    csub = camp.add_subparsers(dest="campaign", required=True)
    chosen = argv[1] if len(argv) > 1 and argv[0] == "campaign" else None
    for name, (help_, description, add_arguments) in CAMPAIGNS.items():
        p = csub.add_parser(name, help=help_, description=description,
                            formatter_class=argparse.ArgumentDefaultsHelpFormatter)
        if name == chosen:
            add_arguments(p)
    _add_simona(sub)


def _add_simona(sub):
    sim = sub.add_parser("simona", help="the SIMONA gyro table (appendix B): real data beside the virtual twin",
                         formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    sim.add_argument("--csv", default=None, help="a table in the appendix-B format (default: the shipped one)")
    sim.add_argument("--gyro", default="p", choices=["p", "q", "r"], help="the SIMONA gyro to show")
    sim.add_argument("--seed", type=int, default=2005)
    sim.add_argument("--out", default="imurig-out/simona")
    sim.add_argument("--overwrite", action="store_true")
    sim.set_defaults(func=_run_simona)


def _tilt_table_args(p):
    # the rig's defaults: its module loads MuJoCo, so only for the campaign asked for
    from imurig.rigs.tilt_table import TiltTableProtocol

    d = TiltTableProtocol()
    p.add_argument("--out", default="imurig-out/tilt-table", help="report folder")
    p.add_argument("--overwrite", action="store_true", help="replace an existing report folder")
    p.add_argument("--seed", type=int, default=2005, help="master random seed (same seed, same data)")
    p.add_argument("--theta", type=_floats, default=d.theta_deg, metavar="DEG,...", help="tilt angles")
    p.add_argument("--phi", type=_floats, default=d.phi_deg, metavar="DEG,...", help="rotation angles")
    p.add_argument("--mounts", "--runs", dest="runs", type=_words, default=d.runs, metavar="MOUNT,...",
                   help="mountings of the IMU on the table: z_down, z_up (--runs: the older name)")
    p.add_argument("--dwell", type=float, default=d.dwell_s, help="seconds acquired per position")
    p.add_argument("--rate", type=float, default=d.sample_rate_hz, help="ADC sample rate, Hz")
    p.add_argument("--start-time", default="2005-06-14T18:00:00+02:00", type=_iso_time,
                   help="local start time (ISO 8601); the pump runs in working hours 07:30-17:30")
    p.add_argument("--model", default="physical", choices=["physical", "linear", "cross", "seed_final", "paper_eq2", "stepwise",
                                                               "backward"],
                   help="main calibration model (paper_eq2: the EUCASS paper's eq. 2, own axis to a^4)")
    p.add_argument("--statistic", default="huber", choices=["huber", "median", "mean"],
                   help="per-position statistic: huber (robust M-estimate, 95 %% Gaussian efficiency), median "
                        "(the seed's, for its tables) or mean")
    p.add_argument("--mux-khz", type=float, default=20.0, help="ADC multiplexing frequency, kHz")
    p.add_argument("--grounding", default="NRSE", choices=["GRSE", "NRSE", "DIFF"], help="ADC wiring")
    p.add_argument("--no-pump", action="store_true", help="switch the basement pump off entirely")
    p.add_argument("--no-people", action="store_true", help="no door/chair transients")
    p.add_argument("--loose-cable", action="store_true", help="the faulty y-channel connector of seed 4.3.3")
    p.add_argument("--no-crosstalk", action="store_true", help="ideal multiplexer settling")
    p.add_argument("--lab", default="quiet", choices=["quiet", "delft-2005"],
                   help="the virtual lab: quiet (default) or delft-2005 (the seed's imperfections, sizes fitted to "
                        "Tab. 4.2-4.3)")
    p.add_argument("--ideal-sensors", action="store_true", help="no drawn sensor errors (datasheet nominal)")
    p.add_argument("--no-rrd", action="store_true", help="skip the rerun file")
    p.add_argument("--no-recording", action="store_true", help="skip saving recording.h5")
    p.set_defaults(func=_run_tilt_table)


def _turn_table_args(p):
    # the rig's defaults: its module loads MuJoCo, so only for the campaign asked for
    from imurig.rigs.turn_table import TurnTableProtocol

    d = TurnTableProtocol()
    p.add_argument("--out", default="imurig-out/turn-table", help="report folder")
    p.add_argument("--overwrite", action="store_true", help="replace an existing report folder")
    p.add_argument("--seed", type=int, default=2005, help="master random seed")
    p.add_argument("--rates", type=_floats, default=d.dial_rates_dps, metavar="DPS,...",
                   help="dial rates (the table turns at 5/6 of them on 50 Hz mains)")
    p.add_argument("--directions", type=_floats, default=d.directions, metavar="1,-1",
                   help="turning directions: 1 (counter-clockwise seen from above), -1, or both")
    p.add_argument("--mounts", type=_words, default=d.mounts, metavar="AXIS_up,...",
                   help="which IMU axis points up the table axis: p_up, q_up, r_up, p_down, ...")
    p.add_argument("--min-window", type=float, default=d.min_window_s, help="least seconds of whole rounds per step")
    p.add_argument("--timer", default="hp6700", choices=["hp6700", "gps_mark", "adc"],
                   help="what times the whole rounds: the HP 6700 counter, the GPS mark input or the ADC")
    p.add_argument("--model", default="physical",
                   choices=["physical", "linear", "seed_final", "paper_eq3", "stepwise", "backward"],
                   help="gyro calibration model (paper_eq3: the EUCASS paper's eq. 3, own axis to the cube)")
    p.add_argument("--mains-hz", type=float, default=50.0, help="mains frequency of the synchronous motor")
    p.add_argument("--no-slip-rings", action="store_true", help="no slip-ring noise")
    p.add_argument("--lab", default="quiet", choices=["quiet", "delft-2005"],
                   help="the virtual lab: quiet (default) or delft-2005 (the seed's turn-table disturbances, sizes "
                        "fitted to Figs. 4.20-4.21)")
    p.add_argument("--no-studies", action="store_true", help="skip the timer, arm and SIMONA studies")
    p.add_argument("--no-rrd", action="store_true")
    p.add_argument("--no-recording", action="store_true")
    p.set_defaults(func=_run_turn_table)


def _thermal_args(p):
    # the rig's defaults: its module loads MuJoCo, so only for the campaign asked for
    from imurig.rigs.thermal_chamber import ThermalProfile

    d = ThermalProfile()
    p.add_argument("--out", default="imurig-out/thermal")
    p.add_argument("--overwrite", action="store_true")
    p.add_argument("--seed", type=int, default=2005)
    p.add_argument("--low", type=float, default=d.low_C, help="lowest set-point, C")
    p.add_argument("--high", type=float, default=d.high_C, help="highest set-point, C")
    p.add_argument("--step", type=float, default=d.step_C, help="set-point step, C")
    p.add_argument("--cycles", type=int, default=d.cycles, help="temperature cycles of the chamber profile")
    p.add_argument("--soak", type=float, default=d.soak_s, help="soak time per set-point, s")
    p.add_argument("--lab", default="quiet", choices=["quiet", "delft-2005"],
                   help="the virtual lab: quiet (default) or delft-2005 (the seed's own gyros: Table B.1 scale "
                        "factors, the paper's Fig. 2 r-gyro bias temperature coefficient)")
    p.add_argument("--no-rrd", action="store_true")
    p.add_argument("--no-recording", action="store_true")
    p.set_defaults(func=_run_thermal)


def _magnetometer_args(p):
    p.add_argument("--out", default="imurig-out/magnetometer")
    p.add_argument("--overwrite", action="store_true")
    p.add_argument("--seed", type=int, default=2005)
    p.add_argument("--start-time", default="2005-06-21T10:00:00+02:00", type=_iso_time, help="date and time (for IGRF)")
    p.add_argument("--hard-iron-nT", type=float, default=6000.0, help="largest hard-iron bias per axis")
    p.add_argument("--noise-nT", type=float, default=5.0, help="fluxgate noise, nT rms per sample")
    p.add_argument("--lab", default="quiet", choices=["quiet", "delft-2005"],
                   help="the virtual lab: quiet (default) or delft-2005 (hard iron fitted to the paper's Fig. 5)")
    p.add_argument("--no-rrd", action="store_true")
    p.add_argument("--no-recording", action="store_true")
    p.set_defaults(func=_run_magnetometer)


def _run_tilt_table(a):
    from imurig.campaigns.tilt_rig import RigAhead   # the rig alone (MuJoCo): light
    from imurig.rigs.tilt_table import TiltTableProtocol

    proto = TiltTableProtocol(theta_deg=a.theta, phi_deg=a.phi, runs=a.runs, dwell_s=a.dwell,
                              sample_rate_hz=a.rate)
    # the table's moves (MuJoCo, without the interpreter lock) start now, beside the heavy imports below
    # (a bad protocol fails there too, and is reported by the campaign's own checks, as before)
    rig = RigAhead.start(seed=a.seed, protocol=proto, start_time=a.start_time, lab=a.lab)
    from imurig.campaigns.tilt_table import TiltTableCampaign   # the sensor chain, the calibration (scipy)
    from imurig.reports.tilt_table import run                   # matplotlib: in the figures' process

    camp = TiltTableCampaign(protocol=proto, seed=a.seed, start_time=a.start_time, model=a.model,
                             statistic=a.statistic,
                             mux_frequency_hz=a.mux_khz * 1e3, grounding=a.grounding, pump=not a.no_pump,
                             people=not a.no_people, loose_cable=a.loose_cable, crosstalk=not a.no_crosstalk,
                             draw_sensor_errors=not a.ideal_sensors, lab=a.lab)
    print(f"imurig: tilt-table campaign, {proto.n_positions} positions, seed {a.seed} -> {a.out}", file=sys.stderr)
    s = run(camp, a.out, overwrite=a.overwrite, rrd=not a.no_rrd, save_recording=not a.no_recording, rig=rig)
    print_summary(s, a.out)


def _run_turn_table(a):
    # heavy (MuJoCo rigs, matplotlib): loaded when the command runs, not for --help
    from imurig.campaigns.turn_table import TurnTableCampaign
    from imurig.reports.turn_table import run
    from imurig.rigs.turn_table import TurnTableProtocol

    proto = TurnTableProtocol(dial_rates_dps=a.rates, directions=tuple(int(d) for d in a.directions),
                              mounts=a.mounts, min_window_s=a.min_window)
    camp = TurnTableCampaign(protocol=proto, seed=a.seed, timer=a.timer, model=a.model, mains_hz=a.mains_hz,
                             slip_rings=not a.no_slip_rings, lab=a.lab)
    print(f"imurig: turn-table campaign, {len(proto.steps())} steps, seed {a.seed} -> {a.out}", file=sys.stderr)
    s = run(camp, a.out, overwrite=a.overwrite, rrd=not a.no_rrd, save_recording=not a.no_recording,
            studies=not a.no_studies)
    print_summary(s, a.out)
    if s.get("timer_study"):
        print("timer residual envelopes (deg/s): " + ", ".join(
            f"{k}={v['envelope_dps']:.4f}" for k, v in s["timer_study"]["timers"].items()))
    if s.get("simona"):
        print("SIMONA own scale factor (mV/(deg/s)) real/virtual: " + ", ".join(
            f"{g}={s['simona']['real'][g]['scale_mV_per_dps']:.3f}/{s['simona']['virtual'][g]['scale_mV_per_dps']:.3f}"
            for g in "pqr"))


def _run_simona(a):
    # heavy (MuJoCo rigs, matplotlib): loaded when the command runs, not for --help
    from imurig.calibration.simona import SimonaCalibration, read_simona
    from imurig.calibration.simona_report import plot_fig_4_19, simona_markdown
    from imurig.campaigns.turn_table import simona_virtual

    real = read_simona(a.csv)
    virt = simona_virtual(a.seed)
    with OutputFolder(a.out, overwrite=a.overwrite) as out:
        plot_fig_4_19(out.file("fig_4_19_simona.png"), real, virt, gyro=a.gyro)
        md = "# SIMONA gyro calibration: real (appendix B) and virtual\n\n" + simona_markdown(
            SimonaCalibration().fit(real).summary_, SimonaCalibration().fit(virt).summary_) + "\n![fig](fig_4_19_simona.png)\n"
        out.write_text("report.md", md)
    print(md)


def _run_thermal(a):
    # heavy (MuJoCo rigs, matplotlib): loaded when the command runs, not for --help
    from imurig.campaigns.thermal import ThermalCampaign
    from imurig.reports.thermal import run
    from imurig.rigs.thermal_chamber import ThermalProfile

    prof = ThermalProfile(low_C=a.low, high_C=a.high, step_C=a.step, cycles=a.cycles, soak_s=a.soak)
    prof.validate()
    print(f"imurig: thermal campaign, {len(prof.setpoints())} set-points, seed {a.seed} -> {a.out}", file=sys.stderr)
    s = run(ThermalCampaign(profile=prof, seed=a.seed, lab=a.lab), a.out, overwrite=a.overwrite, rrd=not a.no_rrd,
            save_recording=not a.no_recording)
    _print_params(s["parameters"])
    for k, v in s["hysteresis"].items():
        print(f"hysteresis {k}: measured gap {v['measured_gap_m_s2']:.3e}, injected {v['injected_hysteresis_m_s2']:.3e} m/s^2")
    print(f"report: {Path(a.out) / 'report.md'}")


def _run_magnetometer(a):
    # heavy (MuJoCo rigs, matplotlib): loaded when the command runs, not for --help
    from imurig.campaigns.magnetometer import MagnetometerCampaign
    from imurig.reports.magnetometer import run

    camp = MagnetometerCampaign(seed=a.seed, start_time=a.start_time, hard_iron_max_nT=a.hard_iron_nT,
                                noise_nT=a.noise_nT, lab=a.lab)
    print(f"imurig: magnetometer campaign, seed {a.seed} -> {a.out}", file=sys.stderr)
    s = run(camp, a.out, overwrite=a.overwrite, rrd=not a.no_rrd, save_recording=not a.no_recording)
    ig = s["igrf"]
    print(f"IGRF: H = {ig['horizontal_nT']:.1f} nT (paper {ig['published_horizontal_nT']:.0f}), "
          f"F = {ig['total_nT']:.1f} nT (paper {ig['published_total_nT']:.0f})")
    _print_params(s["parameters"])
    for k, v in s["heading_error_deg"].items():
        print(f"heading error {k:36s} RMS {v['rms']:.3f} deg, max {v['max_abs']:.3f} deg")
    print(f"report: {Path(a.out) / 'report.md'}")


def print_summary(s: dict, out):
    """Print a campaign's parameter table, residual sigmas, timing and report path."""
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


def _print_params(params):
    print(f"{'parameter':30s} {'injected':>13s} {'estimate':>13s} {'std.err':>9s} {'z':>6s}")
    for p in params:
        inj = "–" if p.get("injected") is None else f"{p['injected']:+.5e}"
        z = "–" if p.get("z") is None else f"{p['z']:+.2f}"
        print(f"{p['name']:30s} {inj:>13s} {p['estimate']:+.5e} {p['std_error']:.2e} {z:>6s}")


#: name -> (help, description, the function adding its arguments)
CAMPAIGNS = {
    "tilt-table": ("accelerometer calibration on the two-axis tilt table (seed 4.3)",
                   "Simulate the tilt-table campaign, calibrate the accelerometers and write a "
                   "report folder (report.md, summary.json, recording.h5, campaign.rrd).", _tilt_table_args),
    "turn-table": ("gyro calibration on the Genisco C181 turn table (seed 4.4)",
                   "Simulate the final gyro calibration (and, unless --no-studies, the timer "
                   "study of Fig. 4.20, accelerometers beyond 1 g on the arm, and the SIMONA "
                   "comparison of Fig. 4.19) and write a report folder.", _turn_table_args),
    "thermal": ("thermal-chamber calibration, two cycles, six attitudes (seed 4.5)", None, _thermal_args),
    "magnetometer": ("IGRF field, two-step ellipse/ellipsoid, compass swing, heading (seed 4.6-4.7)", None,
                     _magnetometer_args),
}
