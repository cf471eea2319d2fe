"""imurig: a virtual calibration rig for inertial measurement units.

    imurig campaign tilt-table            simulate, calibrate and report the seed's protocol
    imurig campaign turn-table            gyro calibration, timers, arm beyond 1 g, SIMONA
    imurig campaign thermal               thermal chamber: bias/scale vs temperature, hysteresis
    imurig campaign magnetometer          IGRF field, two-step ellipse/ellipsoid, compass swing, heading
    imurig simona                         the SIMONA table (appendix B) beside its virtual twin
    imurig montecarlo tilt-table|...      Monte-Carlo accuracy study (Cramer-Rao bounds, coverage)
    imurig flight                         Citation flight with GPS/INS filter, uncalibrated vs calibrated
    imurig calibrate REC                  calibrate your own recording (CSV, MATLAB or HDF5)
    imurig apply CAL.json REC --out OUT   apply a calibration to a new recording
    imurig diagnose REC                   where recording and twin differ; names the physics left out
    imurig concealed list|write|all       the concealed-effect suite as recordings, to diagnose
    imurig export CAMPAIGN --out DIR      a campaign's recording for your own estimator (truth apart)
    imurig score --truth T --estimates E  your estimator's results against the truth
    imurig scoreboard                     your calibrator beside imurig's on every campaign
    imurig reproduce [ITEM|all]           the seed's published items beside imurig's, with verdicts
    imurig convert IN OUT                 HDF5 <-> lab CSV
    imurig info REC                       what a recording holds
"""
from __future__ import annotations

import argparse
import sys

from imurig.cli.campaigns import add_campaign_parsers
from imurig.cli.concealed import add_concealed_parser
from imurig.cli.flight import add_flight_parser
from imurig.cli.montecarlo import add_montecarlo_parser
from imurig.cli.recordings import add_recording_parsers
from imurig.cli.reproduce import add_reproduce_parser
from imurig.cli.scoring import add_scoring_parsers
from imurig.kernel.errors import ImurigError


class HelpFormatter(argparse.RawDescriptionHelpFormatter, argparse.ArgumentDefaultsHelpFormatter):
    """Descriptions as written; defaults shown where they say something: not None or False, not twice."""

    def _get_help_string(self, action):
        h = action.help or ""
        if action.default in (None, False, argparse.SUPPRESS) or "default" in h.lower():
            return h
        return super()._get_help_string(action)


#: help of the options every command shares, where a command gives none
COMMON_HELP = {
    "--out": "output folder or file; an existing one is refused unless --overwrite",
    "--overwrite": "replace an existing output (without it nothing is ever overwritten)",
    "--seed": "random seed: the same seed gives identical data",
    "--no-rrd": "skip the rerun (.rrd) file",
    "--no-recording": "skip saving recording.h5",
}


def _finish(p: argparse.ArgumentParser) -> None:
    """Every parser under ``p``: the shared formatter and the shared options' help."""
    p.formatter_class = HelpFormatter
    for act in p._actions:
        if isinstance(act, argparse._SubParsersAction):
            for sp in act.choices.values():
                _finish(sp)
        elif not act.help:
            act.help = next((COMMON_HELP[o] for o in act.option_strings if o in COMMON_HELP), act.help)


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The ``imurig`` parser for the arguments ``argv`` (default: the command line); a
    campaign's own arguments are added only when ``argv`` asks for that campaign."""
    argv = sys.argv[1:] if argv is None else list(argv)
    p = argparse.ArgumentParser(prog="imurig", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="command", required=True)
    add_campaign_parsers(sub, argv)
    add_montecarlo_parser(sub)
    add_flight_parser(sub)
    add_concealed_parser(sub)
    add_recording_parsers(sub)
    add_scoring_parsers(sub)
    add_reproduce_parser(sub)
    _finish(p)
    return p


def main(argv=None) -> int:
    args = build_parser(argv).parse_args(argv)
    try:
        args.func(args)
    except ImurigError as e:
        print(f"imurig: error: {e}", file=sys.stderr)
        return 2
    except OSError as e:  # a file the system refuses (missing, a folder, no permission, disk full): a message
        where = f" {e.filename}" if e.filename else ""
        print(f"imurig: error: cannot use{where}: {e.strerror or e}; check the path and its permissions",
              file=sys.stderr)
        return 2
    except MemoryError as e:  # an allocation refused (numpy's _ArrayMemoryError is one): a message, not a traceback
        print(f"imurig: error: out of memory ({e}); cut the recording (e.g. per run) or lower its sample rate",
              file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
