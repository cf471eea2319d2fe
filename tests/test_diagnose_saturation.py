"""Saturation and clipping as a library effect, on small numpy-made records (not imurig's simulator)."""
from __future__ import annotations

import numpy as np
import pytest

from imurig.sensors.effects import RawChannelView, by_name
from imurig.sensors.effects.saturation import Saturation

Q16 = 10.0 / 2**16


def _record(rng, fs, seconds=30.0, noise_V=3e-4, q=Q16, amp_V=4.0):
    """A slow sine of amplitude amp_V plus white noise, rounded to the step q."""
    t = np.arange(int(seconds * fs)) / fs
    x = amp_V * np.sin(2 * np.pi * 0.05 * t) + noise_V * rng.standard_normal(t.size)
    return t, x, (np.round(x / q) * q if q else x)


def test_saturation_is_in_the_library():
    assert by_name("saturation") is Saturation
    x = np.linspace(-7, 7, 15)
    assert np.array_equal(Saturation(enabled=True, range_V=5.0).inject(x), np.clip(x, -5, 5))


@pytest.mark.parametrize("fs", [50.0, 102.4, 1000.0])
@pytest.mark.parametrize("known_range", [True, False])
def test_clips_found_with_level_and_fraction(fs, known_range):
    """A sine of 5.5 V clipped at +-5 V: the level is the range and the clipped samples are the
    truth's (those at or beyond the range at the reported extreme), short of at most the runs
    shorter than the test's minimum run."""
    rng = np.random.default_rng(int(fs))
    t, x, xq = _record(rng, fs, amp_V=5.5)
    y = Saturation(enabled=True, range_V=5.0).inject(xq)
    res = Saturation().test(RawChannelView("acc_x", y, t, quantum_V=Q16, range_V=5.0 if known_range else None))
    f = res["finding"]
    assert abs(abs(f["level_V"]) - 5.0) <= Q16
    truth = int(np.sum(np.sign(f["level_V"]) * xq >= 5.0))         # samples clipped at that extreme
    k_min = 2 if known_range else res["saturation_min_run"]
    assert truth - (f["runs"] + 2) * k_min <= f["samples"] <= truth
    assert f["fraction"] == pytest.approx(f["samples"] / t.size)


@pytest.mark.parametrize("fs", [50.0, 1000.0])
@pytest.mark.parametrize("noise_V,q", [(3e-4, Q16), (1e-5, Q16), (1e-3, 0.0)])
def test_no_clip_on_clean_data(fs, noise_V, q):
    """No finding on an unclipped record, whether the step resolves the noise or exceeds it
    (then, with the range known, only a level at the range could show a clip)."""
    rng = np.random.default_rng(3 + int(fs))
    t, _, xq = _record(rng, fs, noise_V=noise_V, q=q)
    res = Saturation().test(RawChannelView("acc_x", xq, t, quantum_V=q, range_V=5.0))
    assert "finding" not in res
