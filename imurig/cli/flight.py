"""`imurig flight`: the default flight with an uncalibrated and a calibrated IMU (issue 6)."""
from __future__ import annotations

import argparse


def add_flight_parser(sub) -> None:
    p = sub.add_parser("flight", help="fly the default flight plan through the GPS/INS filter, uncalibrated vs calibrated",
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--flight", default="default", choices=["default", "static", "van"],
                   help="'default': the Citation's default flight plan; 'static': the paper's static attitude "
                        "tests; 'van': the paper's ground test (section 4.3, Figs. 8-9): a van driven on straight "
                        "runs and circles, braking hard, parked on a ramp")
    p.add_argument("--duration", type=float, default=None, help="cut the flight to this many seconds")
    p.add_argument("--seed", type=int, default=2005, help="the IMU (same seed as the calibration campaigns)")
    p.add_argument("--nav-rate", type=float, default=25.0, help="navigation/filter rate, Hz")
    p.add_argument("--gps-rate", type=float, default=1.0, help="GPS fix rate, Hz")
    p.add_argument("--filter", default="paper18", choices=["paper18", "extended"],
                   help="the filter's states: 'paper18' = the paper's 18 (position, velocity, attitude, "
                        "accelerometer and gyro biases, accelerometer temperatures) in both runs; 'extended' = "
                        "those and a state for each sensor error the run's calibration leaves uncertain "
                        "(uncalibrated 69, calibrated 27; the report and summary.json list them)")
    p.add_argument("--compass-model", default="iron", choices=["iron", "gauss-markov"],
                   help="with --filter extended, the uncalibrated fluxgate in the filter: "
                        "'iron' = hard/soft iron as 12 random-constant "
                        "states (compass updates heading, gyro biases, iron); 'gauss-markov' = one heading-error "
                        "state, Gauss-Markov in the rotation angle (consistent, but far too cautious)")
    p.add_argument("--lab", default="quiet", choices=["quiet", "delft-2005"],
                   help="'delft-2005': the fluxgate installation of the Delft 2005 preset (hard iron fitted to the "
                        "paper's Fig. 5), e.g. for the van's heading of paper Fig. 8; the inertial sensors stay drawn")
    p.add_argument("--full-calibration", action="store_true", help="full campaign protocols instead of reduced ones")
    p.add_argument("--out", default="imurig-out/flight")
    p.add_argument("--overwrite", action="store_true")
    p.set_defaults(func=_run)


def _run(args) -> int:
    # lazy: the study (MuJoCo, the filter) and the report (matplotlib, rerun) load only for this command
    from imurig.campaigns.flight import FlightOptions, fly
    from imurig.reports.flight import open_folder, write_report

    opt = FlightOptions(flight=args.flight, seed=args.seed, duration_s=args.duration, nav_rate_hz=args.nav_rate,
                        gps_rate_hz=args.gps_rate, quick_calibration=not args.full_calibration,
                        mag_iron_states=args.compass_model == "iron", filter=args.filter, lab=args.lab).validate()
    with open_folder(args.out, overwrite=args.overwrite) as folder:   # refuses an existing --out before flying
        s = write_report(folder, fly(opt))
    u, c = s["runs"]["uncalibrated"], s["runs"]["calibrated"]
    print(f"wrote {args.out}: heading RMS {u['heading_rms_deg']:.3f} -> {c['heading_rms_deg']:.3f} deg, "
          f"roll {u['roll_rms_deg']:.4f} -> {c['roll_rms_deg']:.4f} deg, pitch {u['pitch_rms_deg']:.4f} -> "
          f"{c['pitch_rms_deg']:.4f} deg; real-time factor {s['real_time_factor']:.1f}x")
    return 0
