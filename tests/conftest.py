"""Shared, session-scoped simulated datasets (small protocols that keep the suite fast)."""
from __future__ import annotations

import inspect
import os
import sys

# One BLAS thread per test process: the suite runs as `pytest -n 2` on 2 cores, where BLAS threads
# only oversubscribe the cores (spinning threads: ~20 % more CPU for the same tests, measured on
# tests/test_turn_table.py). Set before numpy loads its BLAS; a value the caller set is kept.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")


def _one_blas_thread_in_loaded_openblas() -> list[str]:
    """A plugin may have loaded numpy (and its OpenBLAS) before this file: tell every OpenBLAS
    already mapped into the process to use the thread count set above (what threadpoolctl does)."""
    import ctypes
    import re

    try:
        maps = open("/proc/self/maps").read()   # Linux; elsewhere the environment variable is all
    except OSError:
        return []
    done = []
    for lib in sorted(set(re.findall(r"(/\S*openblas\S*\.so\S*)", maps))):
        dll = ctypes.CDLL(lib)
        for sym in ("scipy_openblas_set_num_threads64_", "scipy_openblas_set_num_threads",
                    "openblas_set_num_threads64_", "openblas_set_num_threads"):
            if hasattr(dll, sym):
                getattr(dll, sym)(int(os.environ["OPENBLAS_NUM_THREADS"]))
                done.append(f"{lib}:{sym}")
                break
    return done


BLAS_THREADS_SET = _one_blas_thread_in_loaded_openblas() if "numpy" in sys.modules else []

import pytest  # noqa: E402

from imurig.campaigns.tilt_table import TiltTableCampaign  # noqa: E402
from imurig.rigs.tilt_table import TiltTableProtocol  # noqa: E402

#: A reduced protocol: 4 tilt angles x 6 rotations x 2 mountings, 4 s per position.
SMALL = TiltTableProtocol(theta_deg=(0, 30, 60, 90), phi_deg=(0, 60, 120, 180, 240, 300), dwell_s=4.0,
                          settle_s=1.0, slew_rate_deg_s=30.0)


def small_campaign(**kw) -> TiltTableCampaign:
    kw.setdefault("protocol", SMALL)
    return TiltTableCampaign(**kw)


@pytest.fixture(scope="session")
def small_recording():
    """A simulated small tilt-table recording (evening: pump off by the clock)."""
    return small_campaign(seed=11).simulate()


class SmallRecords:
    """Small-protocol tilt-table recordings (``small_campaign(seed=..., **kw)``), each simulated
    once per session; calibration and diagnosis leave a recording as it was, so tests share them."""

    def __init__(self):
        self._recs = {}

    def get(self, seed: int, **kw):
        key = (seed, repr(sorted(kw.items())))
        if key not in self._recs:
            self._recs[key] = small_campaign(seed=seed, **kw).simulate()
        return self._recs[key]

    def diagnosis(self, seed: int, **kw) -> dict:
        """``diagnose_tilt_table(get(seed, **kw), default_rng(seed))`` with the nominal twin, once per
        session (tests read it and leave it as it was)."""
        import numpy as np
        from imurig.diagnose.tilt_table import diagnose_tilt_table

        key = ("diagnosis", seed, repr(sorted(kw.items())))
        if key not in self._recs:
            self._recs[key] = diagnose_tilt_table(self.get(seed, **kw), np.random.default_rng(seed))
        return self._recs[key]


@pytest.fixture(scope="session")
def small_records() -> SmallRecords:
    return SmallRecords()


@pytest.fixture(scope="session")
def short_flight():
    """~43 s airborne at 100 Hz: level, 3-2-1-1, double doublet, S-turns at 30 deg both sides."""
    from imurig.flights.plan import AlphaDotSTurns, DoubleDoublet, Elevator3211, FlightPlan, Level, simulate_flight
    plan = FlightPlan(phases=(Level(3.0), Elevator3211(free_s=4.0), DoubleDoublet(lead_s=1.0, free_s=3.0, level_s=1.0),
                              AlphaDotSTurns(banks_first_deg=(30.0,), banks_second_deg=(30.0,), hold_s=5.0,
                                             after_s=2.0, level_s=2.0)))
    return simulate_flight(plan, progress_bar=False)


@pytest.fixture(scope="session")
def default_magnetometer():
    """The scorer's ``magnetometer`` bench campaign: :class:`MagnetometerCampaign` at its default seed,
    whose recording (``.simulate()``, cached by the campaign) the magnetometer and scoring tests share."""
    from imurig.scoring.campaigns import campaign

    return campaign("magnetometer")


def _is_plain_turn_null(case) -> bool:
    """The case's null record is the plain turn-table campaign ``_turn(seed)`` of the suite."""
    import inspect

    return case.rig == "turn_table" and case.null is not None and \
        "null=lambda seed: _turn(seed)" in inspect.getsource(case.null)


class ConcealedRecords:
    """The concealed-effect suite's recordings and null diagnoses, each simulated (diagnosed) once per
    session, whichever test file asks first. Diagnoses do not change the recording they read (the
    Earth-rate test diagnoses one record with two twins), so sharing a record is safe.

    The turn table's null record is ``_turn(seed)`` for every turn case whose ``null`` says so, and
    the Earth-rate case at fraction 1.0 is that same record (``_turn(seed, earth_fraction=1.0)``
    moves no site): one simulation serves them all."""

    def __init__(self):
        self._recs, self._diags = {}, {}

    def _get(self, key, build):
        if key not in self._recs:
            self._recs[key] = build()
        return self._recs[key]

    def make(self, case, seed: int, size: float | None = None):
        size = case.realistic_size if size is None else float(size)
        if case.effect == "earth_rate_left_out" and size == 1.0:
            return self._get(("turn_table", "null", seed), lambda: case.make(seed, size))
        return self._get((case.rig, case.effect, seed, size), lambda: case.make(seed, size))

    def null(self, case, seed: int):
        from imurig.concealed.suite import null_recording

        key = ("turn_table", "null", seed) if _is_plain_turn_null(case) else (case.rig, case.effect, "null", seed)
        return self._get(key, lambda: null_recording(case, seed))

    def null_diagnosis(self, case, seed: int) -> dict:
        """The case's null record diagnosed with the case's null twin (shared by cases with the same both)."""
        from imurig.concealed.suite import diagnose_case

        twin = case.null_twin if case.null_twin is not None else case.twin
        rec = self.null(case, seed)
        key = (id(rec), repr(sorted(_twin_with_defaults(case.rig, twin).items())), case.rig, seed)
        if key not in self._diags:
            self._diags[key] = diagnose_case(case, rec, seed, null=True)
        return self._diags[key]


def _twin_with_defaults(rig: str, twin: dict) -> dict:
    """The twin's settings with the diagnosis' defaults filled in: {} and {'earth_rate': True} are one
    turn-table twin (the null diagnoses of the g-sensitivity and Earth-rate cases are one diagnosis)."""
    from imurig.diagnose.magnetometer import diagnose_magnetometer
    from imurig.diagnose.thermal import diagnose_thermal
    from imurig.diagnose.tilt_table import diagnose_tilt_table
    from imurig.diagnose.turn_table import diagnose_turn_table

    fn = {"tilt_table": diagnose_tilt_table, "turn_table": diagnose_turn_table, "thermal": diagnose_thermal,
          "magnetometer": diagnose_magnetometer}.get(rig)
    if fn is None:
        return dict(twin)
    defaults = {k: p.default for k, p in inspect.signature(fn).parameters.items() if p.default is not p.empty}
    return {**defaults, **twin}


@pytest.fixture(scope="session")
def concealed_records() -> ConcealedRecords:
    return ConcealedRecords()


@pytest.fixture(scope="session")
def check_concealed_case(concealed_records):
    """``check(case, seed, size)``: the diagnosis of the case's recording names exactly the
    expected (channel, effect) pairs with the first parameter within 4 SE of the injected
    truth, and the case's null recording comes back clean. Returns the diagnosis and recording."""
    from imurig.concealed.suite import diagnose_case, found_effects

    def check(case, seed: int, size: float):
        rec = concealed_records.make(case, seed, size)
        d = diagnose_case(case, rec, seed)
        assert found_effects(d) == case.expected
        est, se = case.found_param(d)
        assert abs(est - case.truth_param(rec)) < 4 * se
        assert found_effects(concealed_records.null_diagnosis(case, seed)) == set()
        return d, rec

    return check


def _named(artist) -> bool:
    return not artist.get_label().startswith("_")


def unnamed_artists(fig) -> list[str]:
    """'panel i: artist' for every line, filled area or bar/error-bar set without a label, and every
    panel whose labelled artists no legend of the figure names (its own, another panel's shared
    legend, or the figure's): a legend that does not name every line."""
    out = []
    legends = [*fig.legends, *(ax.get_legend() for ax in fig.axes if ax.get_legend() is not None)]
    named = {t.get_text() for lg in legends for t in lg.get_texts()}
    for i, ax in enumerate(fig.axes):
        where = f"panel {i} ({ax.get_title()[:40]!r})"
        inside = set()
        for c in ax.containers:      # bars, histograms, error bars: the set carries the label
            kids = [k for k in c.get_children() if k is not None]
            inside.update(id(k) for k in kids)
            if not (_named(c) or any(_named(k) for k in kids if hasattr(k, "get_label"))):
                out.append(f"{where}: {type(c).__name__}")
        loose = [a for a in (*ax.get_lines(), *ax.collections) if id(a) not in inside]
        labels = {a.get_label() for a in (*loose, *ax.containers) if _named(a)}
        if ax.get_legend() is None and not labels <= named:   # a shared legend elsewhere may name them
            out.append(f"{where}: no legend names {sorted(labels - named)}")
        out += [f"{where}: {a}" for a in loose if not _named(a)]
    return out


@pytest.fixture(autouse=True)
def every_saved_figure_names_every_line(monkeypatch, request):
    """Every figure a test makes the project save: each panel with lines has a legend and every
    line in it a label (issue 19: figures a reader can read without the code)."""
    from matplotlib.figure import Figure

    problems = []
    orig = Figure.savefig

    def savefig(self, *a, **k):
        problems.extend(f"{a[0] if a else '?'}: {p}" for p in unnamed_artists(self))
        return orig(self, *a, **k)

    monkeypatch.setattr(Figure, "savefig", savefig)
    yield
    assert not problems, "figures whose legend does not name every line:\n" + "\n".join(problems[:20])


def _shared_fixtures(item) -> list[str]:
    """'file::name' of every module- or session-scoped fixture of this test directory that the test
    uses, directly or through another fixture (the data such a fixture holds is built once per worker)."""
    from pathlib import Path

    here = Path(__file__).resolve().parent
    info = getattr(item, "_fixtureinfo", None)
    out = []
    for name in (info.names_closure if info is not None else ()):
        defs = info.name2fixturedefs.get(name)
        if not defs or defs[-1].scope == "function":
            continue
        src = Path(inspect.getsourcefile(defs[-1].func) or "").resolve()
        if src.is_relative_to(here):
            out.append(f"{src.relative_to(here)}::{name}")
    return sorted(out)


@pytest.hookimpl(wrapper=True)   # marks before xdist's own hook turns them into the nodeid's '@group'
def pytest_collection_modifyitems(config, items):
    """Under ``pytest -n 2`` (``--dist loadgroup``, pyproject's addopts) the tests that share a
    module- or session-scoped fixture of this directory (simulated data: :class:`ConcealedRecords`,
    :class:`SmallRecords`, a module's runs) run on one worker, so the data is simulated once per run
    and not once per worker. Tests linked through fixtures they share, directly or by a chain, form
    one group, named after its first fixture; a group a test names itself joins it and names it."""
    parent: dict[str, str] = {}

    def root(k: str) -> str:
        while parent.setdefault(k, k) != k:
            parent[k] = parent[parent[k]]
            k = parent[k]
        return k

    keys = []
    for item in items:
        ks = _shared_fixtures(item) + [f"group:{m.args[0] if m.args else m.kwargs.get('name', 'default')}"
                                       for m in item.iter_markers("xdist_group")]
        keys.append(ks)
        for k in ks[1:]:
            parent[root(k)] = root(ks[0])
    names: dict[str, str] = {}
    for k in sorted({k for ks in keys for k in ks}, key=lambda k: (not k.startswith("group:"), k)):
        names.setdefault(root(k), k)          # a group a test names keeps its name
    for item, ks in zip(items, keys):
        if ks:
            name = names[root(ks[0])]
            item.add_marker(pytest.mark.xdist_group(name.removeprefix("group:").replace("@", "_")))
    yield
    if getattr(config.option, "loadgroup", False):   # a pytest-xdist worker under --dist loadgroup
        _group_suffix_where_xdist_left_none(items)


def _group_suffix_where_xdist_left_none(items) -> None:
    """pytest-xdist 3.8 tells the scheduler an item's group by appending '@group' to ``item._nodeid``;
    pytest 9.2 keeps the node id in ``item._id`` (a structured NodeId), so that suffix is lost and
    every test is scheduled alone (pytest-dev/pytest-xdist#1386; #1388 sets the structured id, as
    here). Where an item with a group has no suffix, set it the way xdist means to: its groups,
    sorted and joined by '_'."""
    from _pytest.nodeid import NodeId

    for item in items:
        groups = sorted({str(m.args[0] if m.args else m.kwargs.get("name", "default"))
                         for m in item.iter_markers("xdist_group")})
        if groups and "@" not in item.nodeid.rpartition("]")[2] and isinstance(getattr(item, "_id", None), NodeId):
            item._id = NodeId.parse(f"{item.nodeid}@{'_'.join(groups)}")
