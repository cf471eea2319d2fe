"""Write one small .rrd of every recording type (the smallest settings of each command).

    python scripts/rrd_examples.py OUT_DIR [--only tilt-table,diagnosis-tilt,...]

Writes OUT_DIR/<kind>/... through the command line (the same code a user runs) and prints
``<kind> <path of the .rrd> <seconds>`` per kind. ``scripts/rrd_screenshots.py`` renders them.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from imurig.cli.main import main as imurig

# kind -> (list of CLI argument lists run in order, the .rrd written, relative to OUT_DIR/<kind>)
KINDS = {
    "tilt-table": ([["campaign", "tilt-table", "--theta", "0,45,90", "--phi", "0,90,180,270", "--dwell", "2",
                     "--seed", "3", "--out", "{d}/out", "--overwrite"]], "out/campaign.rrd"),
    "turn-table": ([["campaign", "turn-table", "--rates", "20,40,80", "--min-window", "5", "--no-studies",
                     "--seed", "4", "--out", "{d}/out", "--overwrite"]], "out/campaign.rrd"),
    "thermal": ([["campaign", "thermal", "--low", "-20", "--high", "40", "--step", "30", "--soak", "2400",
                  "--seed", "1", "--out", "{d}/out", "--overwrite"]], "out/campaign.rrd"),
    "magnetometer": ([["campaign", "magnetometer", "--seed", "1", "--out", "{d}/out", "--overwrite"]],
                     "out/campaign.rrd"),
    "flight": ([["flight", "--duration", "120", "--out", "{d}/out", "--overwrite"]], "out/flight.rrd"),
    "diagnosis-tilt": ([["concealed", "write", "tilt_table:axis_misalignment", "--out", "{d}/rec.h5", "--overwrite"],
                        ["diagnose", "{d}/rec.h5", "--twin-model", "own_axis", "--out", "{d}/out", "--overwrite"]],
                       "out/diagnosis.rrd"),
    "diagnosis-magnetometer": ([["concealed", "write", "magnetometer:hard_iron", "--out", "{d}/rec.h5",
                                 "--overwrite"],
                                ["diagnose", "{d}/rec.h5", "--out", "{d}/out", "--overwrite"]], "out/diagnosis.rrd"),
    "montecarlo": ([["montecarlo", "tilt-table", "--n-runs", "4", "--workers", "1", "--theta", "0,45,90",
                     "--phi", "0,90,180,270", "--dwell", "2", "--out", "{d}/out", "--overwrite"]], "out/study.rrd"),
}


def write(out_dir: Path, kinds) -> dict[str, Path]:
    """Run each kind's commands into ``out_dir/<kind>``; returns {kind: .rrd path}."""
    written = {}
    for kind in kinds:
        cmds, rrd = KINDS[kind]
        d = out_dir / kind
        d.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        for cmd in cmds:
            code = imurig([a.format(d=d) for a in cmd])
            if code != 0:
                raise SystemExit(f"{kind}: `imurig {' '.join(cmd)}` exited {code}")
        written[kind] = d / rrd
        print(kind, written[kind], f"{time.perf_counter() - t0:.1f}", flush=True)
    return written


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out_dir", type=Path)
    ap.add_argument("--only", default=",".join(KINDS), help="comma-separated kinds: " + ", ".join(KINDS))
    a = ap.parse_args(argv)
    write(a.out_dir, [k for k in a.only.split(",") if k])
    return 0


if __name__ == "__main__":
    sys.exit(main())
