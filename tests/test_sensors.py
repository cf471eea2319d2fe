"""Sensor-chain stages against closed forms: Q-Flex equation, ADC crosstalk, grounding,
quantisation, anti-alias filter, band-limited noise and its folding, temperature sensor, and the
chain's composition of effects per stage."""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np
import pytest

from imurig.calibration.preprocess import lowpass_downsample
from imurig.kernel import random_streams
from imurig.kernel.errors import ConfigError
from imurig.kernel.recording import Recording
from imurig.sensors.accelerometer import CurrentTemperatureSensor, QFlexTriad
from imurig.sensors.adc import DAQ6036E
from imurig.sensors.chain import DEFAULT_SCAN, ImuLab, _gradient_rows
from imurig.sensors.effects import AdcCrosstalk, Effect
from imurig.sensors.noise import add_band_noise, band_noise, band_power_gain, sampled_bands, window_mean_variance
from imurig.kernel.units import G_STANDARD

FS = 1000.0


def test_qflex_measurement_equation_closed_form():
    M = np.array([[0, 1e-3, -2e-3], [5e-4, 0, 1e-3], [-1e-3, 2e-3, 0]])
    acc = QFlexTriad(bias_m_s2=[0.01, -0.02, 0.03], k1_A_per_m_s2=np.array([1.30, 1.33, 1.36]) * 1e-3 / G_STANDARD,
                     misalignment_rad=M, k2_per_m_s2=[4e-6, -3e-6, 2e-6], load_resistor_ohm=750.0)
    f = np.array([[1.0, -9.0, 3.0], [0.0, 0.0, 9.81]])
    a = f @ (np.eye(3) + M).T
    expect = 750.0 * acc.k1_A_per_m_s2 * (a + acc.bias_m_s2 + acc.k2_per_m_s2 * a**2)
    np.testing.assert_allclose(acc.ideal_voltage(f), expect, rtol=1e-15, atol=1e-16)
    # datasheet nominal: 1.33 mA/g over 750 ohm is 0.9975 V per g
    assert QFlexTriad.from_datasheet().nominal_sensitivity_V_per_m_s2()[0] * G_STANDARD == pytest.approx(0.9975)


def test_temperature_sensor_datasheet_point():
    s = CurrentTemperatureSensor(noise_V_rms=0.0)
    v = s.voltage(np.array([298.15, 308.15]), np.random.default_rng(0))
    np.testing.assert_allclose(v, [2.982, 3.082], rtol=1e-12)  # 1 uA/K over 10 kohm: 0.1 V per 10 K
    np.testing.assert_allclose(s.temperature_K(v), [298.15, 308.15], rtol=1e-12)


def _quiet_adc(**kw):
    kw.setdefault("input_noise_lsb_rms", 0.0)
    kw.setdefault("common_mode_noise_V_rms", 0.0)
    kw.setdefault("skew_enabled", False)
    return DAQ6036E(**kw)


@pytest.mark.parametrize("f_mux", [200e3, 50e3, 20e3])
def test_crosstalk_is_settling_residual_of_previous_channel(f_mux):
    n = 2000
    t = np.arange(n) / FS
    analog = {"a": np.full(n, 4.0), "b": np.full(n, 1.0)}
    adc = _quiet_adc(scan_list=("a", "b"), mux_frequency_hz=f_mux)
    out, rep = adc.convert(analog, t, np.random.default_rng(0))
    c = np.exp(-1 / (f_mux * 0.59e-6))
    assert rep["crosstalk_coefficient"] == pytest.approx(c, rel=1e-12)
    expect_b = np.round((1.0 + c * 3.0) / adc.lsb_V) * adc.lsb_V
    assert np.all(out["b"] == expect_b)
    # slot 0 follows slot 1 of the previous scan
    expect_a = np.round((4.0 + c * (1.0 - 4.0)) / adc.lsb_V) * adc.lsb_V
    assert np.all(out["a"][1:] == expect_a)


def test_quantisation_is_16_bit_over_the_range():
    adc = _quiet_adc(scan_list=("a",), range_V=5.0, crosstalk_enabled=False)
    x = np.linspace(-6, 6, 10001)
    out, rep = adc.convert({"a": x}, np.arange(x.size) / FS, np.random.default_rng(0))
    q = 10.0 / 65536
    assert rep["lsb_V"] == q
    inside = np.abs(x) < 4.99
    assert np.max(np.abs(out["a"][inside] - x[inside])) <= q / 2 + 1e-15
    assert out["a"].max() == 32767 * q and out["a"].min() == -32768 * q
    assert rep["saturated_samples"]["a"] > 0


def test_grounding_ground_loop_and_common_mode():
    """GRSE adds the 50 Hz ground loop (seed 3.4); NRSE does not; DIFF rejects common mode."""
    n = 20000
    t = np.arange(n) / FS
    x = {"a": np.zeros(n)}
    amp = {}
    for g in ("GRSE", "NRSE", "DIFF"):
        adc = DAQ6036E(scan_list=("a",), grounding=g, input_noise_lsb_rms=0.0, range_V=0.5,
                       common_mode_noise_V_rms=100e-6, ground_loop_V=2e-3)
        v = adc.convert(x, t, np.random.default_rng(1))[0]["a"]
        amp[g] = 2 * np.abs(np.mean(v * np.exp(-2j * np.pi * 50.0 * t)))
        if g == "DIFF":
            assert np.std(v) < adc.lsb_V  # only quantisation of zero is left
        else:
            assert np.std(v) > 50e-6
    # 50 Hz amplitude estimate; its noise is 100 uV * sqrt(2/n) ~ 1 uV
    assert amp["GRSE"] == pytest.approx(2e-3, abs=10e-6)
    assert amp["NRSE"] < 10e-6


def test_scan_too_slow_and_bad_settings_refused():
    from imurig.kernel.errors import ConfigError

    with pytest.raises(ConfigError, match="input ranges"):
        _quiet_adc(scan_list=("a",), range_V=3.0).validate()
    with pytest.raises(ConfigError, match="8 differential"):
        _quiet_adc(scan_list=tuple("abcdefghi"), grounding="DIFF").validate()
    with pytest.raises(ConfigError, match="grounding"):
        _quiet_adc(scan_list=("a",), grounding="floating").validate()


@pytest.mark.parametrize("band", [(0.0, 10.0), (10.0, 490.0), (20.0, 40.0)])
def test_band_noise_has_requested_rms_and_band(band):
    rng = np.random.default_rng(4)
    n = 200_000
    x = band_noise(rng, (n, 2), FS, band, 3.0)
    # rms of a long coloured series: allow 5 % (the effective number of independent samples
    # for a 10 Hz band over 200 s is ~4000, so the relative std of the rms is ~1 %)
    np.testing.assert_allclose(np.sqrt(np.mean(x**2, axis=0)), 3.0, rtol=0.05)
    spec = np.abs(np.fft.rfft(x[:, 0])) ** 2
    f = np.fft.rfftfreq(n, 1 / FS)
    inband = (f >= band[0]) & (f <= band[1])
    assert spec[inband].sum() / spec.sum() > 0.9


def test_antialias_filter_matches_butterworth_response():
    """sosfiltfilt applies |H(f)|^2 of the 5th-order 50 Hz Butterworth: at 50 Hz a tone keeps
    half its amplitude (-3 dB twice), at 10 Hz essentially all."""
    t = np.arange(20000) / FS
    for f0, gain in ((10.0, 1.0 / (1 + (10 / 50) ** 10)), (50.0, 0.5)):
        rec = Recording(time_s=t, channels={"a": np.sin(2 * np.pi * f0 * t)}, units={"a": "V"}, meta={})
        out = lowpass_downsample(rec, rate_hz=500.0)  # keep 50 Hz below the new Nyquist
        y = out.channels["a"][200:-200]
        tt = out.time_s[200:-200]
        a = 2 * np.abs(np.mean(y * np.exp(-2j * np.pi * f0 * tt)))
        assert a == pytest.approx(gain, rel=2e-3)


def test_downsample_to_a_rate_without_a_whole_ratio_keeps_every_kth_sample():
    """fs / rate not whole: every k-th sample, k = floor(fs / rate), so the rate reached is the
    nearest at or above the one asked for (any logger rate goes in)."""
    n = 2000
    t = np.arange(n) / FS
    rec = Recording(time_s=t, channels={"a": np.zeros(n)}, units={"a": "V"}, meta={})
    out = lowpass_downsample(rec, rate_hz=300.0, cutoff_hz=100.0)
    k = int(np.floor(FS / 300.0))
    np.testing.assert_array_equal(out.time_s, t[::k])


# ------------------------------------------------------------------ noise-band folding
def test_sampled_bands_fold_and_average():
    """Direct sampling aliases a band above f_s/2 to white of its full rms and cuts a band across
    f_s/2 at f_s/2; averaged logging drops the first and keeps the second's in-band power share."""
    bands = ((0.0, 10.0, 1.0), (10.0, 500.0, 2.0), (500.0, 10e3, 3.0), (0.0, 5.0, 0.0))
    assert sampled_bands(bands, 100.0) == [(0.0, 10.0, 1.0), (10.0, 50.0, 2.0), (0.0, 50.0, 3.0)]
    av = sampled_bands(bands, 100.0, averaged=True)
    assert av[:1] == [(0.0, 10.0, 1.0)] and len(av) == 2
    assert av[1][:2] == (10.0, 50.0) and av[1][2] == pytest.approx(2.0 * np.sqrt(40.0 / 490.0), rel=1e-15)


def test_window_mean_variance_of_low_pass_noise():
    """The variance of N-sample window means of band_noise (0-10 Hz at 100 Hz) is rms^2 / (g^2 N)
    (long-window limit) within 4.5 standard errors; white noise gives rms^2 / N; a band above DC none."""
    fs, N, n_win = 100.0, 1000, 2000
    x = band_noise(np.random.default_rng(4), (N * n_win,), fs, (0.0, 10.0), 2.0)
    m = x.reshape(n_win, N).mean(axis=1)
    v = window_mean_variance(((0.0, 10.0, 2.0),), fs, N)
    assert v == pytest.approx(4.0 / (band_power_gain(fs, (0.0, 10.0)) * N), rel=1e-15)
    assert abs(np.mean(m**2) - v) < 4.5 * np.std(m**2, ddof=1) / np.sqrt(n_win)
    assert window_mean_variance(((0.0, 500.0, 2.0),), fs, N) == pytest.approx(4.0 / N, rel=1e-15)
    assert window_mean_variance(((10.0, 40.0, 2.0),), fs, N) == 0.0


# ------------------------------------------------------------------ the chain composes effects
def _still_rig(n=3000, fs=100.0, start="2005-06-14T10:00:00+02:00"):
    t = np.arange(n) / fs
    ts = {f"f_C_{a}": np.full(n, v) for a, v in zip("xyz", (0.1, -0.2, 9.81))}
    ts |= {f"B_C_{a}": np.full(n, v) for a, v in zip("xyz", (18e-6, 1e-6, 45e-6))}
    ts |= {f"w_C_{a}": np.zeros(n) for a in "xyz"}
    return Recording(time_s=t, channels={}, units={}, truth_signals=ts,
                     meta={"sample_rate_hz": fs, "start_time": start})


# a new effect with its own random stream registers it (imurig.kernel.random_streams)
random_streams.register("sensor-chain/test_hum", "the test effect's hum phase", child=True)


@dataclass
class Hum(Effect):
    """A test effect: a 7 Hz hum on mag_x (V)."""

    amplitude_V: float = 1e-3
    name: ClassVar[str] = "test_hum"
    stage: ClassVar[str] = "analog"
    stream: ClassVar[str] = "test_hum"

    def lines(self, names, ctx):
        return ["mag_x"]

    def inject(self, v, ctx, rng):
        return v + self.amplitude_V * np.sin(2 * np.pi * 7.0 * ctx.time_s + rng.uniform(0, 2 * np.pi))


def test_chain_stages_compose_the_labs_effects():
    """The named disturbances and the lab's own effects act at their stages; an extra analog
    effect changes its own line only (its own random stream), every other channel bit for bit;
    a conversion or sensor effect is refused as a lab effect."""
    lab = ImuLab(adc=DAQ6036E(scan_list=DEFAULT_SCAN, sample_rate_hz=100.0))
    assert lab.stage_effects("specific_force") == [lab.pump, lab.people]
    assert lab.stage_effects("analog") == [lab.slip_rings, lab.cable]
    assert [e.name for e in lab.stage_effects("conversion")] == ["channel_skew", "adc_crosstalk"]
    rig = _still_rig()
    seed = np.random.SeedSequence(5)
    a = lab.measure(rig, seed)
    hum = Hum()
    b = replace(lab, effects=(hum,)).measure(rig, seed)
    assert replace(lab, effects=(hum,)).stage_effects("analog") == [lab.slip_rings, lab.cable, hum]
    assert "f_dist_C_x" in a.truth_signals and "effects" not in a.truth["chain"]    # the pump is on by day
    assert b.truth["chain"]["effects"] == {"test_hum": {"amplitude_V": 1e-3}}
    for k in a.channels:
        assert np.array_equal(a.channels[k], b.channels[k]) == (k != "mag_x"), k
    with pytest.raises(ConfigError, match="converter"):
        ImuLab(effects=(AdcCrosstalk(),))


def test_converter_consuming_its_lines_gives_the_same_codes_and_frees_them():
    """``consume=True`` (the chain's bounded-memory mode) converts to the same volts, bit for bit,
    and leaves none of the scanned lines (nor their slopes) in the caller's dicts."""
    n = 3000
    t = np.arange(n) / FS
    rng = np.random.default_rng(5)
    lines = {k: rng.normal(0, 1, n) for k in ("a", "b", "c")}
    slope = {k: rng.normal(0, 50, n) for k in ("a", "c")}
    adc = DAQ6036E(scan_list=("a", "b", "c"))
    ref, rep_ref = adc.convert(dict(lines), t, np.random.default_rng(9), dict(slope))
    an, sl = dict(lines), dict(slope)
    out, rep = adc.convert(an, t, np.random.default_rng(9), sl, consume=True)
    assert an == {} and sl == {}
    assert rep == rep_ref
    for k in ref:
        np.testing.assert_array_equal(out[k], ref[k])


@pytest.mark.parametrize("ground_between", [False, True])
def test_converter_in_row_pieces_equals_one_piece(monkeypatch, ground_between):
    """The converter's row pieces (skew, crosstalk from the previous slot across a piece's edge and
    from the last channel into the first, noise drawn piece by piece) give the volts of one piece,
    bit for bit."""
    import imurig.sensors.adc as adc_mod
    n = 5003
    t = np.arange(n) / FS
    rng = np.random.default_rng(5)
    lines = {k: rng.normal(0, 1, n) for k in ("a", "b", "c")}
    slope = {k: rng.normal(0, 50, n) for k in ("a", "c")}
    adc = DAQ6036E(scan_list=("a", "b", "c"), ground_between=ground_between, mux_frequency_hz=200e3)
    assert adc.crosstalk_coefficient() > 0
    whole, rep_w = adc.convert(dict(lines), t, np.random.default_rng(9), dict(slope))
    monkeypatch.setattr(adc_mod, "ROW_CHUNK", 777)
    pieces, rep_p = adc.convert(dict(lines), t, np.random.default_rng(9), dict(slope))
    assert rep_p == rep_w
    for k in whole:
        np.testing.assert_array_equal(pieces[k], whole[k])


@pytest.mark.parametrize("band", [(0.0, 10.0), (10.0, 300.0), (200.0, 500.0), (0.0, 500.0)])
def test_band_noise_in_row_pieces_equals_one_draw(band):
    """add_band_noise (white draws piece by piece, the shaping filter's state carried) adds the
    values of one band_noise draw, bit for bit."""
    ref = band_noise(np.random.default_rng(3), (10_001, 3), FS, band, np.array([1.0, 2.0, 0.5]))
    out = np.zeros((10_001, 3))
    add_band_noise(out, np.random.default_rng(3), FS, band, np.array([1.0, 2.0, 0.5]), chunk=999)
    np.testing.assert_array_equal(out, ref)


def test_sensor_slopes_in_pieces_equal_the_whole_gradient():
    """The chain's piecewise time derivative equals numpy's over the whole record, bit for bit,
    on an uneven clock and for pieces of any size."""
    rng = np.random.default_rng(1)
    t = np.cumsum(rng.uniform(0.5e-3, 1.5e-3, 5003))
    v = rng.standard_normal((t.size, 3))
    for chunk in (2, 7, 1000, 5002):
        np.testing.assert_array_equal(_gradient_rows(v, t, chunk), np.gradient(v, t, axis=0))
