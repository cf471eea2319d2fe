"""The independent lab's rate table with a three-gyro package on it, logged as a time series.

The dial is set by hand in steps (ramped over ``ramp_s``). The table's synchronous motor turns at
``mains_hz / design_hz`` of the dial, its ball-and-disc integrator slips (a shortfall
``s1 (r / 1 deg/s)^-alpha`` of the rate r, appendix B's 1-8 %), and the motor follows the dial
with a first-order lag ``tau_motor_s``:

    omega_table = dial * factor * (1 - s1 |dial factor|^-alpha)   (lagged),
    psi(t) = integral omega_table dt                              (table angle from the index).

The package sits z up on the table; each gyro j puts out ``u_j = b_j + S_j w_j + n_j`` (V) with

    w = (W_N cos psi', -W_N sin psi', omega_table + W_U),  W_N = W_E cos(lat), W_U = W_E sin(lat),

psi' = psi + psi0 (the index's heading), S_j in V/(deg/s). An optical index puts a
``pulse_high_V`` level on the pulse channel for ``pulse_width_s`` each time psi passes a
whole turn (the pulse's own jitter only with the timer effect). Concealed effects: ``EFFECTS``.
"""
from __future__ import annotations

import math

import numpy as np

from .lab import CONVERTERS, LAB_SITE, OMEGA_EARTH, time_tags, white

S_NOMINAL = 5.4e-3                 # V/(deg/s), appendix B's gyros
EFFECTS = ("mains_rate_factor", "table_slip", "timer_quantisation", "slip_ring_noise")
DIAL_DPS = (15.0, 30.0, 60.0, 120.0, 240.0, -15.0, -30.0, -60.0, -120.0, -240.0)


def dial_knots(dial_dps=DIAL_DPS, rounds: float = 3.0, min_hold_s: float = 8.0, ramp_s: float = 3.0,
               rest_s: float = 5.0):
    """Knot times and dial values: rest at 0, then per step a ramp and a hold of >= ``rounds`` turns."""
    t, v, now = [0.0, rest_s], [0.0, 0.0], rest_s
    for d in dial_dps:
        now += ramp_s
        hold = max(min_hold_s, rounds * 360.0 / abs(d) * 1.1)
        t += [now, now + hold]
        v += [d, d]
        now += hold
    t += [now + ramp_s, now + ramp_s + rest_s]
    v += [0.0, 0.0]
    return np.array(t), np.array(v)


def lagged(x: np.ndarray, fs_hz: float, tau_s: float) -> np.ndarray:
    """First-order lag y' = (x - y) / tau on the sample grid (exact for a held input)."""
    a = math.exp(-1.0 / (fs_hz * tau_s))
    y = np.empty_like(x)
    acc = x[0]
    for i, xi in enumerate(x):     # plain loop: 1e5..1e6 samples, a few tenths of a second
        acc = a * acc + (1 - a) * xi
        y[i] = acc
    return y


def crossing_times(t_s: np.ndarray, psi_deg: np.ndarray) -> np.ndarray:
    """Times where the table angle psi passes the index mark (a whole turn), in either direction
    (linear between samples)."""
    turns = np.floor(psi_deg / 360.0)
    idx = np.nonzero(np.diff(turns) != 0)[0]
    level = np.maximum(turns[idx], turns[idx + 1]) * 360.0
    frac = (level - psi_deg[idx]) / (psi_deg[idx + 1] - psi_deg[idx])
    return t_s[idx] + frac * (t_s[idx + 1] - t_s[idx])


def pulse_train(t_s: np.ndarray, t_pulse: np.ndarray, width_s: float, high_V: float) -> np.ndarray:
    """``high_V`` on samples t in [t_k, t_k + width), 0 V elsewhere."""
    out = np.zeros_like(t_s)
    fs = 1.0 / (t_s[1] - t_s[0])
    for tk in t_pulse:
        i0 = int(math.ceil(tk * fs - 1e-9))
        i1 = int(math.ceil((tk + width_s) * fs - 1e-9))
        out[max(i0, 0):max(i1, 0)] = high_V
    return out


def record(seed: int, effect: str | None, fs_hz: float, converter: str) -> tuple[dict, dict, dict]:
    """One turn-table recording: (columns, column steps, manifest)."""
    rng = np.random.default_rng(seed)
    adc = CONVERTERS[converter]
    knots_t, knots_v = dial_knots()
    t = time_tags(int(knots_t[-1] * fs_hz), fs_hz)
    dial = np.interp(t, knots_t, knots_v)
    eff: list[dict] = []
    factor, s1, alpha = 1.0, 0.0, 0.7
    if effect == "mains_rate_factor":
        factor = 50.0 / 60.0
        eff.append({"effect": effect, "channel": "rate", "parameters": {"factor": factor, "mains_hz": 50.0,
                                                                        "motor_design_hz": 60.0},
                    "score": {"name": "factor", "value": factor}, "expected": ["rate:mains_rate_factor"]})
    if effect == "table_slip":
        s1 = 0.03
        eff.append({"effect": effect, "channel": "rate", "parameters": {"s1": -s1, "alpha": alpha, "s0": 0.0},
                    "score": {"name": "s1", "value": -s1}, "expected": ["rate:table_slip"],
                    "note": "s1 as the library fits it: the coefficient of r^-alpha in the rate error (-slip)"})
    r = np.abs(dial * factor)
    shortfall = np.where(r > 0.5, s1 * np.maximum(r, 0.5) ** -alpha, 0.0)
    omega_dps = lagged(dial * factor * (1 - shortfall), fs_hz, 0.3)
    psi = np.concatenate([[0.0], np.cumsum(0.5 * (omega_dps[1:] + omega_dps[:-1]) / fs_hz)])
    lat = math.radians(LAB_SITE["latitude_deg"])
    wN, wU = math.degrees(OMEGA_EARTH * math.cos(lat)), math.degrees(OMEGA_EARTH * math.sin(lat))
    psi0 = rng.uniform(0, 2 * np.pi)
    w = np.column_stack([wN * np.cos(np.radians(psi) + psi0), -wN * np.sin(np.radians(psi) + psi0), omega_dps + wU])
    S = S_NOMINAL * (1 + 0.01 * rng.standard_normal(3))
    b = 0.002 * rng.standard_normal(3)
    sigma = 16e-6 * math.sqrt(fs_hz / 2)          # 0.003 deg/s/rtHz times S
    u = b + S * w + np.column_stack([white(rng, t.size, sigma) for _ in range(3)])
    if effect == "slip_ring_noise":
        amp, harm = np.array([60e-6, 40e-6, 80e-6]), 3
        ph = rng.uniform(0, 2 * np.pi, 3)
        u += amp * np.sin(harm * np.radians(psi)[:, None] + ph)
        eff.append({"effect": effect, "channel": "gyro", "parameters": {"ripple_amplitude_V": amp.tolist(),
                                                                        "harmonic_per_turn": harm,
                                                                        "phase_rad": ph.tolist()},
                    "score": {"name": "ripple_amplitude_V", "value": float(amp[0]), "channel": "gyro_x"},
                    "expected": [f"gyro_{a}:slip_ring_noise" for a in "xyz"],
                    "note": "a deterministic ripple locked to the table angle (contact resistance), not noise"})
    t_pulse = crossing_times(t, psi)
    jitter = 0.0
    if effect == "timer_quantisation":
        jitter = 4e-3
        t_pulse = t_pulse + jitter * rng.standard_normal(t_pulse.size)
    width = max(0.02, 1.5 / fs_hz)
    if effect == "timer_quantisation":
        sig = math.sqrt(jitter ** 2 + (1 / fs_hz) ** 2 / 12)
        eff.append({"effect": effect, "channel": "rate", "parameters": {"jitter_s": jitter, "resolution_s": 1 / fs_hz,
                                                                        "sigma_T_s": sig},
                    "score": {"name": "sigma_T_s", "value": sig}, "expected": ["rate:timer_quantisation"],
                    "note": "the index detector's edge jitters; the sample clock's grid is always there"})
    pulse = pulse_train(t, t_pulse, width, 4.8) + white(rng, t.size, 2e-4)
    V = adc.read(np.column_stack([u, pulse]), rng)
    cols = {"time_s": t, "rate_dps": np.round(dial, 3), "gyro_x_V": V[:, 0], "gyro_y_V": V[:, 1],
            "gyro_z_V": V[:, 2], "pulse_V": V[:, 3]}
    steps = {"time_s": 1e-7 if fs_hz != int(fs_hz) else 1e-4, "rate_dps": 1e-3, "gyro_x_V": adc.step_V,
             "gyro_y_V": adc.step_V, "gyro_z_V": adc.step_V, "pulse_V": adc.step_V}
    truth = {"rig": "turn_table", "seed": seed, "fs_hz": fs_hz, "adc": adc.as_dict(), "adc_name": converter,
             "site": LAB_SITE, "gyros": {"S_V_per_dps": S.tolist(), "bias_V": b.tolist(), "noise_V_rms_per_sample": sigma,
                                         "axes": "z on the table axis, up"},
             "table": {"factor": factor, "slip_s1": s1, "slip_alpha": alpha, "motor_lag_s": 0.3,
                       "index_heading_rad": psi0, "pulse_width_s": width, "pulse_jitter_s": jitter,
                       "n_pulses": int(t_pulse.size)},
             "effects": eff, "null": effect is None, "expected": sorted(x for e in eff for x in e["expected"])}
    return cols, steps, truth
