"""``imurig reproduce [ITEM|all] --out DIR``: the seed's published items run and set beside the seed's
values (:mod:`imurig.reports.reproduce`)."""
from __future__ import annotations

from pathlib import Path


def add_reproduce_parser(sub) -> None:
    p = sub.add_parser("reproduce", help="run the seed's published tables and figures and set each beside the "
                                        "seed's value, with a tolerance and a verdict")
    p.add_argument("item", nargs="?", default="all", help="an item (e.g. tab_4_1, igrf_field, paper_table_1) or all")
    p.add_argument("--out", default="imurig-out/reproduce")
    p.add_argument("--overwrite", action="store_true")
    p.set_defaults(func=_reproduce)


def _reproduce(a):
    # heavy (the flight stack for the observability item): loaded when the command runs, not for --help
    from imurig.kernel.outputs import OutputFolder
    from imurig.reports.reproduce import ITEMS, reproduce
    from imurig.kernel.errors import ConfigError

    if a.item != "all" and a.item not in ITEMS:     # refused before the output folder exists
        raise ConfigError(f"no reproducible item {a.item!r}; choose 'all' or one of {sorted(ITEMS)}")
    with OutputFolder(a.out, overwrite=a.overwrite) as out:
        s = reproduce(a.item, out)
    print(f"{s['within']} of {s['quantities']} quantities within the seed's tolerance; "
          f"report: {Path(a.out) / 'reproduce.md'}")
