"""Shared by the turn-table effects: the recorded table's injected physics in a truth mapping."""
from __future__ import annotations

from collections.abc import Mapping


def table_errors(truth: Mapping) -> Mapping:
    """The turn table's injected errors: truth["rig"]["turn_table"] (a rig recording) or
    truth["turn_table"] (appendix-B rows of the virtual SIMONA experiment)."""
    if "turn_table" in truth:
        return truth["turn_table"]
    return truth["rig"]["turn_table"]
