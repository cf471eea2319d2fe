"""The independent lab generator (tests/independent_lab): numpy and stdlib only, reproducible,
and its recordings obey its own closed forms within the noise and the converter's step."""
from __future__ import annotations

import ast
import json
import math
import sys
from pathlib import Path

import numpy as np

import independent_lab as lab
from independent_lab import tilt, turn

PACKAGE = Path(lab.__file__).parent
ALLOWED = {"numpy"} | set(sys.stdlib_module_names)


def test_the_generator_imports_only_numpy_and_the_standard_library():
    """Every module of the package, parsed: absolute imports are numpy or stdlib (no scipy, no imurig,
    no rigs/sensors/calibration/flights); relative imports stay inside the package."""
    seen = set()
    for src in sorted(PACKAGE.glob("*.py")):
        for node in ast.walk(ast.parse(src.read_text())):
            if isinstance(node, ast.Import):
                roots = {a.name.split(".")[0] for a in node.names}
            elif isinstance(node, ast.ImportFrom):
                if node.level:      # relative: must name a module of this package
                    assert node.module is None or (PACKAGE / f"{node.module.split('.')[0]}.py").exists(), src
                    continue
                roots = {node.module.split(".")[0]}
            elif isinstance(node, ast.Call) and getattr(node.func, "id", "") in ("__import__", "exec", "eval"):
                raise AssertionError(f"{src.name}: dynamic import or exec")
            else:
                continue
            assert roots <= ALLOWED, (src.name, roots - ALLOWED)
            seen |= roots
    assert "numpy" in seen and not seen & {"scipy", "imurig", "rigs", "sensors", "calibration", "flights"}


def test_same_seed_gives_identical_bytes_and_another_seed_does_not(tmp_path):
    a = lab.write_recording(tmp_path / "a.csv", "turn_table", "timer_quantisation", 5, fs_hz=50.0)
    b = lab.write_recording(tmp_path / "b.csv", "turn_table", "timer_quantisation", 5, fs_hz=50.0)
    c = lab.write_recording(tmp_path / "c.csv", "turn_table", "timer_quantisation", 6, fs_hz=50.0)
    assert a.read_bytes() == b.read_bytes() and a.read_bytes() != c.read_bytes()
    ja, jb = (json.loads(p.with_suffix(".json").read_text()) for p in (a, b))
    assert {k: v for k, v in ja.items() if k != "file"} == {k: v for k, v in jb.items() if k != "file"}
    lines = a.read_text().splitlines()
    assert lines[:3] == ["# rig: turn_table", "# site: delft", "time_s,rate_dps,gyro_x_V,gyro_y_V,gyro_z_V,pulse_V"]
    V = np.loadtxt(a, delimiter=",", skiprows=3, usecols=(2, 3, 4, 5))
    q = ja["adc"]["step_V"]
    assert np.abs(V / q - np.rint(V / q)).max() < 1e-3        # written volts are codes times the step (printed to q/1000)


def _plateaus(sp: np.ndarray, margin: int):
    """Index ranges where the set-point rows are constant, trimmed by ``margin`` samples."""
    change = np.r_[True, np.any(np.diff(sp, axis=0) != 0, axis=1)]
    starts = np.flatnonzero(change)
    for s, e in zip(starts, np.r_[starts[1:], len(sp)]):
        if e - s > 2 * margin + 10:
            yield s + margin, e - margin


def test_static_tilt_voltage_is_bias_plus_sensitivity_times_gravity_within_quantisation_and_noise():
    """Null tilt recording: on each plateau the mean of u_j equals b_j + K_j g d_j(theta, phi), with
    d = (-cos phi sin theta, sin phi sin theta, cos theta) (seed eq. 4.36-4.38). The bound is
    4 sigma/sqrt(n) of the white noise plus, on the 16-bit converter whose step exceeds the noise,
    the converter's worst-case rounding bias q/2 (a fine 24-bit converter: q/sqrt(12) in sigma)."""
    for conv in ("24bit_10V", "16bit_5V"):
        cols, _, truth = tilt.record(7, None, 100.0, conv)
        V = np.column_stack([cols[f"acc_{a}_V"] for a in "xyz"])
        sp = np.column_stack([cols["theta_deg"], cols["phi_deg"]])
        K, b = np.array(truth["triad"]["K_V_per_m_s2"]), np.array(truth["triad"]["bias_V"])
        q = truth["adc"]["step_V"]
        sigma = math.hypot(truth["noise_V_rms_per_sample"], truth["adc"]["input_noise_lsb_rms"] * q)
        n_pos = 0
        for s, e in _plateaus(sp, margin=10):
            th, ph = np.radians(sp[s])
            d = np.array([-math.cos(ph) * math.sin(th), math.sin(ph) * math.sin(th), math.cos(th)])
            err = V[s:e].mean(0) - (b + K * truth["g_m_s2"] * d)
            bound = 4 * math.sqrt(sigma ** 2 + q ** 2 / 12) / math.sqrt(e - s) + (q / 2 if conv == "16bit_5V" else 0)
            assert np.all(np.abs(err) < bound), (conv, sp[s], err, bound)
            n_pos += 1
        assert n_pos == len(tilt.positions())
        if conv == "24bit_10V":    # the scatter on a plateau is the white noise's
            s, e = next(_plateaus(sp, margin=10))
            ratio = V[s:e].std(0) / math.sqrt(sigma ** 2 + q ** 2 / 12)
            assert np.all(np.abs(ratio - 1) < 5 / math.sqrt(2 * (e - s))), ratio


def test_turn_table_round_times_and_gyro_rate_follow_the_dial_the_mains_factor_and_the_earth():
    """Null: the index pulses come every 360 / dial seconds (to the sample grid, 1/fs), and gyro z's
    mean on a hold is b + S (dial + W_E sin lat). With the mains effect the rounds take 6/5 as long."""
    fs = 200.0
    for effect, factor in ((None, 1.0), ("mains_rate_factor", 5 / 6)):
        cols, _, truth = turn.record(11, effect, fs, "24bit_10V")
        t, dial, pulse = cols["time_s"], cols["rate_dps"], cols["pulse_V"]
        rising = t[1:][(pulse[1:] > 2.4) & (pulse[:-1] <= 2.4)]
        d_at = np.interp(rising, t, dial)
        settled = np.interp(rising - 3.0, t, dial) == d_at       # 10 motor time constants on the hold
        same = (np.diff(d_at) == 0) & settled[:-1] & (d_at[1:] != 0)
        T_round = np.diff(rising)[same]
        expect = 360.0 / np.abs(d_at[1:][same] * factor)
        assert same.sum() >= 5 and np.all(np.abs(T_round - expect) < 1.0 / fs + 1e-9), (effect, T_round - expect)
        if effect is None:
            wU = math.degrees(7.2921150e-5 * math.sin(math.radians(52.0)))
            S, b = truth["gyros"]["S_V_per_dps"][2], truth["gyros"]["bias_V"][2]
            sp = dial[:, None]
            sigma = math.hypot(truth["gyros"]["noise_V_rms_per_sample"], 0.3 * truth["adc"]["step_V"])
            for s, e in _plateaus(sp, margin=int(3 * fs)):   # 10 motor time constants after the ramp
                err = cols["gyro_z_V"][s:e].mean() - (b + S * (dial[s] + wU))
                assert abs(err) < 4 * sigma / math.sqrt(e - s), (dial[s], err)


def test_every_effect_is_in_its_recording_and_the_set_names_it():
    plan = lab.plan(seeds=range(1))
    assert {(r, e) for r, e, _ in plan if e} == {(r, e) for r, es in lab.RIG_EFFECTS.items() for e in es}
    assert sum(e is None for _, e, _ in plan) == 2
    for rig, effect, seed in plan[:1]:
        _, _, truth = lab.recording(rig, effect, seed, fs_hz=50.0)
        assert [x["effect"] for x in truth["effects"]] == [effect] and truth["expected"]
