"""The index-pulse timer test against the table-axis gyro's integrated angle
(imurig.diagnose.pulse_angle), on turn-table records made here: a dial stepped through ramps and
plateaus, a motor lagging it, the table angle psi = int omega dt, a gyro u = b + S omega + noise on
the table axis, and a pulse channel high for a width w after each whole turn (+ a known jitter and
a constant detector latency)."""
import math

import numpy as np
import pytest
from scipy.signal import lfilter

from imurig.diagnose.pulse_angle import chain, covariance, design, pulse_times, reml
from imurig.diagnose.pulse_timer import edge_times
from imurig.diagnose.turn_table import _pulse_timer
from imurig.kernel.files import load
from independent_lab import write_recording

DIALS_DPS = (14.7, 29.3, 58.9, 117.3, 233.7, -15.3, -29.9, -61.3, -118.9, -236.1)   # periods: no whole samples
S_V_PER_DPS, BIAS_V = 5.3e-3, 0.011


def table_record(fs: float, jitter_s: float, rng: np.random.Generator, width_samples: float = 2.0,
                 latency_s: float = 0.0, noise_V: float = 1e-4, wobble: float = 0.0):
    """(time, gyro volts, pulse volts, plateau starts, stops, dials (rad/s), true pulse times)."""
    kt, kv, now = [0.0, 3.0], [0.0, 0.0], 3.0
    starts, stops = [], []
    for d in DIALS_DPS:
        hold = max(8.0, 3.3 * 360.0 / abs(d))
        kt += [now + 2.0, now + 2.0 + hold]
        kv += [d, d]
        starts.append(now + 2.0)
        stops.append(now + 2.0 + hold)
        now += 2.0 + hold
    kt += [now + 2.0, now + 5.0]
    kv += [0.0, 0.0]
    t = np.arange(int(kt[-1] * fs)) / fs
    a = math.exp(-1.0 / (fs * 0.3))                        # the motor's first-order lag, 0.3 s
    omega = lfilter([1 - a], [1, -a], np.interp(t, kt, kv))
    omega *= 1.0 + wobble * np.sin(2 * np.pi * t / 17.0 + rng.uniform(0, 2 * np.pi))   # the rate's slow wobble
    psi = np.concatenate([[0.0], np.cumsum(0.5 * (omega[1:] + omega[:-1]) / fs)])
    turns = np.floor(psi / 360.0)
    i = np.flatnonzero(np.diff(turns) != 0)
    level = np.maximum(turns[i], turns[i + 1]) * 360.0
    tk = t[i] + (level - psi[i]) / (psi[i + 1] - psi[i]) / fs
    tk = tk + latency_s + jitter_s * rng.standard_normal(tk.size)
    x = np.zeros_like(t)
    for s in tk:
        x[int(math.ceil(s * fs - 1e-9)):int(math.ceil((s + width_samples / fs) * fs - 1e-9))] = 4.8
    u = BIAS_V + S_V_PER_DPS * omega + noise_V * rng.standard_normal(t.size)
    return t, u, x + 2e-4 * rng.standard_normal(t.size), np.array(starts), np.array(stops), \
        np.radians(DIALS_DPS), tk


def run_test(fs, jitter_s, seed, **kw):
    from imurig.diagnose.pulse_angle import angle_timer_test
    t, u, x, a, b, dial, _ = table_record(fs, jitter_s, np.random.default_rng(seed), **kw)
    e = edge_times(t, x)
    c = chain(t, u, pulse_times(e, 1 / fs), a, b, dial)
    assert c is not None
    return angle_timer_test(c, e, 1 / fs, 0.0, np.random.default_rng(1))


@pytest.mark.parametrize("fs,width", [(50.0, 1.5), (100.0, 2.0), (200.0, 3.4)])
def test_known_jitter_is_found_with_its_sigma(fs, width):
    """A 4 ms jitter: found; sigma_T = sqrt(jitter^2 + dt^2/12) within 3 SE; every pulse but the
    five columns' worth is a residual (ramps and settling included)."""
    out = run_test(fs, 4e-3, 3, width_samples=width)
    truth = math.sqrt(16e-6 + (1 / fs) ** 2 / 12)
    assert out["accepted"], out
    assert abs(out["sigma_T_s"] - truth) < 3 * out["sigma_T_se_s"], (out["sigma_T_s"], truth, out["sigma_T_se_s"])
    assert out["dof"] == out["pulses"] - 5
    assert out["finding"]["parameters"][0]["name"] == "sigma_T_s"


@pytest.mark.parametrize("fs,width,latency", [(50.0, 1.5, 0.0), (100.0, 2.0, 7e-3), (102.4, 2.048, 0.0)])
def test_no_jitter_no_finding(fs, width, latency):
    """The sample grid alone (a width of whole samples or not; a constant detector latency, which
    the latency column takes): the simulated null keeps the test quiet."""
    out = run_test(fs, 0.0, 5, width_samples=width, latency_s=latency)
    assert out["tested"] and not out["accepted"], out
    assert out["p_value"] > 0.01


def test_width_is_bracketed_by_what_all_pulses_allow():
    """Pulses 2.3 samples wide at random grid phases show 2 or 3 high samples, so the widths every
    pulse allows overlap in (2, 3) samples, which holds the true width: the grid fixes the width to a
    whole sample only, and the falling edge then narrows no pulse's bracket (the mean count's width,
    2.3 on average, is a statistic: with phase-locked pulses it misplaces every bracket)."""
    t, _u, x, *_ = table_record(100.0, 4e-3, np.random.default_rng(2), width_samples=2.3)
    e = edge_times(t, x)
    lo, hi = e["width_range_s"]
    assert lo < 0.023 < hi and np.allclose([lo, hi], [0.02, 0.03], atol=1e-9), (lo, hi)
    assert np.allclose(e["var_s2"], 0.01**2 / 12)


def test_jitter_z_and_interval_over_draws():
    """Over 40 numpy-made records (100 Hz, 4 ms jitter, the table's rate wobbling 1 % so that the
    pulses fall at independent grid phases, as the model takes them): the REML estimate's z against
    the truth has a mean square within 3 of its sampling SE (sqrt(2/40)) of 1, and the
    likelihood-ratio interval holds the truth in 68.27 % of records within 3 binomial SE."""
    fs, j, n = 100.0, 4e-3, 40
    rng = np.random.default_rng(17)
    z2, inside = [], 0
    for _ in range(n):
        t, u, x, a, b, dial, _ = table_record(fs, j, rng, wobble=0.01)
        e = edge_times(t, x)
        c = chain(t, u, e["time_s"], a, b, dial)
        C0, D, _ = covariance(c, e["var_s2"], 1 / fs, 0.0)
        r = reml(c["N"], design(c), C0, D, 1e-2, 1e-10)
        z2.append(((r["j2"] - j**2) / r["se"]) ** 2)
        inside += r["interval"][0] <= j**2 <= r["interval"][1]
    assert abs(np.mean(z2) - 1.0) < 3 * math.sqrt(2.0 / n), np.mean(z2)
    assert abs(inside / n - 0.6827) < 3 * math.sqrt(0.6827 * 0.3173 / n), inside / n


def test_turn_table_diagnosis_times_the_pulses_on_the_gyro(tmp_path):
    """The independent lab's 200 Hz timer record whose plateau residuals drew a 2.3 ms jitter for the
    4 ms injected (the plateau test: sigma_T 2.20 +- 0.45 ms against 4.25, z = -4.6): the diagnosis
    takes every pulse against the gyro's angle, finds the timer and sizes it within 3 SE."""
    path = write_recording(tmp_path / "timer.csv", "turn_table", "timer_quantisation", 11002)
    rec = load(path)
    out = _pulse_timer(rec, np.random.default_rng(0), 0.01)
    truth = math.sqrt(16e-6 + 0.005**2 / 12)
    assert out["method"] == "gyro angle" and out["gyro_channel"] == "gyro_r"
    assert out["accepted"] and abs(out["sigma_T_s"] - truth) < 3 * out["sigma_T_se_s"], out
    assert out["dof"] > 3 * out["plateau_test"]["dof"]
