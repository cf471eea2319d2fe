"""Progress bars (tqdm) for anything that takes more than a second.

Shown on an interactive terminal; hidden when stderr is not a TTY (CI, tests) unless
``IMURIG_PROGRESS=1``; ``IMURIG_PROGRESS=0`` hides them always.
"""
from __future__ import annotations

import os
import sys

from tqdm.auto import tqdm


def progress(total=None, desc: str = "", unit: str = "it", **kw):
    flag = os.environ.get("IMURIG_PROGRESS")
    if flag is None:
        disable = not sys.stderr.isatty()
    else:
        disable = flag.strip() in ("0", "false", "no", "")
    return tqdm(total=total, desc=desc, unit=unit, disable=disable, unit_scale=True,
                dynamic_ncols=True, leave=False, **kw)
