"""Progress bars (tqdm) for anything that takes more than a second.

Shown on an interactive terminal; hidden when stderr is not a TTY (CI, tests) unless
``IMURIG_PROGRESS=1``; ``IMURIG_PROGRESS=0`` hides them always.
"""
from __future__ import annotations

import os
import sys

from tqdm.auto import tqdm


#: a bar of a few unequal stages: a count and the time spent, no rate and no ETA (a stage's share of the
#: time is not its share of the count, so an ETA from it would mislead)
STAGE_FORMAT = "{desc}: {n}/{total} {unit}s [{elapsed}{postfix}]"


def progress(total=None, desc: str = "", unit: str = "it", **kw):
    """A tqdm bar. Bars in ``unit="stage"`` count whole stages without an ETA (:data:`STAGE_FORMAT`);
    others count work units (samples, epochs, records), whose rate gives an honest ETA; counts are
    shown with SI prefixes only when large (no "2.00/4.00")."""
    flag = os.environ.get("IMURIG_PROGRESS")
    if flag is None:
        disable = not sys.stderr.isatty()
    else:
        disable = flag.strip() in ("0", "false", "no", "")
    if unit == "stage":
        kw.setdefault("bar_format", STAGE_FORMAT)
    return tqdm(total=total, desc=desc, unit=unit, disable=disable, unit_scale=bool(total and total >= 10_000),
                dynamic_ncols=True, leave=False, **kw)
