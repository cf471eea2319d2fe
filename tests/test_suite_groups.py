"""The suite's own scheduling (tests/conftest.py): under ``pytest -n 2`` the tests that share a module- or
session-scoped fixture (simulated data) run on one worker, so the data is built once per run."""
from __future__ import annotations

import os

import pytest

from conftest import _shared_fixtures


@pytest.fixture(scope="module")
def built_once():
    """Stands for a module's simulated data: the process that built it."""
    return os.getpid()


def test_this_module_shares_a_fixture(built_once):
    assert built_once > 0


def test_tests_sharing_a_fixture_have_one_group_that_xdist_reads(request, built_once):
    """Every collected test using a shared fixture carries exactly one xdist group, the same for every
    test of that fixture; on a worker under ``--dist loadgroup`` its node id ends in '@group', the
    suffix xdist's scheduler reads (without it every test is scheduled alone and a module's data is
    built on both workers: pytest 9.2 with xdist 3.8, pytest-dev/pytest-xdist#1386)."""
    group_of: dict[str, str] = {}
    for it in request.session.items:
        fixtures = _shared_fixtures(it)
        if not fixtures:
            continue
        groups = {str(m.args[0]) for m in it.iter_markers("xdist_group")}
        assert len(groups) == 1, (it.nodeid, groups)
        g = groups.pop()
        for f in fixtures:
            assert group_of.setdefault(f, g) == g, (f, it.nodeid, group_of[f], g)
        if getattr(request.config.option, "loadgroup", False):
            assert it.nodeid.endswith("@" + g), it.nodeid
    assert group_of["test_suite_groups.py::built_once"] == "test_suite_groups.py::built_once"
