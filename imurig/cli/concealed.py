"""``imurig concealed {list,write,all}``: the concealed-effect suite as recordings
(:mod:`imurig.concealed.cases`)."""
from __future__ import annotations

from pathlib import Path


def add_concealed_parser(sub) -> None:
    """``imurig concealed {list,write,all}`` (:mod:`imurig.concealed.cases`)."""
    p = sub.add_parser("concealed", help="the concealed-effect suite as recordings: list, write one, or "
                                         "write and diagnose them all")
    s = p.add_subparsers(dest="concealed_cmd", required=True)
    s.add_parser("list", help="the cases: rig:effect, realistic size, twin").set_defaults(func=_list)
    w = s.add_parser("write", help="write one case (or its null record) as a recording with its truth")
    w.add_argument("case", help="rig:effect, e.g. tilt_table:adc_crosstalk (see `imurig concealed list`)")
    w.add_argument("--out", required=True, help="output recording (.h5)")
    w.add_argument("--size", type=float, default=None, help="effect size in the case's unit (default: realistic)")
    w.add_argument("--seed", type=int, default=1)
    w.add_argument("--null", action="store_true", help="the null record: nothing concealed from this twin")
    w.add_argument("--overwrite", action="store_true")
    w.set_defaults(func=_write)
    al = s.add_parser("all", help="write every case and null record and diagnose each")
    al.add_argument("--out", default="imurig-out/concealed")
    al.add_argument("--seeds", type=int, default=1, help="records per case (seeds 1..N)")
    al.add_argument("--cases", default="", help="comma-separated rig:effect (default: all)")
    al.add_argument("--overwrite", action="store_true")
    al.set_defaults(func=_all)


def _write(a):
    # heavy (the suite's MuJoCo rigs, the diagnosis): loaded when the command runs, not for --help
    from imurig.reports.concealed import write_case

    path, rec = write_case(a.case, a.out, a.seed, a.size, a.null, a.overwrite)
    info = rec.meta["concealed_case"]
    what = ("null record (nothing concealed)" if a.null
            else f"{info['effect']} at {info['size']:.4g} {info['size_unit']}")
    print(f"{path}: {info['rig']}, {what}; twin {rec.meta['diagnose_twin'] or 'nominal'}")
    print(f"diagnose it with: imurig diagnose {path} --out {Path(path).stem}-diagnosis")


def _list(_a):
    # heavy (the suite's MuJoCo rigs, the diagnosis): loaded when the command runs, not for --help
    from imurig.reports.concealed import case_table

    print(case_table())


def _all(a):
    # heavy (the suite's MuJoCo rigs, the diagnosis): loaded when the command runs, not for --help
    from imurig.reports.concealed import run_all

    s = run_all(a.out, a.seeds, a.overwrite, a.cases.split(",") if a.cases else None)
    print(f"{s['n_correct']} of {s['n_records']} records diagnosed correctly; report: {Path(a.out) / 'report.md'}")
