"""The streamed turn-table campaign (imurig.campaigns.turn_stream): the rig's rows on demand are the simulated
rig's, bit for bit; the HDF5 file is what save_h5 writes of the collected record; the gyro fit on the acquisition
windows' rows and the .rrd's 10 Hz means are the whole record's, bit for bit; one seed gives one data set; the
streamed noise has the whole-record chain's size."""
from __future__ import annotations

import pickle

import h5py
import numpy as np
import pytest

from imurig.campaigns.turn_stream import _merged, stream_campaign
from imurig.campaigns.turn_table import TurnTableCampaign
from imurig.kernel import random_streams
from imurig.kernel.recording import load_h5, save_h5
from imurig.reports.turn_table import analyse
from imurig.reports.turn_table_rrd import block_means, calibrated_block_means
from imurig.rigs.turn_table import TurnTable, TurnTableProtocol
from imurig.sensors.stream import STREAM_CHUNK
from h5_layout import assert_same_header_and_layout
from window_scatter import assert_same_window_scatter

# ~177k samples: three pieces, ramps (MuJoCo rows), holds (closed form) and two remount gaps
SMALL = TurnTableProtocol(dial_rates_dps=(40, 100), min_window_s=2.0, settle_s=1.0)


@pytest.fixture(scope="module")
def streamed(tmp_path_factory):
    path = tmp_path_factory.mktemp("turn") / "recording.h5"
    camp = TurnTableCampaign(protocol=SMALL, seed=3)
    return camp, path, stream_campaign(camp, path, keep=True)


def test_run_rows_in_any_pieces_are_the_simulated_rig():
    table = TurnTable()
    args = (SMALL, "2005-06-15T18:00:00+02:00")
    rig = table.simulate(*args, random_streams.generator("campaign/turn-table/rig", 3))
    run = table.run(*args, random_streams.generator("campaign/turn-table/rig", 3))
    cuts = list(range(0, run.n, 9973)) + [run.n]
    for name, rows, whole in (("time", run.time_rows, lambda: rig.time_s),):
        assert np.array_equal(np.concatenate([rows(a, b) for a, b in zip(cuts, cuts[1:])]), whole())
    pieces = [run.truth_rows(a, b) for a, b in zip(cuts, cuts[1:])]
    for k, v in rig.truth_signals.items():
        assert np.array_equal(np.concatenate([p[k] for p in pieces]), v), k
    assert np.array_equal(np.concatenate([run.channel_rows(a, b)["rate_dial"] for a, b in zip(cuts, cuts[1:])]),
                          rig.channels["rate_dial"])
    for k, v in rig.events.items():
        assert np.array_equal(run.events[k], v), k
    assert run.meta == rig.meta and run.truth == rig.truth


def test_streamed_h5_is_what_save_h5_writes(streamed, tmp_path):
    _, path, s = streamed
    rec = s.recording
    assert s.streamed and s.n > 2 * STREAM_CHUNK
    back = load_h5(path)
    assert np.array_equal(back.time_s, rec.time_s)
    for group in ("channels", "truth_signals", "events", "segments"):
        a, b = getattr(back, group), getattr(rec, group)
        assert sorted(a) == sorted(b), group
        for k in b:
            assert np.array_equal(a[k], b[k]), (group, k)
    save_h5(rec, tmp_path / "ref.h5")
    with h5py.File(path) as a, h5py.File(tmp_path / "ref.h5") as b:
        assert_same_header_and_layout(a, b)


@pytest.mark.parametrize("timer", ["hp6700", "adc"])
def test_fit_on_the_windows_is_the_whole_records(streamed, timer):
    """The gyro fit (estimates, standard errors, residuals) on the acquisition windows' rows equals the fit on the
    whole collected record, bit for bit (the same rows, the same volts, the same blocks)."""
    s = streamed[2] if timer == "hp6700" else stream_campaign(TurnTableCampaign(protocol=SMALL, seed=3, timer=timer),
                                                               keep=True)
    assert s.rec.n < s.recording.n
    a, b = analyse(s.recording, timer), analyse(s.rec, timer)
    assert a["parameters"] == b["parameters"]
    for ax in "pqr":
        assert np.array_equal(a["main"].results_[ax].residuals_, b["main"].results_[ax].residuals_)
        assert np.array_equal(a["seed_final"].results_[ax].coef_, b["seed_final"].results_[ax].coef_)


def test_rrd_rows_and_figure_window_are_the_whole_records(streamed):
    """The .rrd's rows, also after a pickle round trip (the report sends them to the process that writes the
    .rrd), are the whole record's."""
    _, _, s = streamed
    rec = s.recording
    sent = pickle.loads(pickle.dumps(s.rows))
    t, raw = block_means(rec, ["gyro_p", "gyro_q", "gyro_r"], 100)
    cal = analyse(rec)["main"]
    c = calibrated_block_means(rec, cal, 100)
    idx = np.concatenate([np.arange(b.start, b.stop, 100) for b in rec.blocks()])
    for rows in (s.rows, sent):
        t2, raw2 = block_means(rows, ["gyro_p", "gyro_q", "gyro_r"], 100)
        assert np.array_equal(t, t2) and all(np.array_equal(raw[k], raw2[k]) for k in raw)
        c2 = calibrated_block_means(rows, cal, 100)
        assert all(np.array_equal(c[k], c2[k]) for k in c)
        assert np.array_equal(rows.spin_at(idx), rec.truth_signals["spin_angle"][idx])
    i = int(np.argmax(np.abs(rec.segments["rate_dial"])))
    sl = rec.segment_slices()[i]
    assert np.array_equal(s.fig.channels["temp_box"], rec.channels["temp_box"][sl])
    assert np.array_equal(s.fig.truth_signals["spin_angle"], rec.truth_signals["spin_angle"][sl])


def test_window_ranges_are_the_rows_any_span_covers():
    """The acquisition windows' row ranges (:func:`_merged`): exactly the rows some span [a, b) covers, as
    maximal runs (spans that overlap or meet joined), against a row-by-row count."""
    rng = np.random.default_rng(7)
    for _ in range(500):
        n = int(rng.integers(5, 300))
        a = rng.integers(0, n, int(rng.integers(1, 9)))
        b = np.minimum(a + rng.integers(0, 40, a.size), n)
        covered = np.zeros(n + 2, bool)
        for x, y in zip(a, b):
            covered[x + 1:y + 1] = True
        edges = np.flatnonzero(np.diff(covered.astype(np.int8)))
        assert _merged(zip(a, b)) == [(int(x), int(y)) for x, y in zip(edges[::2], edges[1::2])]


def test_one_seed_one_data_set(streamed):
    camp, _, s = streamed
    a, b = s.recording, stream_campaign(camp, keep=True).recording
    for k in a.channels:
        assert np.array_equal(a.channels[k], b.channels[k]), k
    c = stream_campaign(TurnTableCampaign(protocol=SMALL, seed=8), keep=True).recording
    assert not np.array_equal(a.channels["gyro_p"], c.channels["gyro_p"])


def test_simulate_gives_the_commands_data(streamed):
    """The Python API's simulate() runs the command's streamed chain: the same seed, the same data, bit for
    bit (channels, truth signals, events); the whole-record chain draws another realisation."""
    camp, _, s = streamed
    a, b = camp.simulate(), s.recording
    assert set(a.channels) == set(b.channels) and set(a.truth_signals) == set(b.truth_signals)
    assert all(np.array_equal(a.channels[k], b.channels[k]) for k in a.channels)
    assert all(np.array_equal(a.truth_signals[k], b.truth_signals[k]) for k in a.truth_signals)
    assert all(np.array_equal(a.events[k], b.events[k]) for k in a.events) and a.truth == b.truth
    assert not np.array_equal(camp.simulate(chain="whole").channels["gyro_p"], a.channels["gyro_p"])


def test_streamed_noise_has_the_whole_chain_size(streamed):
    """Per channel, the scatter about each window's mean: the streamed and the whole-record chain draw different
    realisations of the same noise (gyro rate noise, current noise, slip rings, converter), so the pooled sd agree
    within 4 standard errors (sd of a pooled sd ~ sd / sqrt(2 N), the two independent)."""
    camp, _, s = streamed
    whole = camp.simulate(chain="whole")
    # the same metadata and truth, but for the count of clipped samples (the 5 V pulse at the converter's top)
    ma, mb = (dict(r.meta, adc={k: v for k, v in r.meta["adc"].items() if k != "saturated_samples"})
              for r in (whole, s.recording))
    assert ma == mb and whole.truth == s.recording.truth
    assert set(s.recording.meta["adc"]["saturated_samples"]) == {"pulse"}
    assert_same_window_scatter(s.recording, whole, ("gyro_p", "gyro_q", "gyro_r", "acc_x", "acc_z", "temp_box"))


def test_delft_lab_streams_its_scale_wander_and_says_so_to_the_fit():
    """The Delft 2005 preset's own effect on the turn table, the gyros' scale instability, streams; the
    record's noise model states it (the GLS fit weighs the steps by it), in the streamed and the whole-record
    chain alike; the gyro lines' scatter about each window's mean agrees with the whole chain's within 4
    standard errors (different realisations of the same noise)."""
    camp = TurnTableCampaign(protocol=SMALL, seed=3, lab="delft-2005")
    s = stream_campaign(camp, keep=True)
    assert s.streamed and s.why is None
    whole = camp.simulate(chain="whole")
    for rec in (s.recording, whole):
        assert rec.meta["gyro_noise_model"]["scale_instability"] == camp.build()[1].effects[0].sigma > 0
    assert_same_window_scatter(s.recording, whole, ("gyro_p", "gyro_q", "gyro_r"))
