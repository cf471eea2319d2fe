"""The independent lab's two-axis tilt table with a servo-accelerometer triad (numpy only).

Set-points ``theta`` (tilt about the table's y axis) and ``phi`` (rotation of the platform about
the triad's z axis) dwell at each position and ramp linearly between positions at
``slew_deg_s``. At rest the triad senses the specific force (seed eq. 4.35-4.38)

    f_b = Cz(phi) Cy(theta) (0, 0, g)^T = g (-cos phi sin theta, sin phi sin theta, cos theta),

and each accelerometer j puts out

    u_j = b_j + K_j [ s_j + k2_j s_j^2 + kT_j (T - T_ref) ] + n_j,     s = (I + M) f_b,

K_j (V/(m/s^2)) its sensitivity, n_j white (density ``noise_V_rtHz``). The logger converts u
with its :class:`~independent_lab.lab.Converter` and logs the box temperature in degC.
Concealed effects change this chain in one place each (``EFFECTS``); a null has none.
"""
from __future__ import annotations

import math

import numpy as np

from .lab import CONVERTERS, G_LAB, LAB_SITE, time_tags, white

K_NOMINAL = 1.0 / 9.80665        # 1 V per standard g (V/(m/s^2))
T_REF_C = 22.0
EFFECTS = ("adc_crosstalk", "time_delay", "building_vibration", "cable_fault_spikes", "temperature_drift",
           "axis_misalignment", "scale_nonlinearity", "saturation")


def positions(theta_deg=(0, 30, 60, 90, 120, 150, 180), phi_deg=(0, 60, 120, 180, 240, 300)) -> np.ndarray:
    """(theta, phi) in a serpentine order (phi up, then down), deg."""
    out = []
    for i, th in enumerate(theta_deg):
        for ph in (phi_deg if i % 2 == 0 else phi_deg[::-1]):
            out.append((th, ph))
    return np.array(out, float)


def setpoint_knots(pos_deg: np.ndarray, dwell_s: float, slew_deg_s: float, lead_s: float = 2.0):
    """Knot times and (theta, phi) values of the piecewise-linear set-point: dwell, ramp, dwell ..."""
    t, vals, now = [0.0], [pos_deg[0]], lead_s + dwell_s
    t.append(now)
    vals.append(pos_deg[0])
    for a, b in zip(pos_deg[:-1], pos_deg[1:]):
        now += max(np.max(np.abs(b - a)) / slew_deg_s, 0.5)
        t += [now, now + dwell_s]
        vals += [b, b]
        now += dwell_s
    return np.array(t), np.array(vals)


def _cy(a):
    c, s = np.cos(a), np.sin(a)
    z, o = np.zeros_like(a), np.ones_like(a)
    return np.stack([np.stack([c, z, -s], -1), np.stack([z, o, z], -1), np.stack([s, z, c], -1)], -2)


def _cz(a):
    c, s = np.cos(a), np.sin(a)
    z, o = np.zeros_like(a), np.ones_like(a)
    return np.stack([np.stack([c, s, z], -1), np.stack([-s, c, z], -1), np.stack([z, z, o], -1)], -2)


def table_to_body(theta_rad: np.ndarray, phi_rad: np.ndarray) -> np.ndarray:
    """(n, 3, 3): a lab vector (z up) in the triad's axes, Cz(phi) Cy(theta)."""
    return _cz(phi_rad) @ _cy(theta_rad)


def specific_force_body(theta_rad: np.ndarray, phi_rad: np.ndarray, g: float = G_LAB) -> np.ndarray:
    """f_b (n, 3) at rest: gravity's reaction (0, 0, g) up in the lab, seen in the triad's axes."""
    return table_to_body(theta_rad, phi_rad) @ np.array([0.0, 0.0, g])


def draw_triad(rng: np.random.Generator) -> dict:
    """The triad's own errors (a null's truth): sensitivities, biases, noise."""
    return {"K_V_per_m_s2": (K_NOMINAL * (1 + 0.004 * rng.standard_normal(3))).tolist(),
            "bias_V": (0.004 * rng.standard_normal(3)).tolist(),
            "noise_V_rtHz": 5e-6, "misalignment_rad": np.zeros((3, 3)).tolist(), "k2_per_m_s2": [0.0] * 3,
            "bias_tempco_m_s2_per_K": [0.0] * 3}


def temperature_C(t_s: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The box temperature: +2.5 K over the run with a slow wobble (the air conditioning), 0.01 degC steps."""
    span = t_s[-1] if t_s[-1] > 0 else 1.0
    T = T_REF_C + 2.5 * t_s / span + 0.3 * np.sin(2 * np.pi * t_s / 900.0 + rng.uniform(0, 2 * np.pi))
    return np.round(T + 0.005 * rng.standard_normal(t_s.size), 2)


def _vibration(t_s, rot, rng, rms, f0):
    """The basement pump: a narrow line at f0 along a fixed lab direction, amplitude wandering 20 %."""
    u = np.array([0.3, -0.2, 1.0])
    u /= np.linalg.norm(u)
    amp = rms * math.sqrt(2) * (1 + 0.2 * np.sin(2 * np.pi * t_s / rng.uniform(20, 40)))
    e = amp * np.sin(2 * np.pi * f0 * t_s + rng.uniform(0, 2 * np.pi))
    return rot @ u * e[:, None]


def _spikes(n, fs, rng, rate_hz, amp_V):
    """Cable contact faults: Poisson instants, each a 1-3 sample step of random sign and size."""
    out = np.zeros(n)
    k = rng.poisson(rate_hz * n / fs)
    for i in rng.integers(0, n, k):
        out[i:i + rng.integers(1, 4)] += rng.choice((-1, 1)) * amp_V * rng.uniform(0.3, 1.0)
    return out


def fluxgate_V(rot: np.ndarray, rng: np.random.Generator, n: int, fs_hz: float) -> np.ndarray:
    """The IMU's fluxgate (when the lab logs it): 0.08 V/uT on the Earth's field at the site, lab frame
    z up with 18.5 uT north at 2 deg declination from the table's zero and 45 uT down (n, 3)."""
    dec = math.radians(2.0)
    B_lab_uT = np.array([18.5 * math.cos(dec), 18.5 * math.sin(dec), -45.0])
    v = 0.08 * (rot @ B_lab_uT) + 0.002 * rng.standard_normal(3)
    v = v + 4e-5 * math.sqrt(fs_hz / 100) * rng.standard_normal((n, 3))
    return v


def _sensor_errors(effect, tri: dict, rng: np.random.Generator, eff: list) -> tuple:
    """(M, k2, kT) of the triad: zero but for the concealed one (recorded in ``tri`` and ``eff``)."""
    M = np.zeros((3, 3))
    if effect == "axis_misalignment":
        M = 1e-3 * rng.standard_normal((3, 3))
        np.fill_diagonal(M, 0.0)
        tri["misalignment_rad"] = M.tolist()
        Dr = np.array(tri["K_V_per_m_s2"]) / K_NOMINAL
        inv = np.linalg.inv(np.eye(3) + M) / Dr[None, :]
        eff.append({"effect": effect, "channel": "acc", "parameters": {"M_rad": M.tolist(), "m_jk": inv.tolist()},
                    "diagnose_twin": {"twin_model": "own_axis"},
                    # the inverse model's coefficient of u_y in acc_x, u = V / nominal: for a reader with
                    # this lab's nominal (1 V per g); another nominal s scales it by s / K_NOMINAL
                    "score": {"name": "m_xy", "value": float(inv[0, 1]), "channel": "acc_x",
                              "per_nominal_V_per_m_s2": K_NOMINAL, "nominal_power": 1},
                    "expected": [f"acc_{a}:{effect}" for a in "xyz"]})
    k2 = np.zeros(3)
    if effect == "scale_nonlinearity":
        k2 = 48e-6 / 9.80665 * rng.choice((-1.0, 1.0), 3)
        tri["k2_per_m_s2"] = k2.tolist()
        Dr = np.array(tri["K_V_per_m_s2"]) / K_NOMINAL
        lib = (-k2 / Dr ** 2).tolist()
        eff.append({"effect": effect, "channel": "acc", "parameters": {"k2_per_m_s2": k2.tolist(), "k2": lib},
                    "diagnose_twin": {"twin_model": "linear"},
                    # the coefficient of u_x^2, u = V / nominal: scales with (s / K_NOMINAL)^2
                    "score": {"name": "k2", "value": lib[0], "channel": "acc_x",
                              "per_nominal_V_per_m_s2": K_NOMINAL, "nominal_power": 2},
                    "expected": [f"acc_{a}:{effect}" for a in "xyz"]})
    kT = np.zeros(3)
    if effect == "temperature_drift":
        kT = 2 * 70e-6 * 9.80665 * np.array([1.0, -0.7, 0.5])
        tri["bias_tempco_m_s2_per_K"] = kT.tolist()
        lib = (-kT / 0.01).tolist()
        eff.append({"effect": effect, "channel": "acc", "parameters": {"bias_tempco_m_s2_per_K": kT.tolist(),
                                                                       "drift": lib},
                    # in true m/s^2 per K whatever nominal the reader uses: the inverse model's observable is
                    # the reference specific force (g and the angles), and the drift's column is the
                    # temperature, not a reading in V / nominal (unlike m_xy and k2 above)
                    "score": {"name": "drift", "value": float(-kT[0]), "channel": "acc_x",
                              "unit": "m/s^2 per degC of the logged reading"},
                    "expected": [f"acc_{a}:{effect}" for a in "xyz"],
                    "note": "drift (the library's inverse coefficient) is per volt of a 10 mV/K reading; this lab "
                            "logs degC, so the diagnosis' drift per unit of the reading is -kT"})
    return M, k2, kT


def record(seed: int, effect: str | None, fs_hz: float, converter: str, dwell_s: float | None = None,
           slew_deg_s: float = 20.0) -> tuple[dict, dict, dict]:
    """One tilt-table recording: (columns, column steps, manifest)."""
    rng = np.random.default_rng(seed)
    adc = CONVERTERS[converter]
    dwell_s = dwell_s or (4.0 if fs_hz > 500 else 8.0)
    knots_t, knots_v = setpoint_knots(positions(), dwell_s, slew_deg_s)
    t = time_tags(int(knots_t[-1] * fs_hz), fs_hz)
    sp = np.column_stack([np.interp(t, knots_t, knots_v[:, i]) for i in range(2)])
    tri = draw_triad(rng)
    T = temperature_C(t, rng)
    eff: list[dict] = []
    lag = 0.0
    if effect == "time_delay":
        lag = 0.05
        eff.append({"effect": "time_delay", "channel": "acc", "parameters": {"tau_s": lag},
                    "score": {"name": "tau_s", "value": lag}, "expected": ["acc:time_delay"],
                    "note": "the table follows the logged set-points 50 ms late (servo lag)"})
    act = np.column_stack([np.interp(t - lag, knots_t, knots_v[:, i]) for i in range(2)])
    rot = table_to_body(np.radians(act[:, 0]), np.radians(act[:, 1]))
    f_b = rot @ np.array([0.0, 0.0, G_LAB])
    if effect == "building_vibration":
        rms, f0 = 0.03, 24.7 if fs_hz > 50 else 19.3
        f_b = f_b + _vibration(t, rot, rng, rms, f0)
        eff.append({"effect": effect, "channel": "acc", "parameters": {"rms_m_s2": rms, "fundamental_hz": f0},
                    "score": {"name": "frequency_hz", "value": f0}, "expected": [f"acc_{a}:{effect}" for a in "xyz"]})
    M, k2, kT = _sensor_errors(effect, tri, rng, eff)
    s = f_b @ (np.eye(3) + M).T
    K, b = np.array(tri["K_V_per_m_s2"]), np.array(tri["bias_V"])
    sigma = tri["noise_V_rtHz"] * math.sqrt(fs_hz / 2)
    u = b + K * (s + k2 * s ** 2 + kT * (T - T_REF_C)[:, None])
    u = u + np.column_stack([white(rng, t.size, sigma) for _ in range(3)])
    if effect == "cable_fault_spikes":
        rate, amp = 0.5, 0.2
        u[:, 1] += _spikes(t.size, fs_hz, rng, rate, amp)
        eff.append({"effect": effect, "channel": "acc_y", "parameters": {"rate_hz": rate, "amplitude_V": amp},
                    "score": {"name": "rate_hz", "value": rate, "channel": "acc_y"},
                    "expected": [f"acc_y:{effect}"]})
    if effect == "saturation":
        lim = 0.85
        u[:, 2] = np.minimum(u[:, 2], lim)
        eff.append({"effect": effect, "channel": "acc_z", "parameters": {"upper_limit_V": lim},
                    "score": {"name": "upper_limit_V", "value": lim, "channel": "acc_z"},
                    "expected": [f"acc_z:{effect}"], "note": "the amplifier's output saturates (not in the library)"})
    with_mag = effect == "adc_crosstalk" or seed % 2 == 0
    m = fluxgate_V(rot, rng, t.size, fs_hz) if with_mag else None
    scan = ["acc_x", "mag_x", "acc_y", "mag_y", "acc_z", "mag_z"] if with_mag else ["ground", "acc_x", "acc_y", "acc_z"]
    if effect == "adc_crosstalk":
        c, f_mux = 2e-4, 200e3
        # the amplifier keeps c of the channel converted before: acc_y after mag_x, acc_z after mag_y
        u = (1 - c) * u + c * m[:, [2, 0, 1]]
        lib = {f"acc_{a}": -c / (K[j] * (1 - c)) for j, a in enumerate("xyz")}
        eff.append({"effect": effect, "channel": "acc_x,acc_y,acc_z",
                    "parameters": {"settling_tau_s": -1 / (f_mux * math.log(c)), "mux_hz": f_mux,
                                   "leak_fraction": c, "c": lib, "scan_list": scan},
                    "score": {"name": "c", "value": lib["acc_y"], "channel": "acc_y"},
                    "expected": ["acc_x:adc_crosstalk", "acc_y:adc_crosstalk", "acc_z:adc_crosstalk"],
                    "note": "the leak comes from the magnetometer channel scanned before each accelerometer "
                            "(acc_x after the previous scan's mag_z)"})
    V = adc.read(u, rng)
    cols = {"time_s": t, "theta_deg": np.round(sp[:, 0], 4), "phi_deg": np.round(sp[:, 1], 4),
            "acc_x_V": V[:, 0], "acc_y_V": V[:, 1], "acc_z_V": V[:, 2], "temp_box_degC": T}
    if with_mag:
        Vm = adc.read(m, rng)
        cols.update({f"mag_{a}_V": Vm[:, j] for j, a in enumerate("xyz")})
    steps = {"time_s": 1e-7 if fs_hz != int(fs_hz) else 1e-4, "theta_deg": 1e-4, "phi_deg": 1e-4,
             "acc_x_V": adc.step_V, "acc_y_V": adc.step_V, "acc_z_V": adc.step_V, "temp_box_degC": 0.01,
             **{f"mag_{a}_V": adc.step_V for a in "xyz"}}
    truth = {"rig": "tilt_table", "seed": seed, "fs_hz": fs_hz, "adc": adc.as_dict(), "adc_name": converter,
             "site": LAB_SITE, "g_m_s2": G_LAB, "triad": tri, "noise_V_rms_per_sample": sigma, "dwell_s": dwell_s,
             "slew_deg_s": slew_deg_s, "scan_list": scan, "effects": eff, "null": effect is None,
             "expected": sorted(x for e in eff for x in e["expected"]),
             # the twin to compare with (imurig diagnose --twin-model): one without the concealed effect
             "diagnose_twin": next((e["diagnose_twin"] for e in eff if "diagnose_twin" in e), {})}
    return cols, steps, truth
