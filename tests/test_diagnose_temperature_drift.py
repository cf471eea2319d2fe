"""The tilt diagnosis' temperature drift against the truth of a record made here with numpy alone.

Conventions of this file's record (a minimal lab CSV: time, set-points, volts, the box temperature
in degC, ``# rig:`` and ``# site:``): the table dwells at 42 positions (theta, phi), in a shuffled
order, and ramps between them; at rest the triad senses
f = g (-cos phi sin theta, sin phi sin theta, cos theta); each accelerometer j puts out

    u_j = b_j + K_j (f_j + kT_j (T - 22 degC)) + n_j        (V),  n_j white, NOISE_V rms,

with K_j 1.5-2 % off the reader's nominal (the import's datasheet default) and the box
temperature T rising 2.5 K over the run with a 15-minute wobble, logged with 5 mK of noise on a
0.01 degC grid (as a lab's logger writes it). The volts are written with 10 significant digits
(off any grid), so the diagnosis takes per-position medians of the accelerometers.

The drift's column must hold each position's mean temperature: the accelerometers' level at a
position holds kT times the mean of T(t) over the window. The median of the logged temperature
stays on its 0.01 degC grid or half-way between (an error up to 5 mK per position that no number
of samples reduces): on this record the median's column was 17 SE off each position's mean
temperature (the clipped mean's is within 2.3 SE); on a 20-position record at 20 x the tempco it
left a residual after the drift's fit 1.8-2.7 times the one with the temperature logged finely.
"""
from __future__ import annotations

import numpy as np
import pytest
import scipy.stats

from imurig.diagnose.tilt_table import diagnose_tilt_table
from imurig.kernel.labcsv import read_csv

G = 9.81242231                       # the Delft site's gravity (m/s^2)
DEG = np.pi / 180
FS_HZ, DWELL_S, SLEW_DPS = 50.0, 6.0, 30.0
NOISE_V = 2.5e-5                     # accelerometer noise per sample (V rms)
T_NOISE_K, T_STEP_K = 0.005, 0.01    # the thermometer's noise and the logger's grid
S_NOMINAL = 0.1017                   # what the import assumes (V per m/s^2), the datasheet default
K_TRUE = S_NOMINAL * (1 + np.array([0.015, -0.018, 0.02]))
#: 5 x the bias tempco a Q-Flex may have (2 x 70 ug/K with signs and ratios of the independent lab)
KT = 5 * 2 * 70e-6 * 9.80665 * np.array([1.0, -0.7, 0.5])


def positions():
    """(theta, phi) deg, 7 x 6, in a shuffled order: the temperature's rise in time is then not
    a function of the position, and the drift's column is nearly orthogonal to the twin's."""
    grid = np.array([(th, ph) for th in (0, 30, 60, 90, 120, 150, 180) for ph in (0, 60, 120, 180, 240, 300)], float)
    return grid[np.random.default_rng(11).permutation(len(grid))]


def drift_record(seed: int = 5):
    """(columns, true temperature T(t) in degC) of the record described above."""
    rng = np.random.default_rng(seed)
    pos = positions()
    kt, kv, now = [0.0, DWELL_S], [pos[0], pos[0]], DWELL_S
    for a, b in zip(pos[:-1], pos[1:]):
        now += np.max(np.abs(b - a)) / SLEW_DPS
        kt += [now, now + DWELL_S]
        kv += [b, b]
        now += DWELL_S
    kt, kv = np.array(kt), np.array(kv)
    t = np.arange(int(kt[-1] * FS_HZ)) / FS_HZ
    th, ph = (np.interp(t, kt, kv[:, i]) * DEG for i in range(2))
    f = G * np.stack([-np.cos(ph) * np.sin(th), np.sin(ph) * np.sin(th), np.cos(th)], 1)
    T = 22.0 + 2.5 * t / t[-1] + 0.3 * np.sin(2 * np.pi * t / 900.0 + 1.0)
    u = np.array([0.003, -0.002, 0.004]) + K_TRUE * (f + KT * (T - 22.0)[:, None])
    u = u + NOISE_V * rng.standard_normal(u.shape)
    T_log = np.round((T + T_NOISE_K * rng.standard_normal(t.size)) / T_STEP_K) * T_STEP_K
    cols = {"time_s": t, "theta_deg": th / DEG, "phi_deg": ph / DEG, "acc_x_V": u[:, 0], "acc_y_V": u[:, 1],
            "acc_z_V": u[:, 2], "temp_box_degC": T_log}
    return cols, T


@pytest.fixture(scope="module")
def diagnosed(tmp_path_factory):
    cols, T = drift_record()
    path = tmp_path_factory.mktemp("drift") / "drift.csv"
    with open(path, "w") as fh:
        fh.write("# rig: tilt_table\n# site: delft\n" + ",".join(cols) + "\n")
        np.savetxt(fh, np.column_stack(list(cols.values())), fmt="%.10g", delimiter=",")
    rec = read_csv(path)
    return rec, T, diagnose_tilt_table(rec, np.random.default_rng(1), dynamics=False)


def test_drift_column_is_each_positions_mean_temperature(diagnosed):
    """The drift's column (the reading less its mean) against the true T(t) averaged over each
    position's window: within 5 SE of the logged samples' mean (thermometer noise and rounding,
    sigma^2 = 5 mK^2 + q^2 / 12 per sample), where the median's grid error reaches q/2 = 5 mK."""
    rec, T, d = diagnosed
    assert d["position_statistic"] == "median"        # the case the grid error afflicted
    sl = rec.segment_slices()
    assert len(sl) == len(positions())
    mean_T = np.array([T[s].mean() for s in sl])
    n = np.array([s.stop - s.start for s in sl])
    se = np.sqrt(T_NOISE_K ** 2 + T_STEP_K ** 2 / 12) / np.sqrt(n)
    for a in "xyz":
        col = next(v for v in d["axes"][a]["residuals"]["variables"] if v["effect"] == "temperature_drift")
        err = np.asarray(col["values"]) - (mean_T - mean_T.mean())
        assert np.max(np.abs(err - err.mean()) / se) < 5.0


def test_drift_estimate_in_true_units_and_residual_at_the_noise(diagnosed):
    """Each axis names the drift alone; its estimate is -kT in true m/s^2 per K within 4 SE (not
    scaled by the reader's nominal: -kT K_j / s differs by more than 8 SE here), and the residual
    after its fit is the noise: SS / sigma^2 below chi-square's 99.9 % point, sigma^2 per position
    = (pi/2) NOISE_V^2 / (K_j^2 n) (a median's) + kT_j^2 sigma_T^2 / n (the mean temperature's)."""
    rec, _, d = diagnosed
    n = np.array([s.stop - s.start for s in rec.segment_slices()])
    for j, a in enumerate("xyz"):
        ax = d["axes"][a]
        assert [f["effect"] for f in ax["findings"]] == ["temperature_drift"]
        p = ax["findings"][0]["parameters"][0]
        assert p["unit"] == "m/s^2/K"
        assert abs(p["estimate"] + KT[j]) < 4 * p["std_error"]
        assert abs(KT[j] * (K_TRUE[j] / S_NOMINAL - 1)) > 8 * p["std_error"]
        step = ax["fit_steps"][-1]
        var = np.pi / 2 * NOISE_V ** 2 / (K_TRUE[j] ** 2 * n) + KT[j] ** 2 * (T_NOISE_K ** 2 + T_STEP_K ** 2 / 12) / n
        dof = step["n"] - step["p"]
        assert step["ss_res"] / np.mean(var) < scipy.stats.chi2.ppf(0.999, dof)
