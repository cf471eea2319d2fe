"""The lab's own effects in the streamed chain (imurig.sensors.stream_force, the converter's slow tail in
imurig.sensors.stream): piece by piece, the whole-record values; the "Delft 2005" lab streams."""
from __future__ import annotations

from functools import partial
from types import SimpleNamespace

import numpy as np
import pytest

from imurig.sensors.adc import DAQ6036E
from imurig.sensors.effects.air_conditioning import AirConditioningVibration
from imurig.sensors.effects.base import ChainContext
from imurig.sensors.effects.ship_passages import ShipPassages
from imurig.sensors.effects.transformer_hum import TransformerHum
from imurig.sensors.effects.vibration_rectification import VibrationRectification, rectified_offset
from imurig.sensors.effects.warm_up import WarmUp
from imurig.sensors.noise import band_noise, child_rng
from imurig.sensors.stream_force import LabForce, ever_on, rectification_margin, unsupported_effects

FS = 1000.0
#: 07:58:20 local: the record crosses the working hours' start (08:00) 100 s in
START_H = 7 + 58 / 60 + 20 / 3600


def _run(n: int, fs: float = FS, t0: float = 12.5):
    t = t0 + np.arange(n) / fs
    return SimpleNamespace(n=n, meta={"sample_rate_hz": fs}, time_rows=lambda a, b: t[a:b], t=t)


def _hours(t, t0=12.5, start_h=START_H):
    return (start_h + (np.asarray(t) - t0) / 3600.0) % 24.0


class _NoBase:
    rng = None


def _streamed(effects, run, seed, piece, start_h=START_H):
    hours = partial(_hours, start_h=start_h)
    force = LabForce(_NoBase(), effects, run, seed, hours, piece)
    out = [force.rows(hours(run.t[a:a + piece])) for a in range(0, run.n, piece)]
    return np.concatenate(out)


def _whole(effects, run, seed, start_h=START_H):
    ctx = ChainContext(time_s=run.t, sample_rate_hz=FS, hour_of_day=_hours(run.t, start_h=start_h),
                       truth_signals={}, adc=None, sensitivity_V_per_SI={})
    f = np.zeros((run.n, 3))
    for e in effects:
        f = e.inject(f, ctx, child_rng(seed, e.stream) if e.stream else None)
    return f


@pytest.mark.parametrize("piece, start_h", [(4096, START_H), (65536, START_H), (65536, 20.0)])
def test_the_additive_lab_effects_stream_to_the_whole_record_bit_for_bit(piece, start_h):
    """Air conditioning (its compressor cycling, working hours from 08:00; off all evening), transformer hum,
    ship passages (a high rate, so several cross a piece's edge) and the warm-up: the streamed rows,
    concatenated, are ImuLab.measure's specific-force stage over the whole record, to the bit."""
    run = _run(150_000)
    seed = np.random.SeedSequence(11)
    effects = [AirConditioningVibration(enabled=True, cycle_period_s=40.0),
               TransformerHum(enabled=True), ShipPassages(enabled=True, rate_per_hour=200.0, start_h=0.0,
                                                          stop_h=24.0),
               WarmUp.from_datasheet()]
    got = _streamed(effects, run, seed, piece, start_h)
    want = _whole(effects, run, seed, start_h)
    assert np.any(got[:90_000]) and np.any(got[110_000:])
    np.testing.assert_array_equal(got, want)
    # the day's sources matter by day only: without the hum the rows differ after 08:00, not in the evening
    no_hum = _streamed([e for e in effects if e.name != "transformer_hum"], run, seed, piece, start_h)
    assert np.array_equal(no_hum, want) == (start_h >= 18.0)


def test_ever_on_meets_the_working_hours_across_midnight():
    assert ever_on(7.9, 0.2, 8.0, 18.0) and not ever_on(7.0, 0.9, 8.0, 18.0)
    assert ever_on(23.0, 10.0, 8.0, 18.0) and not ever_on(18.5, 13.0, 8.0, 18.0)
    assert ever_on(17.9, 0.05, 8.0, 18.0) and not ever_on(18.0, 0.05, 8.0, 18.0)


def test_the_rectification_streams_within_its_band_pass_margin():
    """The rectified offset of a piece from its rows with rectification_margin rows of context each side
    against the whole record's FFT band-pass: the band-pass's impulse response leaves out a share
    s = 1 / (pi^2 T_M Delta f) of the band's energy beyond T_M = 32 s (Delta f = 150 Hz: s = 2.1e-5). In a
    window's mean square the error is s plus a cross term of sd 2 sqrt(s) / sqrt(2 Delta f W) (W = 1 s:
    300 independent values; 5.3e-4). The largest of the ~340 windows' errors is bounded at s + 4 sd.
    Away from the record's two ends, where the whole record's circular FFT wraps its end onto its start."""
    n = 400_000
    run = _run(n)
    rect = VibrationRectification.from_datasheet()
    vib = band_noise(np.random.default_rng(3), (n, 3), FS, (20.0, 400.0), 0.05)

    class _Base:
        rng = True
        pos = 0

        def rows(self, hour):
            a = self.pos
            self.pos += hour.size
            return vib[a:self.pos].copy()

    force = LabForce(_Base(), [rect], run, np.random.SeedSequence(1), _hours, 65536)
    got = np.concatenate([force.rows(_hours(run.t[a:a + 65536])) for a in range(0, n, 65536)]) - vib
    want = rectified_offset(vib, FS, rect.coeff_per_m_s2, rect.bands_hz, rect.window_s)
    M = rectification_margin(FS, rect.window_s)
    inner = slice(M, n - M)
    share = 1 / (np.pi**2 * 32.0 * 150.0)
    bound = share + 4 * 2 * np.sqrt(share) / np.sqrt(2 * 150.0 * 1.0)
    rel = np.max(np.abs(got[inner] - want[inner]) / np.abs(want[inner]))
    assert 0 < rel < bound, (rel, bound)
    # with 1 s of context instead, the band-pass's tail shows (the bound can fail)
    short = LabForce(_Base(), [rect], run, np.random.SeedSequence(1), _hours, 65536)
    short.margin = int(FS)
    _Base.pos = 0
    got1 = np.concatenate([short.rows(_hours(run.t[a:a + 65536])) for a in range(0, n, 65536)]) - vib
    assert np.max(np.abs(got1[inner] - want[inner]) / np.abs(want[inner])) > rel


def test_the_slow_tail_of_a_piece_is_the_whole_records_rows():
    """The converter's slow settling tail r_j is row-local but for the idle input, the previous scan's last
    slot: with the previous piece's last input as ``idle_first``, pieces give the whole record's r."""
    adc = DAQ6036E(scan_list=("acc_x", "acc_y", "acc_z", "temp_box"), channel_slow_settling={"acc_y": (0.01, 2e-3)})
    rng = np.random.default_rng(5)
    n = 10_000
    analog = {c: rng.normal(size=n) for c in adc.scan_list}
    common = rng.normal(size=n) * 1e-3
    want = adc.slow_tails(analog, common)["acc_y"][1]
    parts, idle = [], None
    for a in range(0, n, 3001):
        b = min(n, a + 3001)
        parts.append(adc.slow_tails({c: v[a:b] for c, v in analog.items()}, common[a:b], idle)["acc_y"][1])
        idle = analog["temp_box"][b - 1] + common[b - 1]
    np.testing.assert_array_equal(np.concatenate(parts), want)


def test_the_delft_2005_lab_streams_and_names_what_does_not():
    """The preset's effects stream (a short protocol); its persistent cable fault (analog stage) does not,
    and the reason names it."""
    from imurig.campaigns.delft_2005 import Delft2005
    from imurig.campaigns.tilt_stream import stream_campaign
    from imurig.campaigns.tilt_table import TiltTableCampaign
    from imurig.rigs.tilt_table import TiltTableProtocol

    camp = TiltTableCampaign(protocol=TiltTableProtocol(theta_deg=(0, 60), phi_deg=(0, 120, 240), dwell_s=2.0),
                             lab="delft-2005")
    res = stream_campaign(camp)
    assert res.streamed and res.why is None
    eff = set(res.truth["chain"]["effects"])
    assert {"air_conditioning_vibration", "transformer_hum", "ship_passages", "warm_up",
            "vibration_rectification"} <= eff
    assert unsupported_effects(Delft2005.fitted().effects(cable_fault=True)) == ["persistent_cable_fault"]


def test_the_scale_wander_streams_as_one_gauss_markov_recursion():
    """The gyros' scale wander piece by piece: s[0] ~ N(0, sigma^2) and then s[k+1] = phi s[k] + drive[k]
    with the recursion's state carried, equal to one lfilter over the same draws to rounding (8 eps of
    sigma: the carried state is the same recursion; plus eps / 2 where s is read back from the line's
    V (1 + s) with V = 1); its sd and lag-1 correlation are the process's (sd of
    the sample sd ~ sigma sqrt(tau fs / n) for a process correlated over tau fs samples)."""
    from scipy import signal

    from imurig.sensors.effects.gyro_scale_instability import GyroScaleInstability
    from imurig.sensors.stream_force import LabLines

    e = GyroScaleInstability(enabled=True, sigma=2e-4, tau_s=0.5)
    seed = np.random.SeedSequence(4)
    lines = LabLines([e], ["gyro_p", "acc_x", "gyro_r"], seed, FS)
    assert [ln for ln, _ in lines.parts] == ["gyro_p", "gyro_r"]
    n, piece = 400_000, 65536
    v = {"gyro_p": np.ones(n), "acc_x": np.ones(n), "gyro_r": np.full(n, 2.0)}
    out = {k: [] for k in v}
    for a in range(0, n, piece):
        cols = {k: x[a:a + piece].copy() for k, x in v.items()}
        lines.add(cols)
        for k in v:
            out[k].append(cols[k])
    s = np.concatenate(out["gyro_p"]) - 1.0
    assert np.array_equal(np.concatenate(out["acc_x"]), v["acc_x"])
    rng = child_rng(seed, e.line_stream("gyro_p"))
    phi = np.exp(-1 / (e.tau_s * FS))
    s0 = rng.standard_normal() * e.sigma
    drive = np.concatenate([rng.standard_normal(min(piece, n - a)) for a in range(0, n, piece)]) \
        * e.sigma * np.sqrt(1 - phi**2)
    drive[0] = s0
    eps = np.finfo(float).eps
    assert np.max(np.abs(s - signal.lfilter([1.0], [1.0, -phi], drive))) <= 8 * eps * e.sigma + eps / 2
    assert abs(s.std() / e.sigma - 1) < 4 * np.sqrt(e.tau_s * FS / n)
    assert abs(np.corrcoef(s[:-1], s[1:])[0, 1] - phi) < 1e-3
