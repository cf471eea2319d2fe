"""The EUCASS 2005 paper's calibration models (the seed's appended paper): its eq. 2 for the
accelerometers and eq. 3 for the gyros, as term libraries of :mod:`imurig.calibration.terms`."""
from __future__ import annotations

from collections.abc import Sequence

from imurig.calibration.terms import TermLibrary


def _own_first(inputs: Sequence[str], own: str) -> tuple[str, str, str]:
    """(own, other, other) of three inputs, in the inputs' order for the other two."""
    if own not in inputs:
        raise ValueError(f"axis input must be one of {list(inputs)}, got {own!r}")
    b, c = (n for n in inputs if n != own)
    return own, b, c


def paper_eq2_terms(axis: str) -> TermLibrary:
    """The EUCASS 2005 paper's accelerometer model, its eq. 2 (x axis; y and z "similar"):

        a_x = C0 + C1 ax + C2 ax^2 + C3 ax^3 + C4 ax^4 + C5 ay + C6 ay^2 + C7 az + C8 az^2
              + C9 ax ay + C10 ax az + C11 ay az

    with a_i the accelerometers' outputs; for axis y (z) the own-axis powers go to ay (az)."""
    inputs = ("ax", "ay", "az")
    a, b, c = _own_first(inputs, f"a{axis}")
    pair = lambda u, v: "*".join(sorted((u, v), key=inputs.index))          # noqa: E731
    return TermLibrary.from_names(["1", a, f"{a}^2", f"{a}^3", f"{a}^4", b, f"{b}^2", c, f"{c}^2",
                                   pair(a, b), pair(a, c), pair(b, c)])


def paper_eq3_terms(axis: str) -> TermLibrary:
    """The EUCASS 2005 paper's gyro model, its eq. 3 (p gyro; q and r "similar"):

        p = C0 + C1 p + C2 p^2 + C3 p^3 + C5 q + C7 r + C9 p q + C10 p r + C11 q r

    with p, q, r the gyros' outputs (the paper numbers the coefficients as in eq. 2 and leaves
    C4, C6, C8 out)."""
    inputs = ("wp", "wq", "wr")
    a, b, c = _own_first(inputs, f"w{axis}")
    pair = lambda u, v: "*".join(sorted((u, v), key=inputs.index))          # noqa: E731
    return TermLibrary.from_names(["1", a, f"{a}^2", f"{a}^3", b, c, pair(a, b), pair(a, c), pair(b, c)])
