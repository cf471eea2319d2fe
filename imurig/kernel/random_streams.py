"""Named random streams: one registry of every random stream the project draws from.

A stream is a :class:`numpy.random.SeedSequence` named by a path such as
``"campaign/tilt-table/sensor-chain"``. Its spawn key is derived from the name, word by word,
and its entropy is the master seed the user gives (``--seed``)::

    name = "w_1/w_2/.../w_k"
    key(name)        = (crc32(w_1), crc32(w_2), ..., crc32(w_k))
    key(name, run=i) = (crc32(w_1), ..., crc32(w_k), i)           only for run-indexed names
    stream           = SeedSequence(entropy=seed, spawn_key=key)

A child stream (a stage of a sensor chain, one draw of a Monte-Carlo run) extends its parent's
key by the crc32 of its own word: the child ``"sensor-chain/pump"`` of the stream
``"flight/sensor-chain"`` has the key of ``"flight/sensor-chain/pump"``. So every stream's key
is a function of its full name, two different names give two different keys (the registry
refuses a word whose crc32 equals another word's, and a word whose crc32 is small enough to be
mistaken for a run index or a ``Generator.spawn`` counter), and a stage switched on or off never
moves another stage's stream.

Every name must be registered below (:data:`STREAMS` for streams of a master seed,
:data:`CHILD_STREAMS` for children of a stream) with a one-line description; an unregistered
name raises :class:`UnknownStreamError`. A new effect that needs its own stream registers it
with :func:`register`. :func:`recording` logs every stream handed out while it is open.

One name is one stream: ``"sensor_errors"`` (the IMU unit's manufacturing errors) is
deliberately the same stream in every campaign and in the flight of one seed, so the rigs
calibrate the very sensors that fly.

The draws that make up one seed's lab (the IMU, the tilt table and its survey, the fluxgate's
installation, the gyros' temperature coefficients) keep the one-word names they had as children
of ``SeedSequence(seed)`` before the registry existed: their keys, and so every seed's IMU, table
and installation, are the same as before. Everything else (rig runs, sensor chains, the flight,
Monte-Carlo runs) has a path name.
"""
from __future__ import annotations

import re
import zlib
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from imurig.kernel.errors import ConfigError

#: crc32 words below this are refused: they could equal a run index or a Generator.spawn counter
MIN_WORD = 2**20

#: streams of a master seed (and, for RUN_INDEXED names, a run index): name -> description
STREAMS: dict[str, str] = {
    # the lab of one seed (one-word names: the same draws as before the registry, see the module doc)
    "sensor_errors": "the IMU's manufacturing errors (ImuLab.draw): one unit per seed, shared by the "
                     "campaigns and the flight of that seed",
    "table": "the tilt table's mechanical errors (TiltTableErrors.draw)",
    "survey": "the survey of the tilt table's errors (TableSurvey.measure)",
    "magnetometer_install": "the magnetometer campaign's fluxgate and its installation iron "
                            "(FluxgateTriad.from_datasheet)",
    "gyro_thermal": "the gyros' temperature coefficients drawn for the thermal campaign",
    # tilt table (accelerometers)
    "campaign/tilt-table/rig": "the tilt table's run in MuJoCo (per-position setting errors)",
    "campaign/tilt-table/sensor-chain": "the tilt-table campaign's sensor chain (parent of its stages)",
    # turn table (gyros), its studies and SIMONA
    "campaign/turn-table/rig": "the turn table's run (dial setting errors, arm radius measurement)",
    "campaign/turn-table/sensor-chain": "the turn-table campaign's sensor chain",
    "campaign/timer-study/rig": "the timer study's turn-table run (r gyro up, section 4.4.3)",
    "campaign/timer-study/sensor-chain": "the timer study's sensor chain",
    "campaign/arm-study/rig": "the arm study's turn-table run (accelerometer on the arm)",
    "campaign/arm-study/sensor-chain": "the arm study's sensor chain",
    "campaign/simona/lab": "the virtual SIMONA experiment: table, FOG draw and noise, voltmeter",
    # thermal chamber
    "campaign/thermal/sensor-chain": "the thermal campaign's sensor chain",
    # magnetometer rig
    "campaign/magnetometer/rig": "the magnetometer rig's gimbal run (wobble of the hand-turned manoeuvres)",
    "campaign/magnetometer/sensor-chain": "the magnetometer campaign's sensor chain",
    # the flight (imurig flight, imurig.scoring.flight)
    "flight/sensor-chain": "the flight's IMU measurement (flights.imu.measure_flight)",
    "flight/gps": "the flight's GPS receiver errors (flights.gps.GpsReceiver.measure)",
    "flight/mag-rig/rig": "the tumble of the flight's fluxgate on the magnetometer rig",
    "flight/mag-rig/sensor-chain": "the sensor chain of that tumble",
    # concealed cases
    "concealed/timer/table-slip": "the turn table's constant slip of one SIMONA timer record",
    # Monte Carlo
    "montecarlo/run": "run i of a Monte-Carlo study: parent of every draw of its virtual lab",
}

#: names whose streams take a run index
RUN_INDEXED = frozenset({"montecarlo/run"})

#: children of a stream whose name ends in the first word: "<parent's last word>/<word>" -> description
#: ("{...}" stands for any word of letters, digits and underscores)
CHILD_STREAMS: dict[str, str] = {
    # the sensor chain's stages (imurig.sensors.chain.ImuLab.measure, imurig.flights.imu)
    "sensor-chain/pump": "hydraulic pump vibration",
    "sensor-chain/people": "people walking in the lab",
    "sensor-chain/accelerometers": "Q-Flex current noise",
    "sensor-chain/magnetometer": "fluxgate noise",
    "sensor-chain/gyros": "FOG angle random walk and bias instability",
    "sensor-chain/temp_{sensor}": "noise of one temperature sensor line (temp_acc_x, ..., temp_box)",
    "sensor-chain/slip_{line}": "slip-ring contact noise on one analog line",
    "sensor-chain/gyro_scale_{line}": "the gyro scale-factor wander of one gyro line (gyro_p, gyro_q, gyro_r)",
    "sensor-chain/cable": "loose-cable spikes",
    "sensor-chain/adc": "DAQ-6036E noise and dither",
    "sensor-chain/gps_mark": "the GPS receiver's event-mark timer",
    "sensor-chain/hp6700": "the HP 6700 counter",
    # one Monte-Carlo run (imurig.montecarlo.tilt, .turn, .flight)
    "run/table": "the tilt table's errors",
    "run/survey": "the table survey",
    "run/sensor_errors": "the IMU's manufacturing errors",
    "run/rig": "the rig's run",
    "run/sensor-chain": "the run's sensor chain (parent of its stages)",
    "run/gps": "the flight's GPS receiver errors",
    "run/residual_{source}": "the residual calibration error of one source (flight error budget)",
    "run/user_{parameter}": "a parameter drawn from a user's distributions file",
}

_WORD_RE = r"[A-Za-z0-9_]+"


class UnknownStreamError(ConfigError):
    """A random stream was asked for by a name the registry does not hold."""


# ------------------------------------------------------------------ keys
_WORDS: dict[int, str] = {}


def word_key(word: str) -> int:
    """crc32 of one word of a name; refuses a word that collides with another or is too small."""
    k = zlib.crc32(word.encode())
    seen = _WORDS.setdefault(k, word)
    if seen != word:
        raise UnknownStreamError(f"stream words {seen!r} and {word!r} share the key {k}; rename one")
    if k < MIN_WORD:
        raise UnknownStreamError(f"stream word {word!r} has the key {k} < {MIN_WORD}, which a run index "
                                 "could equal; rename it")
    return k


def key(name: str, run: int | None = None) -> tuple[int, ...]:
    """The spawn key of the registered stream ``name`` (and run ``run`` for a run-indexed name)."""
    _check_top(name)
    if (run is None) == (name in RUN_INDEXED):
        raise UnknownStreamError(f"stream {name!r} " + ("needs a run index" if run is None else
                                                         "takes no run index"))
    words = tuple(word_key(w) for w in name.split("/"))
    if run is None:
        return words
    if not 0 <= int(run) < MIN_WORD:
        raise ConfigError(f"run index must be in [0, {MIN_WORD}), got {run}")
    return (*words, int(run))


def _check_top(name: str) -> None:
    if name not in STREAMS:
        raise UnknownStreamError(f"no random stream named {name!r}; register it in imurig.kernel.random_streams "
                                 f"(known: {', '.join(sorted(STREAMS))})")


def _child_description(name: str) -> str:
    if name in CHILD_STREAMS:
        return CHILD_STREAMS[name]
    for pattern, text in CHILD_STREAMS.items():
        if "{" in pattern and re.fullmatch(re.sub(r"\{\w+\}", _WORD_RE, pattern), name):
            return text
    family = name.split("/")[0]
    known = sorted(k for k in CHILD_STREAMS if k.split("/")[0] == family)
    raise UnknownStreamError(f"no child stream named {name!r}; register it in imurig.kernel.random_streams "
                             f"(known for {family!r}: {', '.join(known) or 'none'})")


# ------------------------------------------------------------------ streams
def seed_sequence(name: str, seed: int, run: int | None = None) -> np.random.SeedSequence:
    """The SeedSequence of the registered stream ``name`` for master seed ``seed`` (and run
    index ``run`` for a run-indexed name): entropy = seed, spawn key = :func:`key`."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ConfigError(f"a master seed is an integer >= 0, got {seed!r}")
    ss = np.random.SeedSequence(entropy=int(seed), spawn_key=key(name, run))
    _log(name if run is None else f"{name}[{int(run)}]", ss)
    return ss


def generator(name: str, seed: int, run: int | None = None) -> np.random.Generator:
    """A Generator (PCG64) on the stream :func:`seed_sequence` gives."""
    return np.random.default_rng(seed_sequence(name, seed, run))


def child_seed_sequence(parent: np.random.SeedSequence, name: str) -> np.random.SeedSequence:
    """The child ``name`` ("<family>/<word>", registered in :data:`CHILD_STREAMS`) of the stream
    ``parent``: same entropy, spawn key = parent's key + (crc32(word),)."""
    _child_description(name)
    ss = np.random.SeedSequence(entropy=parent.entropy,
                                spawn_key=(*parent.spawn_key, word_key(name.split("/", 1)[1])))
    _log_child(parent, name, ss)
    return ss


def child_generator(parent: np.random.SeedSequence, name: str) -> np.random.Generator:
    """A Generator on the child stream :func:`child_seed_sequence` gives."""
    return np.random.default_rng(child_seed_sequence(parent, name))


def register(name: str, description: str, child: bool = False, run_indexed: bool = False) -> None:
    """Add a stream (``child``: a child family entry "<family>/<word>") to the registry, e.g. for a
    new effect of the sensor chain; refuses a name already registered with another description."""
    table = CHILD_STREAMS if child else STREAMS
    if not description.strip():
        raise ConfigError(f"stream {name!r} needs a description")
    if table.get(name, description) != description:
        raise ConfigError(f"stream {name!r} is already registered: {table[name]!r}")
    if child and len(name.split("/")) != 2:
        raise ConfigError(f"a child stream is named '<family>/<word>', got {name!r}")
    _check_words(name)
    table[name] = description
    if run_indexed and not child:
        global RUN_INDEXED
        RUN_INDEXED = RUN_INDEXED | {name}


# ------------------------------------------------------------------ record what is handed out
@dataclass(frozen=True)
class StreamRecord:
    """One stream handed out: its name (children: parent's name + "/" + word), entropy, spawn key."""

    name: str
    entropy: int
    spawn_key: tuple[int, ...]


@dataclass
class StreamLog:
    """The streams handed out while :func:`recording` was open, in order."""

    records: list[StreamRecord] = field(default_factory=list)
    _names: dict = field(default_factory=dict, repr=False)

    def add(self, name: str, ss: np.random.SeedSequence) -> None:
        r = StreamRecord(name, int(ss.entropy), tuple(int(k) for k in ss.spawn_key))
        self.records.append(r)
        self._names.setdefault((r.entropy, r.spawn_key), r.name)

    def name_of(self, ss: np.random.SeedSequence) -> str | None:
        return self._names.get((int(ss.entropy), tuple(int(k) for k in ss.spawn_key)))

    def by_name(self) -> dict[str, set]:
        """name -> the set of (entropy, spawn key) it was handed out with."""
        out: dict[str, set] = {}
        for r in self.records:
            out.setdefault(r.name, set()).add((r.entropy, r.spawn_key))
        return out

    def shared(self) -> list[tuple[str, ...]]:
        """Groups of different names that were handed the same (entropy, spawn key): empty when
        every stream is distinct."""
        by_key: dict[tuple, set] = {}
        for r in self.records:
            by_key.setdefault((r.entropy, r.spawn_key), set()).add(r.name)
        return [tuple(sorted(n)) for n in by_key.values() if len(n) > 1]


_LOGS: list[StreamLog] = []


@contextmanager
def recording():
    """Log every stream handed out inside the ``with`` block: ``with recording() as log: ...``,
    then ``log.records`` holds (name, entropy, spawn key) of each, ``log.shared()`` the names
    that shared a stream."""
    log = StreamLog()
    _LOGS.append(log)
    try:
        yield log
    finally:
        _LOGS.remove(log)


def _log(name: str, ss: np.random.SeedSequence) -> None:
    for log in _LOGS:
        log.add(name, ss)


def _log_child(parent: np.random.SeedSequence, name: str, ss: np.random.SeedSequence) -> None:
    for log in _LOGS:
        pname = log.name_of(parent) or f"<SeedSequence {parent.entropy} {tuple(parent.spawn_key)}>"
        log.add(f"{pname}/{name.split('/', 1)[1]}", ss)


def _check_words(name: str) -> None:
    for w in name.split("/"):
        if "{" not in w:
            word_key(w)


def _check_registry() -> None:
    """Every registered word has a distinct crc32 above :data:`MIN_WORD` (run at import)."""
    for name in list(STREAMS) + list(CHILD_STREAMS):
        _check_words(name)
    for name in STREAMS:
        if any(name.startswith(r + "/") for r in RUN_INDEXED):
            raise ConfigError(f"stream {name!r} extends a run-indexed name: make it a child of the run instead")


_check_registry()
