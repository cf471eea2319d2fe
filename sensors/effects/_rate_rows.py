"""Shared by the appendix-B row effects: the recorded gyros in a truth mapping."""
from __future__ import annotations

from collections.abc import Mapping


def gyros(truth: Mapping) -> Mapping:
    """The gyro triad's truth: truth["gyros"] (the virtual SIMONA rows) or truth["sensors"]["gyros"]."""
    return truth["gyros"] if "gyros" in truth else truth["sensors"]["gyros"]


def gyro_index(channel: str) -> int:
    """0, 1, 2 for "gyro_p" / "p", "gyro_q", "gyro_r"."""
    return "pqr".index(channel[-1])
