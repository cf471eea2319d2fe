"""The import of minimal lab files: every inference against the truth of files made here with numpy
alone (not with the bench's simulator), with its own conventions written out below."""
from __future__ import annotations

import json

import h5py
import numpy as np
import pytest
import scipy.io

from imurig.kernel.errors import RecordingError
from imurig.kernel.files import load
from imurig.kernel.labcsv import read_csv

G = 9.81242231            # the Delft site's gravity, m/s^2
S_ACC = 0.1017            # V per m/s^2, a unit near the datasheet's
Q16 = 10.0 / 2**16        # +-5 V over 16 bits
DEG = np.pi / 180


def f_case(theta, phi, mount):
    """Specific force on a perfect tilt table, IMU frame: z_up reads +g on z at theta = 0;
    z_down is turned 180 deg about x (y and z flip)."""
    f = G * np.stack([-np.cos(phi) * np.sin(theta), np.sin(phi) * np.sin(theta), np.cos(theta)], 1)
    return f * (np.array([1.0, -1.0, -1.0]) if mount == "z_down" else 1.0)


def tilt_table(rate=102.4, dwell=2.0, ramp=1.0, seed=3, runs=("z_down", "z_up"), noise_V=2e-5, jitter=2e-3):
    """Rows of a tilt-table session: positions held ``dwell`` s, linear ramps between them, a 60 s
    gap at the remount; acc channels quantised to a 16-bit +-5 V ADC; clock jitter ``jitter`` periods
    (1 sigma). Returns (columns, truth)."""
    rng = np.random.default_rng(seed)
    pos = [(t, p) for t in (0, 45, 90, 135) for p in (0, 90, 180, 270)]
    t_all, th_all, ph_all, mount_all, truth = [], [], [], [], {"start": [], "theta": [], "run": []}
    t0 = 0.0
    for r, m in enumerate(runs):
        prev = pos[0]
        for i, (th, ph) in enumerate(pos):
            if i:  # ramp from the previous position
                k = np.arange(int(round(ramp * rate)))
                t_all.append(t0 + k / rate)
                a = (k + 0.5) / k.size
                th_all.append(prev[0] + a * (th - prev[0]))
                ph_all.append(prev[1] + a * (ph - prev[1]))
                mount_all += [m] * k.size
                t0 += k.size / rate
            k = np.arange(int(round(dwell * rate)))
            truth["start"].append(t0)
            truth["theta"].append(th * DEG)
            truth["run"].append(r)
            t_all.append(t0 + k / rate)
            th_all.append(np.full(k.size, float(th)))
            ph_all.append(np.full(k.size, float(ph)))
            mount_all += [m] * k.size
            t0 += k.size / rate
            prev = (th, ph)
        t0 += 60.0
    t = np.concatenate(t_all) + rng.normal(0, jitter / rate, sum(map(len, t_all)))
    th, ph = np.concatenate(th_all), np.concatenate(ph_all)
    mount = np.array(mount_all)
    f = np.empty((t.size, 3))
    for m in runs:
        sel = mount == m
        f[sel] = f_case(th[sel] * DEG, ph[sel] * DEG, m)
    v = S_ACC * (f + 0.02) + rng.normal(0, noise_V, f.shape)
    codes = np.round(v / Q16)
    cols = {"time_s": t, "theta_deg": th + rng.normal(0, 1e-7, t.size), "phi_deg": ph + rng.normal(0, 1e-7, t.size),
            "acc_x_V": codes[:, 0] * Q16, "acc_y_V": codes[:, 1] * Q16, "acc_z_V": codes[:, 2] * Q16,
            "temp_box_degC": 25.0 + 0.01 * rng.standard_normal(t.size)}
    truth.update(codes=codes, f=f)
    return cols, truth


def write(path, cols, head=("# rig: tilt_table", "# site: delft"), rename=None):
    names = [rename.get(k, k) if rename else k for k in cols]
    with open(path, "w") as fh:
        fh.write("\n".join(head) + "\n" + ",".join(names) + "\n")
        np.savetxt(fh, np.column_stack(list(cols.values())), fmt="%.10g", delimiter=",")
    return path


@pytest.fixture(scope="module")
def tilt(tmp_path_factory):
    cols, truth = tilt_table()
    p = write(tmp_path_factory.mktemp("tilt") / "tilt.csv", cols)
    return p, cols, truth, read_csv(p)


def test_rate_gaps_and_plateaus_with_ramps(tilt):
    _, cols, truth, rec = tilt
    inf = rec.meta["inferred"]
    assert abs(inf["sample_rate_hz"]["value"] - 102.4) < 102.4 * 1e-3  # median period under 0.2 % jitter
    assert len(inf["gaps"]["value"]) == 1 and 59.9 < inf["gaps"]["value"][0][1] < 60.1
    assert rec.n_segments == len(truth["start"])
    dt = 1 / 102.4
    assert np.max(np.abs(rec.segments["start_s"] - truth["start"])) < 2 * dt
    np.testing.assert_allclose(rec.segments["theta"], truth["theta"], atol=1e-8)


def test_runs_from_gravity_and_label_check(tilt):
    _, _, truth, rec = tilt
    assert rec.meta["runs"] == ["z_down", "z_up"]
    np.testing.assert_array_equal(rec.segments["run"], truth["run"])
    r = np.array(rec.meta["inferred"]["label_check"]["value"]["correlation_V_vs_f"])
    assert np.all(np.diag(r) > 0.99)


def test_adc_step_sensitivity_temperature_scan_list(tilt):
    _, _, _, rec = tilt
    for c in ("acc_x", "acc_y", "acc_z"):
        assert abs(rec.channel_quantum[c] / Q16 - 1) < 1e-6
    assert rec.meta["acc_nominal_sensitivity_V_per_m_s2"] == pytest.approx([1.33e-3 / 9.80665 * 750] * 3)
    assert any("datasheet default" in w for w in rec.meta["import_warnings"])
    assert rec.units["temp_box"] == "K" and abs(np.mean(rec.channels["temp_box"]) - 298.15) < 1e-3
    assert rec.meta["adc"]["scan_list"] == ["acc_x", "acc_y", "acc_z"]
    assert rec.meta["site"]["gravity_m_s2"] == G


@pytest.mark.parametrize("suffix, value, unit", [("K", 298.15, "K"), ("V", 2.9815, "V")])
def test_temperature_in_kelvin_or_volts(tmp_path, suffix, value, unit):
    cols, _ = tilt_table(dwell=1.5)
    cols["temp_box_degC"] = np.full(cols["time_s"].size, value)
    rec = read_csv(write(tmp_path / "t.csv", cols, rename={"temp_box_degC": f"temp_box_{suffix}"}))
    assert rec.units["temp_box"] == unit and rec.meta["inferred"]["temperatures"]["value"] == {"temp_box": unit}


def test_swapped_and_sign_flipped_headers_are_refused(tmp_path):
    cols, _ = tilt_table(dwell=1.5)
    with pytest.raises(RecordingError, match="look swapped"):
        read_csv(write(tmp_path / "swap.csv", cols, rename={"acc_x_V": "acc_y_V", "acc_y_V": "acc_x_V"}))
    cols["acc_x_V"] = -cols["acc_x_V"]
    with pytest.raises(RecordingError, match="sign error"):
        read_csv(write(tmp_path / "sign.csv", cols))


def test_counts_and_physical_units(tmp_path):
    from imurig.calibration.accelerometer import indicated

    cols, truth = tilt_table(dwell=1.5)
    counts = dict(cols)
    for j, a in enumerate("xyz"):
        counts.pop(f"acc_{a}_V")
        counts[f"acc_{a}_counts"] = truth["codes"][:, j]
    p = write(tmp_path / "c.csv", counts)
    with pytest.raises(RecordingError, match="adc.range_V"):
        read_csv(p)
    rec = read_csv(write(tmp_path / "c2.csv", counts, head=("# rig: tilt_table", "# site: delft",
                                                          "# adc.range_V: 5", "# adc.bits: 16")))
    np.testing.assert_allclose(rec.channels["acc_x"], cols["acc_x_V"], rtol=0, atol=1e-12)
    phys = {k: v for k, v in cols.items() if not k.startswith("acc")}
    for j, a in enumerate("xyz"):
        phys[f"acc_{a}_m_s2"] = truth["f"][:, j] + 0.02
    rec = read_csv(write(tmp_path / "p.csv", phys))
    assert rec.units["acc_x"] == "m/s^2" and rec.meta["acc_nominal_sensitivity_V_per_m_s2"] == [1.0] * 3
    in_g = read_csv(write(tmp_path / "g.csv", {k: (v / 9.80665 if k.startswith("acc") else v) for k, v in phys.items()},
                          rename={f"acc_{a}_m_s2": f"acc_{a}_g" for a in "xyz"}))
    np.testing.assert_allclose(in_g.channels["acc_z"], rec.channels["acc_z"], rtol=1e-9)
    u, _ = indicated(rec)  # the calibration reads them with 1 V per m/s^2
    sl = rec.segment_slices()[3]
    assert u[3, 0] == pytest.approx(np.median(rec.channels["acc_x"][sl]))


@pytest.mark.parametrize("suffix, value, says", [("degC", 298.15, "look like kelvin: name the column temp_box_K"),
                                                  ("K", 25.0, "look like degrees Celsius: name the column "
                                                              "temp_box_degC")])
def test_temperature_units_that_contradict_the_values_are_refused(tmp_path, suffix, value, says):
    cols, _ = tilt_table(dwell=1.5)
    cols["temp_box_degC"] = np.full(cols["time_s"].size, value)
    with pytest.raises(RecordingError, match=says):
        read_csv(write(tmp_path / "t.csv", cols, rename={"temp_box_degC": f"temp_box_{suffix}"}))


def test_accelerations_in_g_named_m_s2_are_refused(tmp_path):
    _, truth = tilt_table(dwell=1.5)
    cols, _ = tilt_table(dwell=1.5)
    for j, a in enumerate("xyz"):
        cols.pop(f"acc_{a}_V")
        cols[f"acc_{a}_m_s2"] = truth["f"][:, j] / 9.80665          # g, under an m/s^2 header
    with pytest.raises(RecordingError, match="look like g in a channel read as m/s\\^2"):
        read_csv(write(tmp_path / "g.csv", cols))


def test_rates_in_deg_s_named_rad_s_are_refused(tmp_path):
    cols, _ = turn_table()
    cols["rate_rad_s"] = cols.pop("rate_dps") * 40.0           # 800-1600 deg/s read as rad/s: beyond 20 turns/s
    with pytest.raises(RecordingError, match="name the column rate_dps"):
        read_csv(write(tmp_path / "r.csv", cols, head=("# rig: turn_table", "# site: delft")))
    cols, _ = turn_table()
    for a in "xyz":
        cols[f"gyro_{a}_rad_s"] = cols.pop(f"gyro_{a}_V") / 6e-3            # deg/s under rad/s headers
    with pytest.raises(RecordingError, match="look like deg/s in a channel read as rad/s"):
        read_csv(write(tmp_path / "g.csv", cols, head=("# rig: turn_table", "# site: delft")))


def test_memory_estimate_refuses_before_allocating(tilt):
    p = tilt[0]
    with pytest.raises(RecordingError, match="GB are available"):
        read_csv(p, memory_limit_bytes=10_000)


def test_site_is_refused_when_missing_and_dotted_keys_give_normal_gravity(tmp_path):
    cols, _ = tilt_table(dwell=1.5)
    with pytest.raises(RecordingError, match="no site"):
        read_csv(write(tmp_path / "a.csv", cols, head=("# rig: tilt_table",)))
    rec = read_csv(write(tmp_path / "b.csv", cols, head=("# rig: tilt_table", "# site.latitude_deg: 52.0",
                                                         "# site.longitude_deg: 4.37", "# site.altitude_m: 0")))
    assert abs(rec.meta["site"]["gravity_m_s2"] - G) < 2e-3  # normal vs measured gravity at Delft


def turn_table(rate=200.0, seed=5, noise_V=1e-3, rise_s=0.01):
    """A turn-table session: dial steps held 8 s with 2 s ramps, gyro r up then p down, and the
    index pulse as a 5 V level 30 ms long with a linear rise of ``rise_s`` once per round."""
    rng = np.random.default_rng(seed)
    s_g = 6e-3 / DEG
    steps = [(20.0, "r_up"), (-30.0, "r_up"), (40.0, "p_down")]
    t = np.arange(0, 10.0 * len(steps), 1 / rate)
    dial = np.zeros(t.size)
    w = np.zeros((t.size, 3))
    for i, (r, m) in enumerate(steps):
        sel = (t >= 10 * i + 2) & (t < 10 * i + 10)
        ramp = (t >= 10 * i) & (t < 10 * i + 2)
        prev = steps[i - 1][0] if i else 0.0
        dial[ramp] = prev + (t[ramp] - 10 * i) / 2 * (r - prev)
        dial[sel] = r
        axis, sign = "pqr".index(m[0]), 1.0 if m.endswith("up") else -1.0
        w[sel | ramp, axis] = sign * dial[sel | ramp] * DEG
    rounds = np.floor(np.abs(np.cumsum(np.abs(dial)) / rate / 360.0 * 3))  # 3 marks per round: more pulses
    idx = np.flatnonzero(np.diff(rounds) > 0) + 1
    tc = t[idx] - 0.003  # true crossing instants of the mid level, between samples
    pulse = np.zeros(t.size)
    for c in tc:
        start = c - rise_s / 2
        pulse += np.clip((t - start) / rise_s, 0, 1) * (t < c + 0.03)
    pulse = 5.0 * np.clip(pulse, 0, 1) + rng.normal(0, noise_V, t.size)
    v = s_g * w + rng.normal(0, 1e-4, w.shape)
    cols = {"time_s": t, "rate_dps": dial, "gyro_x_V": v[:, 0], "gyro_y_V": v[:, 1], "gyro_z_V": v[:, 2],
            "pulse_V": pulse}
    return cols, {"tc": tc, "slope": 5.0 / rise_s, "noise": noise_V}


def test_turn_table_pulses_mounts_and_rate_dial(tmp_path):
    cols, truth = turn_table()
    p = write(tmp_path / "turn.csv", cols, head=("# rig: turn_table", "# site: delft"))
    rec = read_csv(p)
    ev = rec.events["pulse_channel"]
    assert ev.size == truth["tc"].size
    # the crossing time's error: two noisy samples on the ramp, sigma ~ noise * sqrt(2) / slope
    bound = 5 * np.sqrt(2) * truth["noise"] / truth["slope"]
    assert np.max(np.abs(ev - truth["tc"])) < bound < 0.1 / 200
    assert rec.n_segments == 3 and rec.meta["runs"] == ["r_up", "p_down"]
    np.testing.assert_allclose(rec.segments["rate_dial"], np.array([20, -30, 40]) * DEG, atol=1e-12)
    assert rec.meta["inferred"]["channel_names"]["value"]["gyro_x"] == "gyro_p"
    assert rec.meta["timer"] == "channel"
    # white noise 1e-4 V per sample: ARW = 1e-4 / s / sqrt(fs). A plateau's ~1560 first differences
    # (lag-1 correlation -1/2) give the std to sqrt(3 / n) / 2 = 2.2 % (1 sigma); the medians over
    # plateaus and axes do not widen it by more than ~1.2: 9 % is about 4 sigma
    arw_true = 1e-4 / (6e-3 / DEG) / np.sqrt(200.0)
    assert abs(rec.meta["gyro_noise_model"]["arw_rad_s_per_sqrt_hz"] / arw_true - 1) < 0.09


def test_event_column_names_and_pulse_channel_option(tmp_path):
    cols, truth = turn_table()
    ev = np.full(cols["time_s"].size, np.nan)
    idx = np.searchsorted(cols["time_s"], truth["tc"])
    ev[idx] = truth["tc"]
    cols["event_hp6700_s"] = ev
    cols["index_V"] = cols.pop("pulse_V")
    rec = load(write(tmp_path / "t.csv", cols, head=("# rig: turn_table", "# site: delft")), pulse_channel="index")
    np.testing.assert_allclose(rec.events["pulse_hp6700"], truth["tc"])
    assert rec.events["pulse_channel"].size == truth["tc"].size
    cols["event_pulse_hp6700_s"] = cols.pop("event_hp6700_s")
    rec = load(write(tmp_path / "u.csv", cols, head=("# rig: turn_table", "# site: delft")))
    assert "pulse_hp6700" in rec.events and "pulse_channel" not in rec.events


def test_matlab_v5_and_v73_match_the_csv(tilt, tmp_path):
    _, cols, _, rec = tilt
    scipy.io.savemat(tmp_path / "a.mat", {**{k: v for k, v in cols.items()}, "rig": "tilt_table", "site": "delft"})
    with h5py.File(tmp_path / "b.mat", "w", userblock_size=512) as f:
        g = f.create_group("session")
        for k, v in cols.items():
            g.create_dataset(k, data=v.reshape(1, -1)).attrs["MATLAB_class"] = b"double"
        for k, text in (("rig", "tilt_table"), ("site", "delft")):
            f.create_dataset(k, data=np.array([[ord(c)] for c in text], np.uint16)).attrs["MATLAB_class"] = b"char"
    for name in ("a.mat", "b.mat"):
        m = load(tmp_path / name)
        assert m.segment_slices() == rec.segment_slices()  # the CSV holds 10 digits, the .mat all
        assert m.meta["runs"] == rec.meta["runs"]
        np.testing.assert_allclose(m.channels["acc_y"], rec.channels["acc_y"], rtol=1e-9)


def test_cli_info_and_calibrate_take_a_minimal_file(tilt, tmp_path, capsys):
    from imurig.cli.main import main

    p = tilt[0]
    assert main(["info", str(p)]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["inferred"]["runs"]["value"] == ["z_down", "z_up"] and info["import_warnings"]
    bare = write(tmp_path / "bare.csv", tilt[1], head=("# rig: tilt_table",))
    assert main(["info", str(bare)]) == 2
    assert "no site" in capsys.readouterr().err
    assert main(["info", str(bare), "--site", "delft"]) == 0


def test_readme_minimal_file_parses(tmp_path):
    """The README's minimal file goes in with its structure inferred (two samples: one plateau
    would need a second, so none; the rate and the site are inferred)."""
    from pathlib import Path

    readme = (Path(__file__).parents[1] / "README.md").read_text()
    block = readme.split("### The minimal file")[1].split("```")[1]
    p = tmp_path / "minimal.csv"
    p.write_text(block.strip() + "\n")
    rec = read_csv(p)
    assert rec.meta["rig"] == "tilt_table" and rec.meta["site"]["latitude_deg"] == 52.0
    assert rec.units["temp_box"] == "K" and rec.meta["inferred"]["sample_rate_hz"]["value"] == pytest.approx(1 / 0.0098)


@pytest.mark.slow
def test_cli_calibrate_a_minimal_file(tmp_path):
    """`imurig calibrate` on a minimal 200 Hz file (16-bit ADC, ramps, two mountings found from
    gravity): the sensitivities agree with the truth within 4 standard errors, and the summary
    carries what the import inferred."""
    from imurig.cli.main import main

    cols, _ = tilt_table(rate=200.0, dwell=15.0, jitter=0.0)
    p = write(tmp_path / "m.csv", cols)
    assert main(["calibrate", str(p), "--out", str(tmp_path / "cal")]) == 0
    s = json.loads((tmp_path / "cal" / "summary.json").read_text())
    assert s["inferred"]["runs"]["value"] == ["z_down", "z_up"]
    sens = [q for q in s["parameters"] if q["name"].startswith("sensitivity_")]
    assert len(sens) == 3 and all(abs(q["estimate"] - S_ACC) < 4 * q["std_error"] for q in sens)


def test_matlab_export_layout_is_read_as_declared(tmp_path):
    """The layout `imurig export` writes (channels/units structs, segments, meta as JSON)."""
    t = np.arange(400) / 100.0
    v = np.sin(t)
    seg = {"start_s": np.array([[0.5], [2.5]]), "stop_s": np.array([[1.5], [3.5]]), "run": np.array([[0], [1]]),
           "theta_deg": np.array([[0.0], [90.0]])}
    scipy.io.savemat(tmp_path / "e.mat", {"time_s": t.reshape(-1, 1), "channels": {"acc_x": v.reshape(-1, 1)},
                                          "units": {"acc_x": "V"}, "events": {}, "segments": seg,
                                          "meta_json": json.dumps({"rig": "tilt_table", "runs": ["z_down", "z_up"]})})
    rec = load(tmp_path / "e.mat")
    np.testing.assert_array_equal(rec.channels["acc_x"], v)
    np.testing.assert_allclose(rec.segments["theta"], [0, np.pi / 2])
    assert rec.meta["runs"] == ["z_down", "z_up"] and "inferred" not in rec.meta


def test_a_set_point_that_never_holds_gives_no_segment_and_a_weak_sensitivity_is_marginal(tmp_path):
    cols, _ = tilt_table(dwell=1.5)
    n = cols["time_s"].size
    ramp = dict(cols, theta_deg=np.linspace(0, 180, n), phi_deg=np.linspace(0, 90, n))
    rec = read_csv(write(tmp_path / "r.csv", ramp))
    assert rec.n_segments == 0
    weak = dict(cols, **{f"acc_{a}_V": cols[f"acc_{a}_V"] * 0.3 for a in "xyz"})
    rec = read_csv(write(tmp_path / "w.csv", weak, head=("# rig: tilt_table", "# site: delft",
                                                         "# acc_nominal_sensitivity_V_per_m_s2: 0.1017")))
    assert any(w.startswith("MARGINAL") and "sensitivity" in w for w in rec.meta["import_warnings"])


def test_adc_step_survives_printed_decimals_over_thousands_of_codes():
    """Codes of a 16-bit +-5 V converter printed to 7 decimals over a 1 V span (6,500 codes): the
    rounding (<= 5e-8 V, 3e-4 q) must not accumulate into the step estimate; a float record is
    refused (None)."""
    from imurig.kernel.infer import adc_step
    q = 10.0 / 2**16
    rng = np.random.default_rng(3)
    codes = rng.integers(-100, 6500, 20_000)
    x = np.round(codes * q, 7)
    assert abs(adc_step(x) / q - 1) < 1e-6
    assert adc_step(rng.normal(size=5000)) is None
