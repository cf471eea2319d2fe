"""The index-pulse timer test of a turn-table time series (imurig.diagnose.pulse_timer), on pulse
channels made here: constant-rate plateaus, pulses at t0 + k T (+ a known Gaussian jitter),
logged as high levels on a sample grid of rate fs."""
import numpy as np
import pytest

from imurig.diagnose.dispatch import diagnose
from imurig.diagnose.pulse_timer import edge_times, pulse_timer_test
from imurig.kernel.errors import RecordingError
from imurig.kernel.files import load
from independent_lab import recording
from independent_lab.lab import write_csv

PERIODS_S = (2.0137, 1.5061, 3.1013, 2.5071, 1.2049, 2.7023)   # one per plateau; T fs not a whole number


def pulse_record(fs_hz: float, jitter_s: float, rng: np.random.Generator, hold_s: float = 30.0, ramp_s: float = 3.0,
                 width_s: float = 0.02):
    """(time, pulse volts, plateau starts, stops, dials) of plateaus of the periods above."""
    starts, stops, times = [], [], []
    now = 5.0
    for T in PERIODS_S:
        a, b = now, now + hold_s
        tk = a + rng.uniform(0, T) + T * np.arange(int((b - a) / T))
        times.append(tk[tk < b - T / 2])
        starts.append(a)
        stops.append(b)
        now = b + ramp_s
    t = np.arange(int((now + 5.0) * fs_hz)) / fs_hz
    tk = np.concatenate(times)
    tk = tk + jitter_s * rng.standard_normal(tk.size)
    x = np.zeros_like(t)
    for s in tk:
        x[int(np.ceil(s * fs_hz)):int(np.ceil((s + width_s) * fs_hz))] = 4.8
    x += 2e-4 * rng.standard_normal(t.size)
    dial = 2 * np.pi / np.array(PERIODS_S)
    return t, x, np.array(starts), np.array(stops), dial


@pytest.mark.parametrize("fs_hz", [100.0, 1000.0])
def test_known_jitter_is_found_with_its_sigma(fs_hz):
    """A 3 ms jitter: found (and by the chi-square reference too); sigma_T = sqrt(jitter^2 + dt^2/12) within 3 SE."""
    rng = np.random.default_rng(11)
    t, x, a, b, dial = pulse_record(fs_hz, 3e-3, rng)
    out = pulse_timer_test(edge_times(t, x), a, b, dial, 1 / fs_hz, np.random.default_rng(1))
    truth = np.sqrt(3e-3**2 + (1 / fs_hz) ** 2 / 12)
    assert out["accepted"] and out["p_value_chi2"] < 0.01, out
    assert abs(out["sigma_T_s"] - truth) < 3 * out["sigma_T_se_s"], (out["sigma_T_s"], truth, out["sigma_T_se_s"])
    assert out["finding"]["parameters"][0]["name"] == "sigma_T_s"


@pytest.mark.parametrize("fs_hz,width_samples", [(50.0, 1.0), (50.0, 1.5), (102.4, 2.048), (1000.0, 20.0)])
def test_no_jitter_no_finding(fs_hz, width_samples):
    """The sample grid alone (pulses a whole number of samples wide or not): the simulated null
    keeps the test quiet, and the scatter is the grid's own."""
    rng = np.random.default_rng(5)
    t, x, a, b, dial = pulse_record(fs_hz, 0.0, rng, width_s=width_samples / fs_hz)
    out = pulse_timer_test(edge_times(t, x), a, b, dial, 1 / fs_hz, np.random.default_rng(1))
    assert out["tested"] and not out["accepted"], out
    assert out["p_value"] > 0.01
    # the residual scatter is no larger than the grid gives, within its chi-square spread
    assert out["scatter_rms_s"] ** 2 < out["grid_rms_s"] ** 2 * (1 + 3 * np.sqrt(2 / out["dof"]))


def test_width_is_known_to_a_whole_sample_and_the_rising_edge_brackets():
    """A pulse 1.5 samples wide shows 1 or 2 high samples: the widths all pulses allow are (1, 2)
    samples, which hold the truth. Taking the mean count's width (1.5 on average) as exact would halve
    each bracket, but with pulses locked to the grid's phase that mean is biased (1.73 samples on a
    null record of the independent lab) and misplaces every bracket; the rising edge alone brackets
    (grid variance dt^2/12)."""
    rng = np.random.default_rng(2)
    fs = 50.0
    t, x, a, b, dial = pulse_record(fs, 0.0, rng, width_s=1.5 / fs)
    e = edge_times(t, x)
    lo, hi = e["width_range_s"]
    assert np.allclose([lo, hi], [1 / fs, 2 / fs], atol=1e-9) and lo < 1.5 / fs < hi
    assert np.allclose(e["var_s2"], (1 / fs) ** 2 / 12)


def test_slip_joint_fit_se_includes_the_exponent():
    """The slip refit with its exponent free: over 200 draws of d = -s1 r^-alpha + noise (noise
    falling as 1 / window length, as pulse-timed rates do, its variance known), s1's z stays near
    unit RMS, where an SE conditional on the exponent is far too small."""
    from imurig.diagnose.table_rate import slip_joint_fit

    rng = np.random.default_rng(3)
    r = np.array([15.0, 30.0, 60.0, 120.0, 240.0] * 2)
    window = 3 * 360.0 / r                                  # three rounds per step (s)
    sd = 0.004 / window                                     # 4 ms of timing error per window
    z = []
    for _ in range(200):
        d = -0.03 * r**-0.7 + sd * rng.standard_normal(r.size)
        p = {q["name"]: q for q in slip_joint_fit(d, r, sd**-2, absolute=True)["parameters"]}["table_slip:s1"]
        z.append((p["estimate"] + 0.03) / p["std_error"])
    z = np.array(z)
    assert np.sqrt(np.mean(z**2)) < 1.5, np.sqrt(np.mean(z**2))
    assert abs(np.median(z)) < 0.3


def test_a_turn_table_file_without_index_pulses_is_refused_saying_how(tmp_path):
    """A lab CSV with the dial and the gyros but no pulse column: refused with the project's error,
    naming the file and the columns that would let the table's rounds be timed."""
    cols, steps, _ = recording("turn_table", None, 5, 50.0, "24bit_10V")
    cols.pop("pulse_V")
    path = tmp_path / "no_pulse.csv"
    write_csv(path, {"rig": "turn_table", "site": "delft"}, cols, steps)
    with pytest.raises(RecordingError, match="index pulses.*pulse_V.*event_pulse_"):
        diagnose(load(path))


def test_jitter_interval_covers_the_truth_on_few_pulses():
    """Three pulses per plateau (one residual each, m = 10), a 4 ms jitter on a 200 Hz grid (the
    independent lab's timer records): over 200 numpy-made draws the 68.27 % interval of the jitter
    variance holds the truth in 68.27 % of them (within 3 binomial SE), and so does the delta-method
    band estimate +- SE; the interval reaches further above the estimate than below it (a skewed
    chi-square on few residuals), which the symmetric SE cannot say."""
    from imurig.diagnose.pulse_timer import _jitter_interval

    rng = np.random.default_rng(7)
    fs, j, n_draw = 200.0, 4e-3, 200
    dt = 1.0 / fs
    T = np.linspace(1.5, 24.0, 10) + 0.0123               # one period per plateau (s)
    n = np.arange(3.0)
    inside = inside_delta = 0
    up = down = 0.0
    for _ in range(n_draw):
        steps = []
        for Ts in T:
            tau = rng.uniform(0, Ts) + Ts * n + j * rng.standard_normal(3)
            tk = (np.ceil(tau * fs) - 0.5) * dt                # the sample after the edge, bracket middle
            steps.append((n, tk, np.full(3, dt**2 / 12)))
        m = 10
        lo, hi = _jitter_interval(steps, m)
        inside += lo <= j**2 <= hi
        rss = sum(float(np.sum((tk - np.polyval(np.polyfit(nn, tk, 1), nn)) ** 2)) for nn, tk, _ in steps)
        j2 = rss / m - dt**2 / 12
        se = np.sqrt(2.0 / m) * (dt**2 / 12 + max(j2, 0.0))
        inside_delta += abs(j2 - j**2) <= se
        if lo > 0:
            up, down = up + hi - j2, down + j2 - lo
    p, band = 0.6827, 3 * np.sqrt(0.6827 * 0.3173 / n_draw)
    assert abs(inside / n_draw - p) < band, inside / n_draw
    assert abs(inside_delta / n_draw - p) < band, inside_delta / n_draw
    assert up > 1.2 * down, (up, down)
