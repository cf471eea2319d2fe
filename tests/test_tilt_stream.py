"""The streamed tilt-table campaign (imurig.campaigns.tilt_stream, imurig.sensors.stream): its HDF5 file,
its 100 Hz windows and its truth are what the whole-record tools make of the same record, bit for bit;
one seed gives one data set; its noise has the whole-record chain's size."""
from __future__ import annotations

import h5py
import numpy as np
import pytest

from imurig.calibration.preprocess import lowpass_downsample
from imurig.campaigns.tilt_stream import ANALYSED, stream_campaign
from imurig.campaigns.tilt_table import TiltTableCampaign
from imurig.kernel import random_streams
from imurig.kernel.h5stream import h5_info
from imurig.kernel.recording import load_h5, save_h5
from imurig.rigs.tilt_table import TiltTableProtocol
from imurig.sensors.effects import LooseCable
from imurig.sensors.stream import STREAM_CHUNK, _Cable
from h5_layout import assert_same_header_and_layout
from window_scatter import assert_same_window_scatter

# ~80k samples: two pieces, fast slews (MuJoCo rows at every sample) and a remount gap
SMALL = TiltTableProtocol(theta_deg=(0, 90), phi_deg=(0, 120, 240), dwell_s=1.0, settle_s=0.5, slew_rate_deg_s=30.0)


def _same(a, b):
    assert sorted(a.channels) == sorted(b.channels) and sorted(a.truth_signals) == sorted(b.truth_signals)
    assert np.array_equal(a.time_s, b.time_s)
    for k in a.channels:
        assert np.array_equal(a.channels[k], b.channels[k]), k
    for k in a.truth_signals:
        assert np.array_equal(a.truth_signals[k], b.truth_signals[k]), k
    assert a.units == b.units and a.truth_units == b.truth_units


@pytest.fixture(scope="module")
def streamed(tmp_path_factory):
    path = tmp_path_factory.mktemp("stream") / "recording.h5"
    camp = TiltTableCampaign(protocol=SMALL, model="linear", people=True)
    return camp, path, stream_campaign(camp, path, keep=True)


def test_streamed_record_spans_pieces_and_keeps_the_rig_truth(streamed):
    camp, _, s = streamed
    assert s.streamed and s.n > STREAM_CHUNK
    table, _, _ = camp.build()
    rig = table.simulate(camp.protocol, camp.start_time, random_streams.generator("campaign/tilt-table/rig", camp.seed))
    rec = s.recording
    assert np.array_equal(rec.time_s, rig.time_s)
    for k, v in rig.truth_signals.items():
        assert np.array_equal(rec.truth_signals[k], v), k
    for k, v in rig.channels.items():
        assert np.array_equal(rec.channels[k], v), k
    q = rec.meta["adc"]["lsb_V"]
    for k in camp.scan_list:   # converter output on its grid, as codes
        assert rec.channel_quantum[k] == q and np.array_equal(np.round(rec.channels[k] / q) * q, rec.channels[k])


def test_streamed_windows_equal_the_whole_record_filter(streamed):
    _, _, s = streamed
    ref = lowpass_downsample(s.recording, windows_only=True, filtered=ANALYSED)
    _same(s.rec100, ref)
    assert s.rec100.meta == ref.meta
    # only the analysed channels and truth are low-passed: the others are the 1 kHz samples at the 100 Hz
    # instants (a truth signal at rest over every padded window is unchanged by the filter: not checked)
    idx = np.searchsorted(s.recording.time_s, s.rec100.time_s)
    assert np.array_equal(s.recording.time_s[idx], s.rec100.time_s)
    for k in s.rec100.channels:
        same = np.array_equal(s.rec100.channels[k], s.recording.channels[k][idx])
        assert same == (k not in ANALYSED), k
    for k in s.rec100.truth_signals:
        if k not in ANALYSED:
            assert np.array_equal(s.rec100.truth_signals[k], s.recording.truth_signals[k][idx]), k
    assert any(not np.array_equal(s.rec100.truth_signals[k], s.recording.truth_signals[k][idx]) for k in ANALYSED
               if k in s.rec100.truth_signals)


def test_streamed_h5_is_what_save_h5_writes(streamed, tmp_path):
    _, path, s = streamed
    _same(load_h5(path), s.recording)
    save_h5(s.recording, tmp_path / "ref.h5")
    with h5py.File(path) as a, h5py.File(tmp_path / "ref.h5") as b:
        assert_same_header_and_layout(a, b)
        assert a["channels/acc_x"].compression == "gzip" and a["channels/acc_x"].shuffle
    assert h5_info(path)["samples"] == s.n


def test_simulate_is_the_streamed_record(streamed):
    """simulate() collects the streamed chain: the record the campaign streams, bit for bit, and its metadata."""
    camp, _, s = streamed
    rec = camp.simulate()
    _same(rec, s.recording)
    assert rec.channel_quantum == s.recording.channel_quantum
    assert rec.meta == s.recording.meta and rec.truth == s.recording.truth


def test_one_seed_one_data_set():
    camp = TiltTableCampaign(protocol=SMALL, model="linear", seed=7)
    a, b = (stream_campaign(camp, keep=True).recording for _ in range(2))
    _same(a, b)
    c = stream_campaign(TiltTableCampaign(protocol=SMALL, model="linear", seed=8), keep=True).recording
    assert not np.array_equal(a.channels["acc_x"], c.channels["acc_x"])


def test_streamed_noise_has_the_whole_chain_size(streamed):
    """Per channel, the scatter about each window's mean: the streamed and the whole-record chain draw
    different realisations of the same noise, so the pooled sd agree within 4 standard errors
    (sd of a pooled sd ~ sd / sqrt(2 N), the two independent)."""
    camp, _, s = streamed
    table, lab, ss = camp.build()
    whole = lab.measure(table.simulate(camp.protocol, camp.start_time,
                                       random_streams.generator("campaign/tilt-table/rig", camp.seed)), ss)
    assert_same_window_scatter(s.recording, whole, camp.scan_list)


def test_what_the_stream_does_not_model_runs_the_whole_chain():
    camp = TiltTableCampaign(protocol=SMALL, model="linear", start_time="2005-06-14T10:00:00+02:00")
    s = stream_campaign(camp)
    assert not s.streamed and "pump" in s.why
    _same(s.recording, camp.simulate())


def test_cable_spikes_stay_rectangles_across_pieces():
    """The streamed loose cable (pieces of 997 rows, spikes of 5-50 rows: most cross a boundary) is the
    sum of the rectangles a_e rect over [t_e, t_e + L_e) its draws define, placed on the whole record:
    the level and the steps past a piece's end carried (to the cumulative sum's rounding, 1e-12 V)."""
    eff = LooseCable(enabled=True, rate_hz=20.0)
    fs, n, m = 1000.0, 60_000, 997
    piecewise = _Cable(eff, fs, np.random.default_rng(4))
    v = np.concatenate([piecewise.rows(min(m, n - a)) for a in range(0, n, m)])
    rng, ref, events = np.random.default_rng(4), np.zeros(n), 0
    for a in range(0, n, m):
        starts = a + np.flatnonzero(rng.random(min(m, n - a)) < eff.rate_hz / fs)
        if starts.size:
            lengths = np.maximum(1, (rng.uniform(eff.min_duration_s, eff.max_duration_s, starts.size) * fs).astype(int))
            for t0, L, amp in zip(starts, lengths, rng.normal(0, eff.amplitude_V, starts.size)):
                ref[t0:t0 + L] += amp
            events += starts.size
    assert events > 1000 and np.abs(v - ref).max() < 1e-12


def test_streamed_cable_spikes_one_line_only():
    """A loose cable streams; only its line changes (every other stage keeps its stream), and its spike
    starts are Bernoulli(rate / f_s) per sample: their count within 4 sd of rate * T (Poisson)."""
    a = TiltTableCampaign(protocol=SMALL, model="linear", seed=4)
    b = TiltTableCampaign(protocol=SMALL, model="linear", seed=4, loose_cable=True)
    ra, rb = a.simulate(), stream_campaign(b, keep=True)
    assert rb.streamed
    rb = rb.recording
    for k in ra.channels:
        if k != b.build()[1].cable.channel:
            assert np.array_equal(ra.channels[k], rb.channels[k]), k
    d = rb.channels["acc_y"] != ra.channels["acc_y"]
    starts = int(np.count_nonzero(d[1:] & ~d[:-1]) + d[0])
    lam = b.build()[1].cable.rate_hz * ra.n / ra.sample_rate_hz
    assert abs(starts - lam) < 4 * np.sqrt(lam), (starts, lam)


class _Clock:
    """A record of ``hours`` at 1 Hz from ``start``: what _pump_on reads of a rig's run."""

    def __init__(self, start: str, hours: float):
        self.meta = {"start_time": start}
        self.n = int(hours * 3600)

    def time_rows(self, a, b):
        return np.arange(a, b, dtype=float)


@pytest.mark.parametrize("start, hours, on", [
    ("2005-06-14T18:00:00+02:00", 2.2, False),    # the seed's evening campaign: decided from its two ends
    ("2005-06-14T06:00:00+02:00", 1.0, False),    # before the working day
    ("2005-06-14T17:00:00+02:00", 2.0, True),     # into the last half hour of it
    ("2005-06-14T22:00:00+02:00", 4.0, False),    # across midnight, asleep: piece by piece
    ("2005-06-14T23:00:00+02:00", 9.0, True),     # across midnight into the morning
    ("2005-06-14T18:00:00+02:00", 30.0, True),    # longer than a day
])
def test_pump_hours_over_a_record(start, hours, on):
    from imurig.sensors.effects.building_vibration import PumpVibration
    from imurig.sensors.stream import _pump_on

    assert _pump_on(PumpVibration(), _Clock(start, hours)) is on
