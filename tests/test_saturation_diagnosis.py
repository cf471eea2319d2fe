"""Saturation in the tilt table's position regression, and the position noise of a coarse converter,
on the independent lab's records (numpy-made, not imurig's simulator) and on numpy-made codes."""
from __future__ import annotations

import numpy as np
import pytest
from independent_lab import tilt
from independent_lab.lab import CONVERTERS, write_csv

from imurig.diagnose.position_noise import shared_rounding_variance
from imurig.diagnose.tilt_table import diagnose_tilt_table
from imurig.kernel.files import load
from imurig.sensors.effects.saturation import limit_from_samples


def _tilt_record(tmp_path, effect, seed, fs_hz, converter):
    """A short independent-lab tilt record (4 s dwell) as a minimal lab CSV, loaded; and its truth."""
    cols, steps, truth = tilt.record(seed, effect, fs_hz, converter, dwell_s=4.0)
    path = tmp_path / f"tilt-{effect}-{seed}.csv"
    write_csv(path, {"rig": "tilt_table", "site": "delft"}, cols, steps)
    return load(path), truth


def _saturation(d: dict) -> list[dict]:
    return [f for a in "xyz" for f in d["axes"][a]["findings"] if f["effect"] == "saturation"]


@pytest.mark.parametrize("fs_hz,converter", [(50.0, "12bit_10V"), (50.0, "24bit_10V")])
def test_clip_limit_within_its_standard_errors(tmp_path, fs_hz, converter):
    """acc_z clipped at 0.85 V before the converter: named on acc_z (and nothing else there), and the
    refitted limit is the truth within 3 SE."""
    rec, truth = _tilt_record(tmp_path, "saturation", 11, fs_hz, converter)
    d = diagnose_tilt_table(rec, np.random.default_rng(1), n_sim=100)
    sat = _saturation(d)
    assert [f["channel"] for f in sat] == ["acc_z"]
    assert [f["effect"] for f in d["axes"]["z"]["findings"]] == ["saturation"]
    p = next(p for p in sat[0]["parameters"] if p["name"] == "saturation:upper_limit_V")
    lim = truth["effects"][0]["parameters"]["upper_limit_V"]
    assert p["std_error"] > 0 and abs(p["estimate"] - lim) <= 3 * p["std_error"]
    # the positions it clips are those whose input passes the limit (theta 0 and 30 deg: 12 of 42)
    assert len(sat[0]["clipped_positions"]) == 12


def test_no_saturation_without_a_clip(tmp_path):
    """A null record on a coarse converter (the step above the noise): no clipping finding, and no
    finding at all on acc_z, whose six positions per theta share one rounding error."""
    rec, _ = _tilt_record(tmp_path, None, 2999, 100.0, "12bit_10V")
    d = diagnose_tilt_table(rec, np.random.default_rng(2), n_sim=100)
    assert _saturation(d) == []
    assert d["axes"]["z"]["findings"] == []
    assert d["axes"]["z"]["noise_model"]["shared_level_errors"]


@pytest.mark.parametrize("frac", [0.08, 0.5, 0.68])
@pytest.mark.parametrize("converter", ["12bit_10V", "16bit_5V"])
def test_limit_from_codes_is_unbiased_by_rounding(frac, converter):
    """Codes round((L + n) / q), n ~ N(0, (0.3 q)^2) (the lab's converter noise, no analog noise after a
    clip): the plain mean is biased by the rounding, the maximum-likelihood limit is within 3 SE."""
    adc = CONVERTERS[converter]
    q = adc.step_V
    L = (170 + frac) * q
    rng = np.random.default_rng(int(frac * 100))
    x = [adc.read(np.full(400, L), rng) for _ in range(12)]
    est, se = limit_from_samples(x, q)
    assert se > 0 and abs(est - L) <= 3 * se
    assert se < 0.05 * q


def test_shared_rounding_variance():
    """The rounding error's variance is q^2 / 12 unsmeared (the sawtooth's Fourier series) and its
    part common to one level falls as the first harmonic's exp(-4 pi^2 s^2 / q^2) once smeared."""
    q = 1e-3
    assert shared_rounding_variance(q, 0.0, terms=2000) == pytest.approx(q * q / 12, rel=1e-3)
    s = 0.3 * q
    assert shared_rounding_variance(q, s) == pytest.approx(q * q / (2 * np.pi ** 2) * np.exp(-4 * np.pi ** 2 * 0.09),
                                                          rel=1e-3)
