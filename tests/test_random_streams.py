"""Named random streams (imurig.kernel.random_streams): every stream of a flight run is its own,
one seed reproduces a campaign bit for bit, an unregistered name is refused."""
from __future__ import annotations

import zlib

import numpy as np
import pytest

from imurig.campaigns.tilt_table import TiltTableCampaign
from imurig.cli.main import main
from imurig.kernel import random_streams as R
from imurig.kernel.errors import ConfigError, ImurigError
from imurig.rigs.tilt_table import TiltTableProtocol
from imurig.sensors.noise import child_rng

# the flight job's reduced tilt-table protocol (imurig.campaigns.flight.calibrations, quick)
QUICK_TILT = TiltTableProtocol(theta_deg=(0, 30, 60, 90), phi_deg=(0, 90, 180, 270), dwell_s=3, settle_s=1,
                               remount_s=10, sample_rate_hz=200)


# ------------------------------------------------------------------ keys
def test_key_is_the_crc32_of_each_word_of_the_name():
    assert R.key("campaign/tilt-table/sensor-chain") == tuple(zlib.crc32(w.encode())
                                                              for w in ("campaign", "tilt-table", "sensor-chain"))
    assert R.key("montecarlo/run", run=7) == (zlib.crc32(b"montecarlo"), zlib.crc32(b"run"), 7)
    ss = R.seed_sequence("flight/sensor-chain", 2005)
    assert ss.entropy == 2005 and ss.spawn_key == R.key("flight/sensor-chain")
    # a child extends its parent's key by its own word: the key of the full name
    pump = R.child_seed_sequence(ss, "sensor-chain/pump")
    assert pump.spawn_key == (*R.key("flight/sensor-chain"), zlib.crc32(b"pump"))
    np.testing.assert_array_equal(child_rng(ss, "pump").random(4), np.random.default_rng(pump).random(4))


def test_the_lab_draws_keep_their_keys():
    """One seed's IMU, tilt table, survey, fluxgate installation and gyro tempcos are the draws they
    were before the registry: children crc32(word) of SeedSequence(seed)."""
    for w in ("sensor_errors", "table", "survey", "magnetometer_install", "gyro_thermal"):
        old = np.random.SeedSequence(entropy=2005, spawn_key=(zlib.crc32(w.encode()),))
        np.testing.assert_array_equal(R.generator(w, 2005).random(3), np.random.default_rng(old).random(3))


def test_registered_streams_are_pairwise_distinct():
    keys = [R.key(n, run=0 if n in R.RUN_INDEXED else None) for n in R.STREAMS]
    assert len(set(keys)) == len(keys)
    states = {tuple(R.seed_sequence(n, 1, run=0 if n in R.RUN_INDEXED else None).generate_state(4))
              for n in R.STREAMS}
    assert len(states) == len(R.STREAMS)
    assert all(d.strip() for d in list(R.STREAMS.values()) + list(R.CHILD_STREAMS.values()))


# ------------------------------------------------------------------ (1) a flight run
@pytest.fixture(scope="module")
def flight_run_streams(tmp_path_factory):
    """Every stream the `imurig flight` job hands out, at the shortest settings that still run each
    stage: the static tests (the MuJoCo flight draws no random numbers, so the default flight uses
    the same streams), 70 s, 5 Hz navigation, the quick tilt- and turn-table protocols, the
    magnetometer-rig tumble, the thermal campaign, both filter runs and the report."""
    out = tmp_path_factory.mktemp("flight") / "f"
    with R.recording() as log:
        assert main(["flight", "--flight", "static", "--duration", "70", "--nav-rate", "5", "--out", str(out)]) == 0
    assert (out / "summary.json").exists()
    return log


def test_all_streams_of_a_flight_run_are_distinct(flight_run_streams):
    log = flight_run_streams
    names = log.by_name()
    # every stage ran: the IMU, its flight, its GPS and every calibration campaign the job runs
    for n in ("sensor_errors", "flight/sensor-chain", "flight/gps", "flight/mag-rig/rig",
              "flight/mag-rig/sensor-chain", "table", "survey",
              "campaign/tilt-table/rig", "campaign/tilt-table/sensor-chain", "campaign/turn-table/rig",
              "campaign/turn-table/sensor-chain", "gyro_thermal", "campaign/thermal/sensor-chain",
              "flight/sensor-chain/gyros", "campaign/thermal/sensor-chain/gyros",
              "campaign/turn-table/sensor-chain/slip_gyro_p", "campaign/turn-table/sensor-chain/hp6700"):
        assert n in names, n
    # one name, one stream: the IMU's errors are deliberately the same unit in every campaign
    assert all(len(v) == 1 for v in names.values()), {k: v for k, v in names.items() if len(v) > 1}
    assert log.shared() == []
    # and the generators differ, not only the keys
    states = {n: tuple(np.random.SeedSequence(e, spawn_key=k).generate_state(4)) for n, ((e, k),) in names.items()}
    assert len(set(states.values())) == len(states)
    # the collision of issue 15: the flight's chain and the thermal campaign's chain of the same seed
    assert states["flight/sensor-chain/gyros"] != states["campaign/thermal/sensor-chain/gyros"]
    # (59: the tilt campaign's streamed chain hands out no stream to a stage that is off, as the flight
    # job's pump and people are; the whole-record chain made one for each and drew nothing from it)
    assert len(names) >= 59


# ------------------------------------------------------------------ (2) reproducible
def test_same_seed_gives_bit_identical_tilt_campaign():
    a = TiltTableCampaign(protocol=QUICK_TILT, seed=11).simulate()
    b = TiltTableCampaign(protocol=QUICK_TILT, seed=11).simulate()
    c = TiltTableCampaign(protocol=QUICK_TILT, seed=12).simulate()
    assert set(a.channels) == set(b.channels) and a.channels
    for k in a.channels:
        assert np.array_equal(a.channels[k], b.channels[k]), k
    for k in a.truth_signals:
        assert np.array_equal(a.truth_signals[k], b.truth_signals[k]), k
    assert not np.array_equal(a.channels["acc_x"], c.channels["acc_x"])


# ------------------------------------------------------------------ (3) refusals
def test_unregistered_names_are_refused():
    with pytest.raises(R.UnknownStreamError, match="no random stream named 'campaign/tilt-table/nope'"):
        R.generator("campaign/tilt-table/nope", 1)
    with pytest.raises(R.UnknownStreamError, match="no child stream named 'sensor-chain/laser'"):
        child_rng(R.seed_sequence("flight/sensor-chain", 1), "laser")
    with pytest.raises(R.UnknownStreamError, match="needs a run index"):
        R.seed_sequence("montecarlo/run", 1)
    with pytest.raises(R.UnknownStreamError, match="takes no run index"):
        R.seed_sequence("flight/gps", 1, run=3)
    with pytest.raises(ConfigError, match="master seed"):
        R.generator("flight/gps", -1)
    assert issubclass(R.UnknownStreamError, ConfigError) and issubclass(R.UnknownStreamError, ImurigError)


def test_register_adds_a_stream_and_refuses_a_clash(monkeypatch):
    monkeypatch.setattr(R, "CHILD_STREAMS", dict(R.CHILD_STREAMS))
    R.register("sensor-chain/laser_speckle", "a test stage", child=True)
    parent = R.seed_sequence("flight/sensor-chain", 3)
    assert R.child_seed_sequence(parent, "sensor-chain/laser_speckle").spawn_key[-1] == zlib.crc32(b"laser_speckle")
    with pytest.raises(ConfigError, match="already registered"):
        R.register("sensor-chain/pump", "something else", child=True)


def test_recording_logs_name_entropy_and_key():
    with R.recording() as log:
        ss = R.seed_sequence("campaign/magnetometer/sensor-chain", 9)
        child_rng(ss, "adc")
    assert [r.name for r in log.records] == ["campaign/magnetometer/sensor-chain",
                                            "campaign/magnetometer/sensor-chain/adc"]
    assert log.records[1].entropy == 9 and log.records[1].spawn_key == (*ss.spawn_key, zlib.crc32(b"adc"))
    with R.recording() as empty:
        pass
    R.generator("flight/gps", 1)
    assert empty.records == []
