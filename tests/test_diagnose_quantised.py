"""The diagnosis' tests on quantised data, from small numpy-made records (not imurig's simulator):
the ADC step estimate, the noise floor q / sqrt(12) and the spike test on the quantised scale."""
from __future__ import annotations

import numpy as np
import pytest

from imurig.sensors.effects import ScatterView
from imurig.sensors.effects.adc_quantisation import estimate_step, step_of
from imurig.sensors.effects.cable_fault_spikes import LooseCable

Q16 = 10.0 / 2**16          # a 16-bit +-5 V converter's step (V)


def _positions(rng, fs, m=12, seconds=20.0, sigma_V=0.2 * Q16, q=Q16):
    """m static positions of a quantised channel: level + white noise sigma_V, rounded to q."""
    n = int(seconds * fs)
    levels = rng.uniform(-2.0, 2.0, m)
    x = np.concatenate([lv + sigma_V * rng.standard_normal(n) for lv in levels])
    return np.round(x / q) * q, [slice(i * n, (i + 1) * n) for i in range(m)]


@pytest.mark.parametrize("q", [Q16, 20.0 / 2**12, 1e-3])
def test_step_estimate_is_the_grid(q):
    rng = np.random.default_rng(1)
    x = np.round(rng.normal(0.3, 30 * q, 5000) / q) * q
    assert estimate_step(x) == pytest.approx(q, rel=1e-6)
    # a float logger (no grid) gives no step; so does a constant
    assert estimate_step(rng.normal(0, 1, 5000)) == 0.0
    assert estimate_step(np.full(10, 0.7)) == 0.0


def test_step_of_reads_the_metadata_first():
    x = np.arange(10) * 1e-3
    assert step_of({"inferred": {"adc_step_V": 2e-4}}, "acc_x", x) == 2e-4
    assert step_of({"inferred": {"adc_step_V": {"acc_x": 3e-4}}}, "acc_x", x) == 3e-4
    assert step_of({"adc": {"range_V": 5.0, "bits": 16}}, "acc_x", x) == pytest.approx(Q16)
    assert step_of({}, "acc_x", x) == pytest.approx(1e-3)


@pytest.mark.parametrize("fs", [50.0, 100.0, 1000.0])
@pytest.mark.parametrize("noise_lsb", [0.05, 0.3, 3.0])
def test_no_spikes_on_clean_quantised_data(fs, noise_lsb):
    """The step exceeds the noise (MAD = 0): before the quantised scale every sample off the median
    code was a spike (thousands per record); now none, at any rate and resolution."""
    rng = np.random.default_rng(int(fs) + int(10 * noise_lsb))
    x, pos = _positions(rng, fs, sigma_V=noise_lsb * Q16)
    view = ScatterView("acc_x", x, pos, fs, np.full(len(pos), 12.0), quantum_V=step_of({}, "acc_x", x))
    assert view.quantum_V == pytest.approx(Q16, rel=1e-6)
    res = LooseCable().test(view)
    assert res["spikes_total"] == 0 and "finding" not in res
    assert res["robust_sigma_V"] >= Q16 / np.sqrt(12) * (1 - 1e-12)
    # without the step (the old test) the same clean record was full of "spikes" when MAD = 0
    if noise_lsb < 0.3:
        assert LooseCable().test(ScatterView("acc_x", x, pos, fs, np.full(len(pos), 12.0)))["spikes_total"] > 100


@pytest.mark.parametrize("fs", [50.0, 1000.0])
def test_spikes_found_on_quantised_data(fs):
    """Spikes of 30 steps (far beyond 8 s + q/2 = 2.8 q) on a record whose step exceeds the noise:
    every one is counted, nothing else."""
    rng = np.random.default_rng(7)
    x, pos = _positions(rng, fs)
    idx = rng.choice(x.size, 5, replace=False)
    x = x.copy()
    x[idx] += 30 * Q16 * rng.choice([-1.0, 1.0], 5)
    res = LooseCable().test(ScatterView("acc_y", x, pos, fs, np.full(len(pos), 12.0), quantum_V=Q16))
    assert res["spikes_total"] == 5 and res["finding"]["spikes"] == 5


@pytest.mark.parametrize("fs,expected", [(50.0, 50.0), (100.0, 100.0), (102.4, 102.4), (250.0, 125.0),
                                         (1000.0, 100.0), (1024.0, 102.4)])
def test_working_rate_any_logger_rate(fs, expected):
    """The tilt diagnosis' working record from any rate 50 Hz - 1 kHz: decimated by a whole number
    where there is something to decimate, as logged otherwise (no refusal, no cut-off at Nyquist);
    a tone at 5 Hz (in the pass band) keeps its amplitude to the filter's pass-band ripple."""
    from imurig.diagnose.samples import working_record
    from imurig.kernel.recording import Recording

    t = np.arange(int(20 * fs)) / fs
    x = np.sin(2 * np.pi * 5.0 * t)
    w = working_record(Recording(t, {"acc_x": x}, {"acc_x": "V"}))
    assert w.sample_rate_hz == pytest.approx(expected, rel=1e-9)
    inner = slice(w.n // 4, 3 * w.n // 4)
    amp = np.sqrt(2 * np.mean(w.channels["acc_x"][inner] ** 2))
    assert abs(amp - 1.0) < 2e-3     # |H(5 Hz)|^2 = 1 - 1e-10; 2e-3: a part period in the half-record mean


@pytest.mark.parametrize("fs", [50.0, 100.0, 1000.0])
def test_vibration_peak_on_the_quantised_scale(fs):
    """The pump's spectral-peak test: no peak on a clean record whose step exceeds the noise (its
    PSD floored at the rounding's q^2/12 over 0..fs/2), the tone found where it is 10 steps high."""
    from imurig.sensors.effects.building_vibration import PumpVibration

    rng = np.random.default_rng(int(fs) + 1)
    x, pos = _positions(rng, fs, sigma_V=0.05 * Q16)
    view = ScatterView("acc_x", x, pos, fs, np.full(len(pos), 12.0), quantum_V=Q16)
    assert "finding" not in PumpVibration().test(view)
    t = np.arange(x.size) / fs
    tone = np.round((x + 10 * Q16 * np.sin(2 * np.pi * 7.3 * t)) / Q16) * Q16
    res = PumpVibration().test(ScatterView("acc_x", tone, pos, fs, np.full(len(pos), 12.0), quantum_V=Q16))
    assert abs(res["finding"]["spectral_peak_hz"] - 7.3) <= fs / min(256, pos[0].stop - pos[0].start)
