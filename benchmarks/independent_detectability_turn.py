"""Whether a turn-table effect of the independent lab is detectable at all in one recording: its
expected non-centrality, from the lab's manifest and schedule, against the one a test needs.

The table's motion is rebuilt with the lab's own functions (dial knots, motor lag, mains factor and
slip of the manifest) so the index crossings and the whole rounds are those of the recording.

- ``slip_ring_noise`` (a ripple A_j sin(h psi + phi_j) on gyro j, V): tested per gyro by
  regression on the table angle's harmonics 2..5 in the whole rounds of each dial plateau (from
  ``SETTLE_S`` after the plateau began, the first round dropped where there are four pulses or more).
  Its non-centrality is

      lambda_j = N A_j^2 / 2 / sigma_j^2,   sigma_j^2 = s^2 + (lsb q)^2 + q^2 / 12

  (N the samples in those rounds, s the gyro's white noise per sample, lsb q the converter's input
  noise, q^2/12 its rounding), needed: the 90 % power point of a chi-square test with 2 x 4 degrees
  of freedom at alpha / 3 (the test's level per gyro). A ripple below what the converter's rounding
  makes of the Earth's 1/rev signal (a1 = S_j Omega_N) is not detectable either: its lambda is 0 then.
- ``timer_quantisation`` (jitter j on the index pulse's edge, s): the test
  (:mod:`imurig.diagnose.pulse_angle`) places every pulse against the table-axis gyro's integrated
  angle. Its statistic U is simulated here with the recording's own crossings (the motion above),
  jittered and bracketed on the sample grid as they lie, the gyro's integration noise
  (the white noise, the converter's input noise and rounding of the manifest, per sample) and the
  rounding's rate offsets, against the null the test draws (:func:`imurig.diagnose.pulse_angle.score_null`,
  built from the same crossings: no jitter, each settled plateau's pulses at one uniform grid phase,
  the others at independent ones); its power at level alpha is expressed as the non-centrality of a
  chi-square on the same m residual degrees of freedom that has that power, needed: the one with 90 %
  power. A width of whole samples leaves each pulse bracketed by its rising edge (dt^2 / 12), as the
  test does; a width of n + phi samples shows n or n + 1 high samples, and the test times each pulse
  at its middle with phi unknown: it rejects where its statistic passes its null's 1 - alpha point at
  every phi of its grid, and so does the power here.

The mains factor and the slip are read from the table's mean rate over many rounds, far above the
timer's error at the lab's sizes: always scored (None).
"""
from __future__ import annotations

import math

import numpy as np
from scipy import optimize, special, stats

# the timer test's own edge bracketing, covariance, design and score, so the power is that of the test the diagnosis runs
from imurig.diagnose import pulse_angle as pa
from imurig.diagnose.pulse_timer import _bracket

ALPHA, POWER = 0.01, 0.9
#: seconds after a dial plateau began before its pulses count (the table's settling)
SETTLE_S = 2.0
#: harmonics 2..5 of the table angle (cos and sin): the ripple test's degrees of freedom
RIPPLE_DOF = 8
#: draws per fraction of the width where the width is n + phi samples (19 fractions, each a batch of inverses)
N_SIM_CLASSES = 500
#: the running mean (samples) whose half is cut from each window's ends
RUNNING_MEAN = 51


def lambda_needed(k: int, alpha: float, power: float = POWER) -> float:
    """The non-centrality giving ``power`` to a chi-square(k) test at level ``alpha``."""
    crit = stats.chi2.isf(alpha, k)
    return float(optimize.brentq(lambda lam: stats.ncx2.sf(crit, k, lam) - power, 1e-6, 1e5))


def table_motion(turn, truth: dict):
    """(t, psi_deg, crossing times, plateaus [(start, stop, dial)], knot times, knot dials) of the
    recording, rebuilt with the lab's own functions and the manifest's table."""
    fs, tb = truth["fs_hz"], truth["table"]
    knots_t, knots_v = turn.dial_knots()
    t = np.arange(int(knots_t[-1] * fs)) / fs
    dial = np.interp(t, knots_t, knots_v)
    r = np.abs(dial * tb["factor"])
    short = np.where(r > 0.5, tb["slip_s1"] * np.maximum(r, 0.5) ** -tb["slip_alpha"], 0.0)
    omega = turn.lagged(dial * tb["factor"] * (1 - short), fs, tb["motor_lag_s"])
    psi = np.concatenate([[0.0], np.cumsum(0.5 * (omega[1:] + omega[:-1]) / fs)])
    cross = turn.crossing_times(t, psi)
    plateaus = [(a, b, v) for a, b, v, v2 in zip(knots_t[:-1], knots_t[1:], knots_v[:-1], knots_v[1:])
                if v == v2 and v != 0]
    return t, psi, cross, plateaus, knots_t, knots_v


def rounding_harmonics_V(q: float, a1: float, sigma: float, m: int, k_max: int = 2000) -> float:
    """The largest amplitude at harmonic m that rounding to q makes of b + a1 cos(psi) under
    Gaussian noise sigma, any b: sum_k 2 q / (pi k) exp(-2 pi^2 k^2 sigma^2 / q^2) |J_m(2 pi k a1 / q)|
    (the quantiser's Fourier series, Jacobi-Anger), the tail past k_max by |J_m(x)| <= sqrt(2 / (pi x)))."""
    if q <= 0 or a1 <= 0:
        return 0.0
    k = np.arange(1, k_max + 1, dtype=float)
    damp = np.exp(-2 * np.pi**2 * k**2 * sigma**2 / q**2)
    head = float(np.sum(2 * q / (np.pi * k) * damp * np.abs(special.jv(m, 2 * np.pi * k * a1 / q))))
    return head + 2 * q / np.pi * math.sqrt(q / (np.pi**2 * a1)) * 2.0 / math.sqrt(k_max) * float(damp[-1])


def _rounds(cross: np.ndarray, a: float, b: float) -> np.ndarray:
    """The pulses of a plateau's whole rounds as the ripple test takes them."""
    p = cross[(cross >= a + SETTLE_S) & (cross <= b)]
    return p[1:] if p.size >= 4 else p


def slip_ring(truth: dict, effect: dict, turn, motion) -> dict:
    """lambda per gyro of the ripple (module doc)."""
    t, _psi, cross, plateaus = motion[:4]
    fs, adc = truth["fs_hz"], truth["adc"]
    n = 0
    for a, b, _v in plateaus:
        p = _rounds(cross, a, b)
        if p.size >= 2:
            n += max(int(round((p[-1] - p[0]) * fs)) - 2 * (RUNNING_MEAN // 2), 0)
    q = adc["step_V"]
    s2 = truth["gyros"]["noise_V_rms_per_sample"] ** 2 + (adc["input_noise_lsb_rms"] * q) ** 2
    sigma2 = s2 + q * q / 12
    lat = math.radians(truth["site"]["latitude_deg"])
    w_n_dps = math.degrees(7.2921150e-5 * math.cos(lat))
    amp = effect["parameters"]["ripple_amplitude_V"]
    h = effect["parameters"]["harmonic_per_turn"]
    lam = {}
    for j, a in enumerate("xyz"):
        a1 = truth["gyros"]["S_V_per_dps"][j] * w_n_dps if j < 2 else 0.0
        bound = rounding_harmonics_V(q, a1, math.sqrt(s2), h)
        lam[f"gyro_{a}"] = float(n * amp[j] ** 2 / 2 / sigma2) if amp[j] > bound else 0.0
    need = lambda_needed(RIPPLE_DOF, ALPHA / 3)
    return {"effect": effect["effect"], "lambda": lam, "lambda_90": need, "dof": RIPPLE_DOF, "samples": n,
            "detectable": all(v >= need for v in lam.values())}


def timer(truth: dict, effect: dict, motion, n_sim: int = 2000, seed: int = 0) -> dict:
    """The timer test's power (module doc), as a chi-square non-centrality on its m residuals."""
    t, psi, cross, plateaus, knots_t, knots_v = motion
    fs, adc, g = truth["fs_hz"], truth["adc"], truth["gyros"]
    dt, w = 1.0 / fs, truth["table"]["pulse_width_s"]
    j = effect["parameters"]["jitter_s"]
    rng = np.random.default_rng(seed)
    om_t = np.gradient(psi, t) / 360.0                                        # turns/s
    w2 = np.concatenate([[0.0], np.cumsum(0.5 * (om_t[1:] ** 2 + om_t[:-1] ** 2) * np.diff(t))])
    S = abs(g["S_V_per_dps"][2]) * 360.0                                      # V per turn/s
    groups = []
    for a, b, _v in plateaus:
        k = np.flatnonzero((cross >= a + SETTLE_S) & (cross <= b))
        if k.size >= 3:
            groups.append(k)
    q = adc["step_V"]
    c = {"t": cross, "omega": np.interp(cross, t, om_t), "G1": np.interp(cross, t, psi) / 360.0,
         "G2": np.interp(cross, t, w2), "N": np.zeros(cross.size), "a0": 1.0 / S, "groups": groups,
         "sigma_u": math.sqrt(g["noise_V_rms_per_sample"] ** 2 + (adc["input_noise_lsb_rms"] * q) ** 2 + q * q / 12),
         "segments": [(a, b) for a, b, v, v2 in zip(knots_t[:-1], knots_t[1:], knots_v[:-1], knots_v[1:]) if v == v2]}
    X = pa.design(c)
    m = cross.size - X.shape[1]
    if abs(w / dt - round(w / dt)) > 1e-6:           # n + phi samples: each pulse at its middle, phi unknown
        return _timer_classes(truth, effect, c, cross, dt, w, j, q, X, m, rng, N_SIM_CLASSES)
    # a whole-sample width: one count, so the test brackets by the rising edge
    wr = (-np.inf, np.inf)
    v_grid = np.full(cross.size, dt**2 / 12)
    C0, _D, _parts = pa.covariance(c, v_grid, dt, q)
    Cg = C0 - np.diag(c["omega"] ** 2 * v_grid)
    u0 = pa.score_null(c, v_grid, dt, w, Cg, X, rng, n_sim, w_range=wr)
    # H1: the recording's crossings, jittered, on the sample grid as it lies (the phases the schedule gives)
    tau = cross[None, :] + j * rng.standard_normal((n_sim, cross.size))
    mid, vs = _bracket(tau, dt, w, wr)
    eps = (mid - cross[None, :]) * c["omega"][None, :] + pa.gyro_draws(Cg, rng, n_sim)
    u1 = pa.scores(eps, vs, Cg, X, c["omega"])
    u0s = np.sort(u0)
    p1 = (1 + u0.size - np.searchsorted(u0s, u1, side="left")) / (1 + u0.size)
    return _power(effect, float(np.mean(p1 < ALPHA)), m)


def _power(effect: dict, power: float, m: int) -> dict:
    """The test's ``power`` as the non-centrality of a chi-square on ``m`` with that power, against the 90 % point."""
    need = lambda_needed(m, ALPHA)
    cc = stats.chi2.isf(ALPHA, m)
    lam = 1e5 if power >= 1 - 1e-9 else (0.0 if power <= ALPHA else
                                           float(optimize.brentq(lambda x: stats.ncx2.sf(cc, m, x) - power, 1e-9, 1e5)))
    return {"effect": effect["effect"], "lambda": {"rate": lam}, "lambda_90": need, "dof": m, "power": power,
            "detectable": power >= POWER}


def _timer_classes(truth, effect, c, cross, dt, w, j, q, X, m, rng, n_sim) -> dict:
    """The power of the test where the width is n + phi samples (:func:`imurig.diagnose.pulse_angle.class_test`):
    it rejects where Q(phi) passes its null's 1 - alpha point at every phi of the grid; H1 draws are the
    recording's crossings, jittered, on the grid as they lie, each pulse at its middle."""
    om = c["omega"]
    phi0 = w / dt - math.floor(w / dt)
    Cg, _D, _parts = pa.covariance(c, np.zeros(cross.size), dt, q)
    tau0 = pa.null_times(c, np.full(cross.size, dt**2 / 48), dt, rng, n_sim)
    g0 = pa.gyro_draws(Cg, rng, n_sim)
    tau1 = cross[None, :] + j * rng.standard_normal((n_sim, cross.size))
    g1 = pa.gyro_draws(Cg, rng, n_sim)
    a0, a1 = (np.ceil(tau0 / dt) - 1.0) * dt, (np.ceil(tau1 / dt) - 1.0) * dt
    c1 = ((tau1 - a1) / dt > 1.0 - phi0).astype(float)               # the recording's classes, at its true width
    eps1 = (a1 + 0.5 * dt * (1.0 + c1) - cross[None, :]) * om[None, :] + g1
    reject = np.ones(n_sim, bool)
    for phi in pa.PHI_GRID:
        cs = ((tau0 - a0) / dt > 1.0 - phi).astype(float)
        u0 = pa.scores((a0 + 0.5 * dt * (1.0 + cs) - tau0) * om[None, :] + g0, pa.class_var(cs, phi, dt), Cg, X, om)
        u1 = pa.scores(eps1, pa.class_var(c1, phi, dt), Cg, X, om)
        reject &= u1 > np.quantile(u0, 1.0 - ALPHA)
    return _power(effect, float(np.mean(reject)), m)


def detectability(truth: dict, turn) -> dict | None:
    """{lambda, lambda_90, detectable, ...} of a turn-table recording's effect, or None (always scored)."""
    eff = [e for e in truth.get("effects", []) if e["effect"] in ("slip_ring_noise", "timer_quantisation")]
    if truth.get("rig") != "turn_table" or not eff:
        return None
    motion = table_motion(turn, truth)
    if eff[0]["effect"] == "slip_ring_noise":
        return slip_ring(truth, eff[0], turn, motion)
    return timer(truth, eff[0], motion, seed=int(truth["seed"]))
