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
#: a job of weighted stages: the share of the work done and an ETA from it (:class:`StageBar`)
SHARE_FORMAT = "{desc}: {percentage:3.0f}% |{bar}| [{elapsed}<{remaining}{postfix}]"


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


class StageBar:
    """A job's stages on one bar in work units: each stage's share of the job's time, measured
    on the reference machine (2 cores) for the default job, so that tqdm's ETA (time so far /
    share done x share left) is honest to the accuracy of those shares. ``bar(name)`` starts
    stage ``name`` and completes the one before; stages missing from ``shares`` count 0; the
    shares of the stages actually run are scaled to 100 %. Use as a context manager."""

    def __init__(self, shares: dict[str, float], stages, desc: str):
        run = {s: float(shares.get(s, 0.0)) for s in stages}
        total = sum(run.values()) or 1.0
        self.share = {s: 100.0 * w / total for s, w in run.items()}
        self.current = None
        self.bar = progress(total=100.0, desc=desc, unit="%", bar_format=SHARE_FORMAT)

    def __call__(self, name: str) -> None:
        self._finish()
        self.current = name
        self.bar.set_postfix_str(name)

    def _finish(self) -> None:
        if self.current is not None:
            self.bar.update(self.share.get(self.current, 0.0))
            self.current = None

    def __enter__(self) -> "StageBar":
        return self

    def __exit__(self, *exc) -> None:
        self._finish()
        self.bar.close()
