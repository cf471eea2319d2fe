"""The effect library: every effect keeps the contract, and each one's physics holds in closed form."""
from __future__ import annotations

import json
import math
from dataclasses import fields, is_dataclass, replace

import numpy as np
import pytest

from imurig.sensors.adc import DAQ6036E
from imurig.sensors.effects import LIBRARY, STAGES, AdcCrosstalk, Candidate, PositionView, ScanSlot, by_name
from imurig.sensors.effects.adc_quantisation import floor_V, variance_V2


@pytest.mark.parametrize("cls", LIBRARY, ids=lambda c: c.name)
def test_effect_contract(cls):
    """Names are unique and say where they act; the words and the seed's support are there; the
    parameters carry units; settings and description are plain JSON."""
    assert [c.name for c in LIBRARY].count(cls.name) == 1 and by_name(cls.name) is cls
    assert cls.stage in STAGES
    assert cls.physics and cls.seed_section and cls.seed_says
    assert all(p.unit for p in cls.params)
    eff = cls()
    assert is_dataclass(eff)
    json.dumps(eff.settings())
    json.dumps(cls.describe())
    if "enabled" in {f.name for f in fields(eff)}:  # switched off, the chain sees nothing of it
        x = np.linspace(-1.0, 1.0, 50)
        off = replace(eff, enabled=False)
        slot = ScanSlot(1, 20e3, previous_V=np.full(50, 3.0))
        assert np.array_equal(off.inject(x, slot, np.random.default_rng(0)), x)


def _view(m=12, scan=("acc_x", "mag_x", "acc_y")):
    rng = np.random.default_rng(1)
    med = {c: rng.normal(size=m) for c in scan}
    return PositionView(channel="acc_y", axis="y", readings={n: rng.normal(size=m) for n in ("ax", "ay", "az")},
                        channel_median=med.get, scan_list=scan), med


@pytest.mark.parametrize("cls", [c for c in LIBRARY if c.views], ids=lambda c: c.name)
def test_candidates_have_one_row_per_observation(cls):
    view, _ = _view()
    for cand in cls().candidates(view):
        assert isinstance(cand, Candidate) and cand.name == cls.name
        for th in cand.scan:
            assert cand.design(th).shape == (12, len(cand.param_names))


def test_crosstalk_injection_closed_form():
    """u_j + c (u_{j-1} - u_j) with c = exp(-1 / (f_mux tau)), to machine precision."""
    eff = AdcCrosstalk(settling_tau_s=0.59e-6)
    c = math.exp(-1.0 / (200e3 * 0.59e-6))
    assert eff.coefficient(200e3) == pytest.approx(c, rel=1e-15)
    u, prev = np.array([0.1, -2.0, 4.0]), np.array([1.0, 1.0, -3.0])
    np.testing.assert_allclose(eff.inject(u, ScanSlot(2, 200e3, prev)), u + c * (prev - u), rtol=1e-15, atol=1e-15)
    assert AdcCrosstalk(enabled=False).coefficient(200e3) == 0.0


def test_crosstalk_truth_map_is_the_inverse_models_coefficient():
    """Regressing the true specific force on (measured volts, previous channel's volts) gives the
    coefficient the effect's ``fitted`` states, -c / (s (1 - c)), to machine precision."""
    rng = np.random.default_rng(2)
    s, f_mux = 1.33e-3 / 9.80665 * 750.0, 150e3
    eff = AdcCrosstalk(settling_tau_s=1e-6)
    c = eff.coefficient(f_mux)
    f = rng.normal(0, 9.8, 40)
    v_prev = rng.normal(0, 2.0, 40)
    v_meas = eff.inject(s * f, ScanSlot(2, f_mux, v_prev))
    coef, *_ = np.linalg.lstsq(np.column_stack([v_meas, v_prev]), f, rcond=None)
    truth = {"chain": {"adc": {"crosstalk_coefficient": c}},
             "sensors": {"accelerometers": {"sensitivity_V_per_m_s2": [0.0, s, 0.0]}}}
    assert coef[1] == pytest.approx(eff.fitted(truth, "acc_y")["c"], rel=1e-9)


def test_crosstalk_candidate_is_the_previous_channels_median():
    view, med = _view()
    (cand,) = AdcCrosstalk().candidates(view)
    np.testing.assert_array_equal(cand.design(None)[:, 0], med["mag_x"])
    first = replace(view, channel="acc_x")  # the scan wraps round: acc_x follows acc_y
    np.testing.assert_array_equal(AdcCrosstalk().candidates(first)[0].design(None)[:, 0], med["acc_y"])
    assert AdcCrosstalk().candidates(replace(view, scan_list=())) == []


@pytest.mark.parametrize("averaging", [1, 10])
def test_quantisation_variance_matches_the_converter(averaging):
    """The converter's error on a constant input has the variance (q^2/12 + (k_e q)^2) / n_avg,
    within 4.5 standard errors of the sample variance (SE from the sample's own fourth moment)."""
    adc = DAQ6036E(scan_list=("a",), range_V=0.05, input_noise_lsb_rms=0.6, common_mode_noise_V_rms=0.0,
                   skew_enabled=False, crosstalk_enabled=False, averaging=averaging)
    n = 200_000
    x = np.random.default_rng(3).uniform(-0.01, 0.01, n)  # spread over many codes: the rounding error is uniform
    out, _ = adc.convert({"a": x}, np.arange(n) / 1e3, np.random.default_rng(4))
    e = out["a"] - x
    var, m4 = np.var(e), np.mean((e - e.mean()) ** 4)
    se = math.sqrt((m4 - var**2) / n)
    assert abs(var - variance_V2(adc.lsb_V, 0.6, averaging)) < 4.5 * se
    assert adc.sample_variance_V2() == variance_V2(adc.lsb_V, 0.6, averaging)
    assert floor_V(adc.lsb_V) == pytest.approx(adc.lsb_V / math.sqrt(12), rel=1e-15)


# ------------------------------------------------------------------ the Q-Flex's mean-level effects
G = 9.80665


def _triad_truth(tri, T_mean):
    """The truth mapping the truth maps read (recording_truth's form) for a triad at T_mean."""
    return {"sensors": {"accelerometers": tri.truth()},
            "conditions": {"mean_temperature_K": float(T_mean),
                           "acc_nominal_sensitivity_V_per_m_s2": tri.nominal_sensitivity_V_per_m_s2().tolist()}}


def _positions(m=60, seed=5):
    rng = np.random.default_rng(seed)
    f = rng.normal(0.0, 1.0, (m, 3))
    return G * f / np.linalg.norm(f, axis=1, keepdims=True) * rng.uniform(0.3, 1.0, (m, 1))


def test_misalignment_truth_map_is_the_exact_inverse_model():
    """Regressing the true f_j on (1, u_x, u_y, u_z) of the noise-free Q-Flex (bias, scale errors,
    scale tempco at 303 K, misalignment, no k2) gives the effect's m_jk to machine precision."""
    from imurig.sensors.accelerometer import QFlexTriad
    from imurig.sensors.effects import AxisMisalignment

    M = np.array([[0, 1.5e-3, -0.8e-3], [0.6e-3, 0, 1.1e-3], [-1.9e-3, 0.4e-3, 0]])
    tri = QFlexTriad(bias_m_s2=[0.02, -0.01, 0.05], k1_A_per_m_s2=np.array([1.31, 1.34, 1.33]) * 1e-3 / G,
                     misalignment_rad=M, scale_tempco_per_K=[1e-4, -2e-4, 5e-5])
    f, T = _positions(), 303.15
    u = tri.ideal_voltage(f, T) / tri.nominal_sensitivity_V_per_m_s2()
    X = np.column_stack([np.ones(len(f)), u])
    truth = _triad_truth(tri, T)
    for j, a in enumerate("xyz"):
        coef, *_ = np.linalg.lstsq(X, f[:, j], rcond=None)
        for k, b in enumerate("xyz"):
            if k != j:
                assert coef[1 + k] == pytest.approx(AxisMisalignment().fitted(truth, f"acc_{a}")[f"m_{a}{b}"],
                                                    rel=1e-9, abs=1e-13)
    np.testing.assert_allclose(AxisMisalignment(M).inject(f), f @ (np.eye(3) + M).T, rtol=1e-15, atol=1e-15)


def test_nonlinearity_truth_map_is_the_inverse_models_square():
    """u = D (a + k2 a^2) inverts to a = u/D - k2 (u/D)^2 + 2 k2^2 (u/D)^3 - ...: regressing f on
    powers of u up to the fourth gives the coefficient of u^2 = -k2 / D^2 (the effect's map) to
    the series' truncation, (k2 g)^3 ~ 1e-13 relative."""
    from imurig.sensors.accelerometer import QFlexTriad
    from imurig.sensors.effects import ScaleNonlinearity

    k2 = np.array([48e-6, -30e-6, 20e-6]) / G
    tri = QFlexTriad(k1_A_per_m_s2=np.array([1.31, 1.34, 1.33]) * 1e-3 / G, k2_per_m_s2=k2,
                     scale_tempco_per_K=[1e-4, -2e-4, 5e-5])
    f, T = _positions(), 293.15
    u = tri.ideal_voltage(f, T) / tri.nominal_sensitivity_V_per_m_s2()
    truth = _triad_truth(tri, T)
    for j, a in enumerate("xyz"):
        X = np.column_stack([u[:, j] ** p for p in range(5)])
        coef, *_ = np.linalg.lstsq(X, f[:, j], rcond=None)
        assert coef[2] == pytest.approx(ScaleNonlinearity().fitted(truth, f"acc_{a}")["k2"], rel=1e-7)
    np.testing.assert_allclose(ScaleNonlinearity(k2).inject(f), f + k2 * f**2, rtol=1e-15, atol=1e-15)


def test_temperature_drift_truth_map_and_candidate():
    """f_j = u_j / D_j - b_j - kb_j dT exactly: regressing f on (1, u, V_T) of the temperature
    sensor (10 mV/K) gives -kb_j / 0.01 to machine precision; the candidate is V_T - mean, only
    where the temperature moved more than 0.2 K."""
    from imurig.sensors.accelerometer import CurrentTemperatureSensor, QFlexTriad
    from imurig.sensors.effects import ChainContext, TemperatureDrift

    kb = np.array([5e-4, -3e-4, 2e-4])
    tri = QFlexTriad(bias_m_s2=[0.01, -0.02, 0.03], k1_A_per_m_s2=np.array([1.31, 1.33, 1.35]) * 1e-3 / G,
                     bias_tempco_m_s2_per_K=kb)
    f = _positions()
    T = 298.15 + np.random.default_rng(6).uniform(-5, 5, len(f))
    u = tri.ideal_voltage(f, T) / tri.nominal_sensitivity_V_per_m_s2()
    v_T = CurrentTemperatureSensor(noise_V_rms=0.0).voltage(T, np.random.default_rng(0))
    X = np.column_stack([np.ones(len(f)), u, v_T])
    for j, a in enumerate("xyz"):
        coef, *_ = np.linalg.lstsq(X, f[:, j], rcond=None)
        assert coef[-1] == pytest.approx(TemperatureDrift().fitted({"sensors": {"accelerometers": tri.truth()}},
                                                                   f"acc_{a}")["drift"], rel=1e-9)
    eff = TemperatureDrift(kb)
    ctx = ChainContext(time_s=np.arange(len(f)), sample_rate_hz=1.0, truth_signals={"T_imu": T})
    np.testing.assert_allclose(eff.inject(f, ctx), f + kb * (T - 298.15)[:, None], rtol=1e-15, atol=1e-15)
    view = PositionView(channel="acc_x", axis="x", readings={}, channel_median={"temp_acc_y": v_T}.get)
    (cand,) = eff.candidates(view)
    np.testing.assert_array_equal(cand.design(None)[:, 0], v_T - v_T.mean())
    flat = np.full(len(f), 2.982) + np.linspace(0, 0.0019, len(f))     # 0.19 K: too little to name a drift
    assert eff.candidates(replace(view, channel_median={"temp_acc_x": flat}.get)) == []


def test_cross_coupling_is_absent_from_the_qflex_inverse_model():
    """The Q-Flex's readings are each a function of their own axis: regressing f on the inverse
    model's powers plus the product of the other two readings leaves the product's coefficient at
    the effect's truth, 0, to the series' truncation."""
    from imurig.sensors.accelerometer import QFlexTriad
    from imurig.sensors.effects import CrossCoupling

    tri = QFlexTriad(k2_per_m_s2=np.array([48e-6, -30e-6, 20e-6]) / G)
    f = _positions(120)
    u = tri.ideal_voltage(f) / tri.nominal_sensitivity_V_per_m_s2()
    X = np.column_stack([np.ones(len(f))] + [u[:, k] ** p for k in range(3) for p in range(1, 5)]
                        + [u[:, 1] * u[:, 2]])
    coef, *_ = np.linalg.lstsq(X, f[:, 0], rcond=None)
    assert abs(coef[-1] - CrossCoupling().fitted({}, "acc_x")["c"]) < 1e-12
    c = np.array([1e-4, 2e-4, 3e-4])
    expect = f + c * np.stack([f[:, 1] * f[:, 2], f[:, 0] * f[:, 2], f[:, 0] * f[:, 1]], 1)
    np.testing.assert_allclose(CrossCoupling(c).inject(f), expect, rtol=1e-15, atol=1e-15)


def test_position_candidates_follow_the_twin():
    """Misalignment and nonlinearity are offered only where the twin lacks them."""
    from imurig.sensors.effects import AxisMisalignment, ScaleNonlinearity

    view, _ = _view()
    (mis,) = AxisMisalignment().candidates(view)
    assert mis.param_names == ("m_yx", "m_yz")
    np.testing.assert_array_equal(mis.design(None), np.column_stack([view.readings["ax"], view.readings["az"]]))
    assert AxisMisalignment().candidates(replace(view, model_terms=frozenset({"ax", "az"}))) == []
    (sq,) = ScaleNonlinearity().candidates(view)
    np.testing.assert_array_equal(sq.design(None)[:, 0], view.readings["ay"] ** 2)
    assert ScaleNonlinearity().candidates(replace(view, model_terms=frozenset({"ay^2"}))) == []


# ------------------------------------------------------------------ kinematics and the converter
def test_lever_arm_is_tangential_plus_centripetal():
    """Spinning about z at w(t) = w0 + w1 t with r = (r, 0, 0): dw/dt x r = (0, w1 r, 0) and
    w x (w x r) = (-w^2 r, 0, 0), to machine precision (the rate is linear: central differences
    are exact but for their rounding); the recorded offset is the fitted dr."""
    from imurig.sensors.effects import ChainContext, LeverArm

    t = np.linspace(0.0, 2.0, 201)
    w = 0.5 + 0.3 * t
    r = 0.12
    ctx = ChainContext(time_s=t, sample_rate_hz=100.0,
                       truth_signals={"w_C_x": 0 * t, "w_C_y": 0 * t, "w_C_z": w})
    out = LeverArm([r, 0.0, 0.0]).inject(np.zeros((t.size, 3)), ctx)
    # to the rounding of the central differences, eps |w| / dt ~ 1e-14
    np.testing.assert_allclose(out, np.column_stack([-w**2 * r, np.full(t.size, 0.3 * r), 0 * t]), rtol=0, atol=1e-14)
    np.testing.assert_array_equal(LeverArm().inject(np.ones((t.size, 3)), ctx), np.ones((t.size, 3)))
    truth = {"sensors": {"accelerometers": {"position_C_m": [0.02, -0.015, 0.01]}}}
    assert LeverArm().fitted(truth) == {"dr_x_m": 0.02, "dr_y_m": -0.015, "dr_z_m": 0.01}


def test_channel_skew_is_the_first_order_time_shift():
    """A ramp x = a t sampled j / f_mux late reads a (t + j / f_mux): the skew's first-order
    shift is exact for it; the truth map is the slot over f_mux of the recorded scan."""
    from imurig.sensors.chain import DEFAULT_SCAN
    from imurig.sensors.effects import ChannelSkew

    t = np.linspace(0, 1, 11)
    a, f_mux = 3.7, 20e3
    for j in range(4):
        out = ChannelSkew().inject(a * t, ScanSlot(j, f_mux, slope_V_s=np.full(t.size, a)))
        np.testing.assert_allclose(out, a * (t + j / f_mux), rtol=1e-15, atol=1e-15)
    adc = DAQ6036E(scan_list=DEFAULT_SCAN)
    assert ChannelSkew().fitted({"chain": {"adc": adc.settings()}}, "acc_y")["tau_s"] == 2 / 20e3
    assert ChannelSkew().fitted({"chain": {"adc": replace(adc, skew_enabled=False).settings()}}, "acc_y")["tau_s"] == 0
    # the converter applies it: a ramp on slot 2 reads its value 2 / f_mux later (to the rounding)
    n = 1000
    tt = np.arange(n) / 1e3
    quiet = DAQ6036E(scan_list=("a", "b", "c"), range_V=0.05, input_noise_lsb_rms=0.0, common_mode_noise_V_rms=0.0,
                     crosstalk_enabled=False)
    x = {k: 0.01 * tt for k in "abc"}
    out, _ = quiet.convert(x, tt, np.random.default_rng(0), slope={k: np.full(n, 0.01) for k in "abc"})
    assert np.max(np.abs(out["c"] - 0.01 * (tt + 2 / 20e3))) <= quiet.lsb_V / 2 + 1e-15


# ------------------------------------------------------------------ the lab's disturbances
def _batch_se(x, batches=100):
    """Mean of x and its standard error from batch means (x correlated over << len / batches)."""
    b = np.asarray(x, float)[: len(x) // batches * batches].reshape(batches, -1).mean(axis=1)
    return float(b.mean()), float(b.std(ddof=1) / math.sqrt(batches))


def test_pump_harmonic_amplitudes_and_variance():
    """A_h = rms sqrt(2) w_h / |w| (sum A_h^2 / 2 = rms^2); the simulated vibration's power summed
    over the axes (directions are unit vectors) is 3 x the effect's per-axis variance within 4.5
    standard errors; nothing out of working hours, nothing in a long window mean."""
    from imurig.sensors.effects import ChainContext, PumpVibration

    pump = PumpVibration(rms_m_s2=0.03, broadband_rms_m_s2=0.01, modulation_hz=2.0)
    A = pump.amplitudes()
    np.testing.assert_allclose(A, 0.03 * math.sqrt(2) * np.array([1.0, 0.5]) / math.sqrt(1.25), rtol=1e-15)
    assert np.sum(A**2) / 2 == pytest.approx(0.03**2, rel=1e-14)
    fs, n = 200.0, 100_000
    t = np.arange(n) / fs
    day = ChainContext(time_s=t, sample_rate_hz=fs, hour_of_day=np.full(n, 10.0))
    # independent records (each draws its own phases, directions and envelopes): SE from their spread
    p = [np.mean(np.sum(pump.inject(np.zeros((n, 3)), day, np.random.default_rng(70 + k)) ** 2, axis=1))
         for k in range(12)]
    assert abs(np.mean(p) - 3 * pump.noise_variance(day)) < 4.5 * np.std(p, ddof=1) / math.sqrt(len(p))
    night = replace(day, hour_of_day=np.full(n, 20.0))
    assert pump.noise_variance(night) == 0.0
    assert not np.any(pump.inject(np.zeros((n, 3)), night, np.random.default_rng(7)))
    assert pump.noise_variance(replace(day, window_samples=1500)) == 0.0


def test_pump_test_and_refit_recover_a_sinusoid():
    """Positions of white noise plus a 24.7 Hz sinusoid of amplitude A (random phase each): the
    spectral test fires at the peak and the refit gives the frequency to a small fraction of a
    Welch bin, A within 4.5 standard errors, and the residual scatter down to the noise."""
    from imurig.sensors.effects import PumpVibration, ScatterView

    rng = np.random.default_rng(8)
    fs, m, n, A, sig, s = 100.0, 30, 400, 2e-3, 4e-4, 0.1
    t = np.arange(n) / fs
    x = np.concatenate([A * np.sin(2 * np.pi * 24.7 * t + rng.uniform(0, 2 * np.pi)) + sig * rng.normal(size=n)
                        for _ in range(m)])
    view = ScatterView("acc_x", x, [slice(i * n, (i + 1) * n) for i in range(m)], fs, np.full(m, 10.0), s)
    res = PumpVibration().test(view)
    fd = res["finding"]
    assert res["spectral_peak_to_median"] > 25 and fd["positions_affected"] == m
    assert abs(fd["refit_frequency_hz"] - 24.7) < 0.01 * fs / 256
    assert abs(fd["amplitude_V"] - A) < 4.5 * fd["amplitude_se_V"]
    assert fd["amplitude_m_s2"] == pytest.approx(fd["amplitude_V"] / s, rel=1e-15)
    assert fd["scatter_before_V"] == pytest.approx(math.sqrt(A**2 / 2 + sig**2), rel=0.05)
    assert fd["scatter_after_V"] == pytest.approx(sig, rel=0.05)
    quiet = replace(view, samples=sig * rng.normal(size=m * n))
    assert "finding" not in PumpVibration().test(quiet)


def test_people_transients_variance_is_shot_noise():
    """Per-axis variance of one sample p peak^2 / 3 sum h^2 and of a long window mean
    p peak^2 / 3 H(1)^2 / N against the simulated transients (sum over the three axes, 4.5 SE)."""
    from imurig.sensors.effects import ChainContext, PeopleTransients

    people = PeopleTransients(rate_per_hour_working=3600.0 * 5)    # 5 events per second by day
    fs, n = 100.0, 2_000_000
    ctx = ChainContext(time_s=np.arange(n) / fs, sample_rate_hz=fs, hour_of_day=np.full(n, 10.0))
    f = people.inject(np.zeros((n, 3)), ctx, np.random.default_rng(9))
    m, se = _batch_se(np.sum(f**2, axis=1))
    assert abs(m - 3 * people.noise_variance(ctx)) < 4.5 * se
    N = 2000  # 20 s windows, 65 decay times: the long-window limit holds to ~tau fs / N = 1.5 %
    w = f[: n // N * N].reshape(-1, N, 3).mean(axis=1)
    s2 = np.sum(w**2, axis=1)
    expect = 3 * people.noise_variance(replace(ctx, window_samples=N))
    assert abs(s2.mean() - expect) < 4.5 * s2.std(ddof=1) / math.sqrt(s2.size)
    assert people.impulsive and people.noise_variance(replace(ctx, sample_rate_hz=20.0)) == 0.0


def test_loose_cable_spikes_variance_and_test():
    """Spike lengths max(1, floor(U f_s)) have the moments the effect states (4.5 SE); the line's
    per-sample variance p amplitude^2 E[L] against a simulated record; the spike test counts
    spikes > 8 robust sigma and names the effect from three."""
    from imurig.sensors.effects import ChainContext, LooseCable, ScatterView

    cable = LooseCable(enabled=True, rate_hz=2.0, min_duration_s=0.0023, max_duration_s=0.0517)
    fs = 1000.0
    U = np.random.default_rng(10).uniform(cable.min_duration_s, cable.max_duration_s, 1_000_000)
    L = np.maximum(1, (U * fs).astype(int)).astype(float)
    m1, m2 = cable.length_moments(fs)
    assert abs(L.mean() - m1) < 4.5 * L.std() / 1e3 and abs(np.mean(L**2) - m2) < 4.5 * np.std(L**2) / 1e3
    n = 4_000_000
    ctx = ChainContext(time_s=np.arange(n) / fs, sample_rate_hz=fs)
    assert cable.lines(["acc_x", "acc_y"], ctx) == ["acc_y"]
    with pytest.raises(ValueError, match="not an analog line"):
        cable.lines(["acc_x"], ctx)
    v = cable.inject(np.zeros(n), ctx, np.random.default_rng(11))
    mv, se = _batch_se(v**2, batches=400)
    assert abs(mv - cable.noise_variance(ctx)) < 4.5 * se
    rng = np.random.default_rng(12)
    x = 1e-4 * rng.normal(size=20 * 400)
    view = ScatterView("acc_y", x, [slice(i * 400, (i + 1) * 400) for i in range(20)], 100.0, np.full(20, 20.0))
    assert "finding" not in cable.test(view) and cable.test(view)["spikes_total"] == 0
    x[[50, 1234, 5000]] += 0.01
    res = cable.test(replace(view, samples=x))
    assert res["finding"]["spikes"] == 3 and res["finding"]["positions"] == 3
    assert res["robust_sigma_V"] == pytest.approx(1e-4, rel=0.05)
# ------------------------------------------------------------------ turn table, rate rows, thermal, magnetometer
from imurig.kernel.site import EARTH_RATE_RAD_S, Site  # noqa: E402
from imurig.kernel.units import T_REF_K  # noqa: E402
from imurig.sensors.effects import (EarthRateLeftOut, GSensitivity, GyroRowDrift, GyroScaleNonlinearity,  # noqa: E402
                                    HardIron, InstrumentRangeChange, LocalFieldAnomaly, MagMisalignment,
                                    MagScaleNonlinearity, MagTemperatureDrift, MagTimeDelay, MagTimeDrift, MagView,
                                    MainsRateFactor, RateProportionalError, RateRowView, RateShortfallView,
                                    SlipRingNoise, SoftIron, TableSlip, TemperatureHysteresis, ThermalView,
                                    TimerQuantisation, TurnSampleView, TurnView, VoltmeterRowView, for_view)
from imurig.sensors.effects.base import ChainContext  # noqa: E402
from imurig.sensors.effects.views import across_field  # noqa: E402
from imurig.sensors.gyro import FOGTriad  # noqa: E402


def _mag_view(nb=40, twin_model="nominal", temperature=True, seed=5):
    rng = np.random.default_rng(seed)
    R = np.stack([np.linalg.qr(rng.normal(size=(3, 3)))[0] for _ in range(nb)])
    R *= np.sign(np.linalg.det(R))[:, None, None]
    B_W = np.array([0.0, 18_000.0, -45_000.0])
    B = np.einsum("nij,j->ni", R, B_W)
    return MagView(twin_model=twin_model, field_nT=B, rate_nT_s=rng.normal(0, 50, (nb, 3)), R_CW=R,
                   time_s=np.arange(nb, dtype=float), igrf_W_nT=B_W, calibration=np.diag([1.01, 0.99, 1.02]),
                   temperature_K=295 + np.linspace(0, 3, nb) if temperature else None)


def _views():
    """One synthetic view of every kind the turn-table, rate-row, thermal and magnetometer effects serve."""
    rng = np.random.default_rng(4)
    r = np.linspace(1.0, 100.0, 20)
    e = np.repeat([1.0, 0.0, -1.0], 4)
    return [(TurnView("gyro_p", "p", on_axis=e, specific_force_m_s2=9.8 * e + rng.normal(0, 0.1, 12),
                      earth_rate_in_twin=False), 12),
            (RateShortfallView(r), 20), (RateRowView("gyro_p", r, first_rows=(5, 6, 7)), 20),
            (VoltmeterRowView(("p", "q", "r"), r, first_rows=(5, 6), scale_V_per_dps=(5e-3, 5.1e-3, 4.9e-3)), 60),
            (ThermalView("acc_x", "m/s^2", branch=np.tile([0.5, -0.5], 8)), 16),
            (_mag_view(), 120), (_mag_view(twin_model="calibrated"), 120)]


@pytest.mark.parametrize("view,m", _views(), ids=lambda v: getattr(v, "kind", str(v)))
def test_new_views_candidates_have_one_row_per_observation(view, m):
    """Every effect offered for a view kind gives columns with one row per observation and one
    column per parameter at every scan value, under the name the diagnosis reports it by."""
    cands = [c for cls in for_view(view.kind) for c in cls().candidates(view)]
    assert cands
    names = {cls.finding_name() for cls in for_view(view.kind)}
    for cand in cands:
        assert cand.name in names
        for th in cand.scan:
            assert cand.design(th).shape == (m, len(cand.param_names))


def test_candidates_follow_the_twin():
    """The Earth's rate only for a twin without it; hard and soft iron and misalignment only for the
    nominal (gains-only) magnetometer twin; the fluxgate's temperature drift only where T moved."""
    v = _views()[0][0]
    assert EarthRateLeftOut().candidates(replace(v, earth_rate_in_twin=True)) == []
    np.testing.assert_array_equal(EarthRateLeftOut().candidates(v)[0].design(None)[:, 0], -v.on_axis)
    np.testing.assert_array_equal(GSensitivity().candidates(v)[0].design(None)[:, 0], -v.specific_force_m_s2)
    cal = _mag_view(twin_model="calibrated")
    assert [c.name for cls in for_view(MagView.kind) for c in cls().candidates(cal)] == \
        ["local_field_anomaly", "temperature_drift", "time_drift", "scale_nonlinearity", "time_delay"]
    assert MagTemperatureDrift().candidates(_mag_view(temperature=False)) == []
    flat = replace(_mag_view(), temperature_K=np.full(40, 300.0) + np.linspace(0, 0.15, 40))
    assert MagTemperatureDrift().candidates(flat) == []


def test_g_sensitivity_in_the_gyro_model_and_its_truth_map():
    """The FOG adds G f_C through the effect (machine precision); with a diagonal G the twin's
    residual against the candidate column -f gives back G_jj, the effect's truth map."""
    G = np.diag([3e-5, -2e-5, 1e-5]) + 1e-6
    g = FOGTriad(scale_V_per_rad_s=[0.3, 0.34, 0.35], g_sensitivity_rad_s_per_m_s2=G)
    rng = np.random.default_rng(0)
    w, f = rng.normal(0, 0.5, (30, 3)), rng.normal(0, 9.8, (30, 3))
    np.testing.assert_allclose(g.ideal_voltage(w, f_C=f), g.scale_V_per_rad_s * (w + f @ G.T), rtol=1e-14)
    ctx = ChainContext(time_s=np.arange(30.0), sample_rate_hz=1.0, truth_signals={f"f_C_{a}": f[:, j]
                                                                                 for j, a in enumerate("xyz")})
    np.testing.assert_allclose(GSensitivity(G).inject(w, ctx), w + f @ G.T, rtol=0, atol=1e-15)
    g = replace(g, g_sensitivity_rad_s_per_m_s2=np.diag(np.diag(G)))  # the diagnosis fits the diagonal
    truth = {"sensors": {"gyros": g.truth()}}
    for j, a in enumerate("pqr"):
        u = g.ideal_voltage(w, f_C=f)[:, j] / g.scale_V_per_rad_s[j]  # the indicated rate; the reference is w
        col = GSensitivity().candidates(TurnView(f"gyro_{a}", a, np.zeros(30), f[:, j]))[0].design(None)
        coef = np.linalg.lstsq(col, w[:, j] - u, rcond=None)[0][0]
        assert coef == pytest.approx(GSensitivity().fitted(truth, f"gyro_{a}")["G"], rel=1e-9)


def test_earth_rate_truth_map_is_the_sites_vertical_rate():
    for lat in (0.0, 30.0, 52.0, 80.0):
        site = Site(latitude_deg=lat)
        truth = {"conditions": {"site": site.to_dict()}}
        assert EarthRateLeftOut().fitted(truth)["Omega_vertical"] == pytest.approx(site.earth_rate_W()[2],
                                                                                   rel=1e-15, abs=1e-25)
    e = np.array([1.0, 0.0, -1.0])
    eff = EarthRateLeftOut(latitude_rad=math.radians(52.0))
    np.testing.assert_allclose(eff.inject(np.zeros(3), TurnView("gyro_r", "r", e, e)),
                               e * EARTH_RATE_RAD_S * math.sin(math.radians(52.0)), rtol=1e-15)


def test_table_rate_law_and_its_truth_maps():
    """The rig's table applies the effects' law (machine precision); the shortfall d of the slipping
    table against the column r^-alpha gives -s1 to first order in the slip (|error| < 2 alpha s_max)."""
    from imurig.rigs.turn_table import TurnTableErrors

    e = TurnTableErrors()
    dial = np.array([1.0, 2.0, 4.0, 8.0, 10.0, 20.0, 40.0, 80.0, 100.0])
    slip, mains = TableSlip(e.slip_const, e.slip_coeff, e.slip_exp), MainsRateFactor(e.mains_hz, e.motor_design_hz)
    np.testing.assert_array_equal(e.slip(dial), slip.shortfall(dial * mains.factor))
    assert e.mains_factor == mains.factor == 5 / 6
    np.testing.assert_allclose(e.true_rate_dps(dial), slip.inject(mains.inject(dial)), rtol=1e-15)
    truth = {"turn_table": e.to_dict()}
    assert MainsRateFactor().fitted(truth) == {"factor": 5 / 6}
    r = slip.inject(mains.inject(dial))
    d = r / (mains.factor * dial) - 1
    (cand,) = slip.candidates(RateShortfallView(r))
    coef = np.linalg.lstsq(np.column_stack([np.ones(dial.size), cand.design(e.slip_exp)]), d, rcond=None)[0]
    s1 = slip.fitted(truth)["s1"]
    assert abs(coef[1] / s1 - 1) < 2 * e.slip_exp * slip.shortfall(dial * mains.factor).max()
    rp = RateProportionalError(c_per_dps=2e-5)
    (cand,) = rp.candidates(RateShortfallView(dial))
    np.testing.assert_allclose(rp.inject(dial), dial * (1 + 2e-5 * cand.design(None)[:, 0]), rtol=1e-15)
    assert rp.fitted(truth) == {"c": 0.0}


def test_timer_quantisation_through_the_effect():
    """EventTimer measures through the effect (same draws, machine precision); a round time's error
    has variance q^2/6 + 2 jitter^2 within 4.5 standard errors; the truth maps."""
    from imurig.sensors.timers import EventTimer, gps_mark_timer

    t = np.cumsum(np.random.default_rng(1).uniform(3.0, 4.0, 200_001))
    tm = gps_mark_timer()
    eff = TimerQuantisation(tm.resolution_s, tm.jitter_s, tm.latency_s)
    np.testing.assert_array_equal(tm.measure(t, np.random.default_rng(2)), eff.inject(t, None, np.random.default_rng(2)))
    coarse = EventTimer("adc", resolution_s=1e-3)
    err = np.diff(coarse.measure(t, np.random.default_rng(3))) - np.diff(t)
    var, m4 = np.var(err), np.mean((err - err.mean()) ** 4)
    assert abs(var - coarse.effect().round_time_variance_s2()) < 4.5 * math.sqrt((m4 - var**2) / err.size)
    assert TimerQuantisation().fitted({"timer": {"resolution_s": 0.01}})["sigma_T_s"] == 0.01 / math.sqrt(12)
    chain = {"chain": {"timers": {"gps_mark": tm.settings()}}}
    assert TimerQuantisation().fitted(chain, "gps_mark")["sigma_T_s"] == pytest.approx(
        math.sqrt(tm.resolution_s**2 / 6 + 2 * tm.jitter_s**2), rel=1e-15)


def test_range_change_nonlinearity_and_drift_recovered_exactly():
    """Noise-free appendix-B rows: the voltmeter's range change (joint over the gyros), and each
    gyro's k2 and a drift in row order, are recovered by the nominal model plus the effects' columns
    to machine precision and equal the truth maps."""
    r = np.geomspace(1.0, 100.0, 24)  # rows in rising rate, not linear in the row index
    k, step = 15, -0.006
    SF = np.array([5.4e-3, 5.5e-3, 5.3e-3]) * 180 / math.pi  # V per rad/s
    w = np.radians(r)[:, None] * np.ones(3)
    truth = {"voltmeter": {"gain": [1.0, 1.0 + step, 1.0 + step]}}
    rc = InstrumentRangeChange(first_row=k, gain_step=step, offset_step_V=2e-4)
    V = FOGTriad(scale_V_per_rad_s=SF).ideal_voltage(w)
    Vs = np.column_stack([rc.inject(V[:, j]) for j in range(3)])
    jv = VoltmeterRowView(("p", "q", "r"), r, first_rows=(k,), scale_V_per_dps=tuple(SF * math.radians(1.0)))
    X0 = np.zeros((72, 6))
    for j in range(3):
        X0[j * 24:(j + 1) * 24, 2 * j], X0[j * 24:(j + 1) * 24, 2 * j + 1] = 1.0, r
    (cand,) = rc.candidates(jv)
    coef = np.linalg.lstsq(np.column_stack([X0, cand.design(k)]), Vs.T.reshape(-1), rcond=None)[0]
    assert coef[6] == pytest.approx(rc.fitted(truth)["relative_gain_step"], rel=1e-9)
    assert coef[7] == pytest.approx(2e-4, rel=1e-9)

    g = FOGTriad(scale_V_per_rad_s=SF, k2_per_rad_s=[4e-4, -3e-4, 2e-4])
    V = g.ideal_voltage(w)
    view = RateRowView("gyro_p", r, first_rows=(k,))
    for j, a in enumerate("pqr"):
        y = GyroRowDrift(drift_V_per_row=3e-5).inject(V[:, j])
        X = np.column_stack([np.ones(24), r] + [c.design(k) for cls in (GyroScaleNonlinearity, GyroRowDrift)
                                                for c in cls().candidates(view)])
        c = np.linalg.lstsq(X, y, rcond=None)[0]
        assert c[2] == pytest.approx(GyroScaleNonlinearity().fitted({"gyros": g.truth()}, a)["k2"], rel=1e-9)
        assert c[3] == pytest.approx(3e-5, rel=1e-9)
    assert GyroRowDrift().fitted(truth) == {"drift": 0.0}
    np.testing.assert_allclose(GyroScaleNonlinearity(g.k2_per_rad_s).inject(w), w + g.k2_per_rad_s * w**2, rtol=1e-15)


def test_temperature_hysteresis_gap_in_the_six_position_bias():
    """A Q-Flex with a bias hysteresis Hb: the six-position mean of the indicated readings on the
    heating branch (h = +1/2) less the cooling branch (h = -1/2) is D (1 + ks dT) Hb, the effect's
    truth map, to machine precision; the candidate is the branch sign; inject adds Hb h."""
    from imurig.sensors.accelerometer import QFlexTriad

    acc = QFlexTriad(bias_m_s2=[1e-3, -2e-3, 5e-4], k1_A_per_m_s2=np.array([1.01, 0.99, 1.003]) * 1.33e-3 / 9.80665,
                     k2_per_m_s2=[1e-5, -2e-5, 3e-6], scale_tempco_per_K=[1e-4, -2e-4, 5e-5],
                     bias_hysteresis_m_s2=[5e-3, -3e-3, 2e-3])
    g = 9.80665
    six = np.vstack([np.eye(3), -np.eye(3)]) * g
    T = 283.15
    truth = {"sensors": {"accelerometers": acc.truth()}, "conditions": {"mean_temperature_K": T}}
    bias = {h: (acc.ideal_voltage(six, np.full(6, T), np.full(6, h)) / acc.nominal_sensitivity_V_per_m_s2()).mean(0)
            for h in (0.5, -0.5)}
    for j, a in enumerate("xyz"):
        assert bias[0.5][j] - bias[-0.5][j] == pytest.approx(TemperatureHysteresis().fitted(truth, f"acc_{a}")["H"],
                                                             rel=1e-9)
    assert TemperatureHysteresis().fitted(truth, "gyro_p") == {"H": 0.0}
    s = np.tile([0.5, -0.5], 5)
    (cand,) = TemperatureHysteresis().candidates(ThermalView("acc_x", "m/s^2", s))
    np.testing.assert_array_equal(cand.design(None)[:, 0], s)
    h = np.linspace(-0.5, 0.5, 7)
    ctx = ChainContext(time_s=np.arange(7.0), sample_rate_hz=1.0, truth_signals={"h_acc": h})
    np.testing.assert_allclose(TemperatureHysteresis([1.0, 2.0, 3.0]).inject(np.zeros((7, 3)), ctx),
                               h[:, None] * [1.0, 2.0, 3.0], rtol=1e-15)


def test_slip_ring_profile_once_per_record_and_noise_variance():
    """The profile is computed once per angle record and reused for every line (the same draws as
    rms P n); the per-sample variance rms^2 <P^2> holds within 4.5 SE."""
    eff = SlipRingNoise(rms_V=20e-6)
    ang = np.mod(np.linspace(0.0, 40 * np.pi, 200_000), 2 * np.pi)
    P = eff.profile(ang)
    assert eff.profile(ang) is P                       # cached for the record
    assert eff.profile(ang.copy()) is not P            # a different record is computed afresh
    ctx = ChainContext(time_s=np.arange(ang.size) / 1e3, sample_rate_hz=1e3, truth_signals={"spin_angle": ang})
    v = eff.inject(np.zeros_like(ang), ctx, np.random.default_rng(7))
    np.testing.assert_array_equal(v, 20e-6 * P * np.random.default_rng(7).standard_normal(ang.size))
    var, m4 = np.mean(v**2), np.mean(v**4)
    assert abs(var - eff.noise_variance(ctx)) < 4.5 * math.sqrt((m4 - var**2) / v.size)
    assert eff.round_average_variance_V2() == pytest.approx(eff.noise_variance(ctx), rel=1e-3)
    assert SlipRingNoise(enabled=False).noise_variance(ctx) == 0.0


def test_slip_ring_test_and_refit_against_the_truth_map():
    """A turning table (1 kHz, 60 deg/s) with white line noise and slip-ring noise, the fast residual
    taken as the diagnosis takes it: the test fires, flags the rough spots, and the refit's peak
    excess noise lies within 4 SE of the truth map; without the rings the test stays quiet."""
    from scipy import ndimage

    rng = np.random.default_rng(11)
    t = np.arange(600_000) / 1000.0
    ang = np.mod(math.radians(60.0) * t, 2 * np.pi)
    eff = SlipRingNoise()
    h = eff.window // 2

    def view(rings):
        x = 60e-6 * rng.standard_normal(t.size) + rings.voltage(ang, rng)
        r = x - ndimage.uniform_filter1d(x, eff.window, mode="nearest")
        return TurnSampleView("gyro_p", ang[h:-h], r[h:-h], alpha=0.01)

    assert "finding" not in SlipRingNoise().test(view(SlipRingNoise(enabled=False)))
    f = eff.test(view(eff))["finding"]
    est, se = f["parameters"][0]["estimate"], f["parameters"][0]["std_error"]
    truth = {"chain": {"slip_rings": eff.settings()}}
    assert abs(est - eff.fitted(truth, "gyro_p")["peak_excess_noise_rms_V"]) < 4 * se, (est, se)
    spots = np.degrees(eff.spots_rad)
    assert all(np.min(np.abs((np.array(f["angles_deg"]) - s_ + 180) % 360 - 180)) <= 10 for s_ in spots)


def test_fluxgate_measurement_equation_through_its_effects():
    """The fluxgate model composes misalignment, soft iron, hard iron and the new temperature term:
    V = s (S (I + M) B + b + c (T - T_ref)) to machine precision, each part the effect's inject."""
    from imurig.sensors.magnetometer import FluxgateTriad

    rng = np.random.default_rng(3)
    S = np.eye(3) + 0.01 * np.array([[0.0, 1.0, -0.6], [1.0, 0.0, 0.4], [-0.6, 0.4, 0.0]])
    M = 1e-3 * np.array([[0.0, 1.0, -2.0], [-1.0, 0.0, 0.5], [2.0, -0.5, 0.0]])
    c = np.array([2e-9, -1e-9, 1.5e-9])
    mag = FluxgateTriad(sensitivity_V_per_T=[4.1e4, 3.9e4, 4.0e4], hard_iron_T=[1e-6, -2e-6, 5e-7], soft_iron=S,
                        misalignment_rad=M, noise_T_rms=0.0, tempco_T_per_K=c)
    B, T = rng.normal(0, 3e-5, (50, 3)), 290.0 + rng.uniform(0, 10, 50)
    expect = (B @ (S @ (np.eye(3) + M)).T + mag.hard_iron_T + (T - T_REF_K)[:, None] * c) * mag.sensitivity_V_per_T
    np.testing.assert_allclose(mag.output_voltage(B, rng, T), expect, rtol=1e-12)
    ctx = ChainContext(time_s=np.arange(50.0), sample_rate_hz=1.0, truth_signals={"T_box": T})
    parts = MagTemperatureDrift(c).inject(HardIron(mag.hard_iron_T).inject(SoftIron(S).inject(
        MagMisalignment(M).inject(B))), ctx)
    np.testing.assert_allclose(parts * mag.sensitivity_V_per_T, expect, rtol=1e-12)
    np.testing.assert_array_equal(mag.output_voltage(B, rng), replace(mag, tempco_T_per_K=np.zeros(3))
                                  .output_voltage(B, rng, T))  # no temperature term without a tempco
    truth = {"sensors": {"magnetometer": mag.truth()}}
    gain = mag.sensitivity_V_per_T / 4.0e4
    assert HardIron().fitted(truth)["b_y_nT"] == pytest.approx(gain[1] * -2e-6 * 1e9, rel=1e-15)
    assert SoftIron().fitted(truth) == {"s_xy": S[0, 1], "s_xz": S[0, 2], "s_yz": S[1, 2]}
    assert MagMisalignment().fitted(truth)["w_xz_rad"] == M[0, 2]
    assert MagTemperatureDrift().fitted(truth)["c_z_nT_per_K"] == pytest.approx(gain[2] * c[2] * 1e9, rel=1e-15)


def test_magnetometer_columns_recover_the_truth_maps_exactly():
    """Indicated block means from the field with an offset drift with temperature (and a hard iron),
    or from an IGRF field plus a local anomaly: the twin's model plus the effects' columns recover
    the truth maps to machine precision (the anomaly's along-field part absorbed by the gains)."""
    v = _mag_view()
    nb = v.n_blocks
    gain = np.diag(v.calibration)
    c_T, b_T = np.array([2e-9, -1e-9, 1.5e-9]), np.array([3e-7, -1e-7, 2e-7])
    truth = {"sensors": {"magnetometer": {"sensitivity_V_per_T": list(gain * 4e4), "nominal_sensitivity_V_per_T": 4e4,
                                          "hard_iron_T": list(b_T), "tempco_T_per_K": list(c_T)}}}
    m = gain * (v.field_nT + 1e9 * (b_T + (v.temperature_K - T_REF_K)[:, None] * c_T))
    X0 = np.column_stack([v.on_axis(j, v.field_nT[:, j]) for j in range(3)])
    C = [cand.design(None) for cls in (HardIron, MagTemperatureDrift) for cand in cls().candidates(v)]
    coef = np.linalg.lstsq(np.column_stack([X0] + C), v.stacked(m), rcond=None)[0]
    np.testing.assert_allclose(coef[6:9], list(MagTemperatureDrift().fitted(truth).values()), rtol=1e-8)

    B_W = v.igrf_W_nT * 1e-9
    u1, u2 = across_field(B_W)
    dB = 300e-9 * u1 - 200e-9 * u2 + 500e-9 * B_W / np.linalg.norm(B_W)
    truth = {"magnetometer_diagnosis": {"anomaly_W_T": list(dB), "igrf_field_W_T": list(B_W)}}
    m = np.einsum("nij,j->ni", v.R_CW, LocalFieldAnomaly(dB).inject(B_W)) * 1e9
    a = 1 + dB @ B_W / np.linalg.norm(B_W) ** 2
    cal = replace(v, twin_model="calibrated", calibration=a * np.eye(3))
    X0 = np.column_stack([cal.on_axis(j, cal.field_nT[:, k]) for j in range(3) for k in range(3)]
                         + [cal.on_axis(j, np.ones(nb)) for j in range(3)])
    (cand,) = LocalFieldAnomaly().candidates(cal)
    coef = np.linalg.lstsq(np.column_stack([X0, cand.design(None)]), cal.stacked(m), rcond=None)[0]
    np.testing.assert_allclose(coef[12:], list(LocalFieldAnomaly().fitted(truth).values()), rtol=1e-6)


def test_magnetometer_delay_drift_and_nonlinearity_closed_form():
    """The delay shifts a ramp by -rate tau inside a block; the drift and the nonlinearity add
    d (t - t0) and k2 B^2; the truth maps of what no chain injects are zero."""
    t = np.arange(200) / 100.0
    x = np.column_stack([3.0 + 2.0 * t, -1.0 * t, 0.5 * t])
    ctx = ChainContext(time_s=t, sample_rate_hz=100.0)
    y = MagTimeDelay(0.05).inject(x, ctx)
    np.testing.assert_allclose(y[10:], x[10:] - 0.05 * np.array([2.0, -1.0, 0.5]), rtol=0, atol=1e-12)
    assert MagTimeDelay().fitted({"magnetometer_diagnosis": {"delay_s": 2e-3}}) == {"tau_s": 2e-3}
    np.testing.assert_allclose(MagTimeDrift([1e-9, 0, -1e-9]).inject(np.zeros((200, 3)), ctx)[:, 0], 1e-9 * t,
                               rtol=1e-15)
    np.testing.assert_allclose(MagScaleNonlinearity([1e3, 0, 0]).inject(x)[:, 0], x[:, 0] + 1e3 * x[:, 0] ** 2,
                               rtol=1e-15)
    assert set(MagTimeDrift().fitted({}).values()) == {0.0} == set(MagScaleNonlinearity().fitted({}).values())
