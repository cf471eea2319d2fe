"""The index pulses' timing error against the table-axis gyro's integrated angle: the timer test
on every pulse of a turn-table time series, ramps and settling included.

The plateau test (:mod:`imurig.diagnose.pulse_timer`) spends two parameters (t0, T) on each dial
plateau and drops the pulses of the ramps and of the settling, so a record of ten plateaus of a few
rounds keeps about a dozen residuals. The gyro on the table axis measures the table's rate
whatever the motor, the mains factor or the slip make of it, so its integral places every pulse.
With u the table-axis gyro (V, signed by the mounting), G1(t) = int_0^t u dt, G2(t) = int_0^t u^2 dt
(trapezoids on the samples, read at the pulse times) and N_k the whole turns the table has made at
pulse k (counted from the gyro's integral between pulses, rounded), the physical gyro model
w = b + a u + c u^2 (the twin's) gives, for the measured pulse times t_k = tau_k + e_k,

    N_k = theta0 + b t_k + a G1(t_k) + c G2(t_k) + eps_k                   [turns]
    eps_k = -omega_k e_k + W(t_k) + sum_s beta_s L_s(t_k)

omega_k the table's rate at pulse k (turns/s, from the gyro around t_k), e_k the pulse's timing error
(the sample grid's bracket, variance v_k (:func:`imurig.diagnose.pulse_timer.edge_times`), plus the
detector's jitter j^2), W the random walk of the gyro's white noise (a^2 sigma_u^2 dt per second;
sigma_u from the first differences on the plateaus) and beta_s a rate offset per segment: what the
converter's rounding makes of a held signal under input noise sigma_pre (variance A^2/2,
A = a sum_k q / (pi k) exp(-2 pi^2 k^2 sigma_pre^2 / q^2), the quantiser's Fourier series),
L_s(t) the time spent in segment s before t. So

    cov(eps) = C0 + j^2 D,   C0 = diag(omega^2 v) + a^2 sigma_u^2 dt min(t_i, t_j) + sum_s A^2/2 L_s L_s',
    D = diag(omega^2),

plus a column omega_k, a constant latency of the detector (the plateau test's offsets absorb it too),
so m = K - 5 residual degrees of freedom for K pulses. The statistic is Q = r' P0 r (P0 the generalised
least squares residual projector under C0; H0: j = 0), the plateau test's Q on every pulse; its null
simulated (:func:`score_null`: the grid's brackets of the pulses, on each plateau at its
fitted period within its SE and a uniform phase as in the plateau test, elsewhere a uniform phase
each, plus Gaussian draws of the gyro terms). j^2 is the restricted maximum-likelihood estimate
(REML: the log-likelihood of the residual contrasts, maximised over j^2 >= 0), its SE from the
expected information 1/2 tr(P D P D) at the estimate; sigma_T = sqrt(j^2 + dt^2/12) as in the plateau
test (the library's per-edge timer error), by the delta method, and the REML likelihood-ratio
interval (2 delta l <= 1) beside it.

The model adds the grid's error and the jitter (var v_k + j^2), which holds when the pulses fall at
independent phases on the grid. A pulse train locked to the grid (a plateau's period a whole number
of samples, as an exact synchronous rate gives) breaks this within a record: a pulse in the middle
of its sample interval shows a jitter smaller than dt/2 as no error at all. Over such records the
estimate stays unbiased but scatters more than its SE says (numpy-made 100 Hz records with the
phases locked: z RMS about 1.5 on j^2; with the rate wobbling 1 %, about 0.8).

A pulse width of n + phi samples (0 < phi < 1) shows n or n + 1 high samples (:func:`width_classes`):
the longer count says that the rising edge fell in the last phi of its sample interval, the
shorter one that it fell in the first 1 - phi. Each pulse is timed at its middle, the rising
bracket's middle plus dt/2 for the longer count (:func:`pulse_times`): both classes then sit phi dt/2
after their edge on average (the latency column's), with grid variances (phi dt)^2/12 and
((1 - phi) dt)^2/12; at phi = 1/2 every bracket is half a sample. The counts alone do not fix phi
(with pulses locked to the grid's phase their share is not phi, and the residuals' spread against
the gyro pins it only loosely), so phi is a nuisance: Q(phi) with the classes' variances at phi,
its null simulated at phi (each draw's pulses classed and centred as the data's are), and the
test's p-value is the largest over PHI_GRID (:func:`class_test`), valid whatever phi is. The
jitter's REML estimate is mixed over phi (:func:`mixed_jitter`): over the phi whose simulated
long-pulse counts hold the data's, the REML fits' mean, its variance theirs plus their spread
(the Gaussian likelihood of uniform brackets is no guide to phi: on a 50 Hz record it preferred 0.9
to the true 0.5 by 4 log units).
"""
from __future__ import annotations

import numpy as np
from scipy import optimize

from imurig.diagnose.gyro_samples import GyroSamples
from imurig.diagnose.pulse_timer import N_SIM, SETTLE_S, _bracket, timer_finding

#: the table's rate at a pulse: the gyro averaged this long around it (s)
RATE_WINDOW_S = 0.1
#: the model's columns (module doc): offset, gyro bias, scale, square term, the detector's latency
X_COLUMNS = 5
#: the largest turn-count rounding error accepted (turns) before the gyro's angle is refused as a reference
MAX_TURN_ERROR = 0.25
#: the pulse width's fractions of a sample the test and the estimate range over (:func:`class_test`)
PHI_GRID = np.linspace(0.05, 0.95, 19)
#: draws of the simulated null per fraction of the width
N_SIM_WIDTH = 600


def rounding_bias_amplitude(q: float, sigma_pre: float, k_max: int = 200) -> float:
    """The largest mean error (V) rounding to ``q`` gives a held input under Gaussian input noise
    ``sigma_pre`` (V): sum_k q / (pi k) exp(-2 pi^2 k^2 sigma_pre^2 / q^2)."""
    if q <= 0:
        return 0.0
    k = np.arange(1, k_max + 1, dtype=float)
    return float(np.sum(q / (np.pi * k) * np.exp(-2 * np.pi**2 * k**2 * sigma_pre**2 / q**2)))


def chain(t_s: np.ndarray, u_V: np.ndarray, t_pulse: np.ndarray, start_s, stop_s, dial) -> dict | None:
    """The pulses' turn counts and the gyro's integrals at them (module doc), or None when the gyro
    cannot count the turns (fewer than two turning plateaus, or a count off by more than
    ``MAX_TURN_ERROR``). Returns {N, G1, G2, t, omega (turns/s), a0 (turns per V s), b0 (V), groups,
    sigma_u (V), segments [(start, stop)]}; ``groups``: per plateau the index of its settled pulses."""
    return chain_from(GyroSamples(t_s, u_V), t_pulse, start_s, stop_s, dial)


def chain_from(g, t_pulse: np.ndarray, start_s, stop_s, dial) -> dict | None:
    """:func:`chain` on the gyro's samples as ``g`` gives them (:class:`GyroSamples`)."""
    tp = np.asarray(t_pulse, float)
    rates, means, groups, sd = [], [], [], []
    for a, b, d in zip(start_s, stop_s, dial):
        w = g.window(a, b)
        if w.size > 10:
            sd.append(float(np.std(np.diff(w)) / np.sqrt(2.0)))
        k = np.flatnonzero((tp >= a + SETTLE_S) & (tp <= b))
        if d == 0 or k.size < 2:
            continue
        T0 = float(np.median(np.diff(tp[k])))
        n = np.round((tp[k] - tp[k[0]]) / T0)
        T = float(np.polyfit(n, tp[k], 1)[0]) if k.size >= 3 else T0
        rates.append(np.sign(d) / T)
        means.append(float(np.mean(g.window(tp[k[0]], tp[k[-1]]))))
        if k.size >= 3:
            groups.append(k)
    if len(rates) < 2 or np.ptp(rates) == 0:
        return None
    S, b0 = np.polyfit(rates, means, 1)               # u = b0 + S omega (V; V per turn/s)
    a0 = 1.0 / S
    g1, g2 = g.integrals(tp)
    turns = a0 * (np.diff(g1) - b0 * np.diff(tp))
    dN = np.round(turns)
    if np.max(np.abs(turns - dN), initial=0.0) > MAX_TURN_ERROR:
        return None
    h = max(1, int(round(0.5 * RATE_WINDOW_S / g.dt)))
    omega = a0 * (g.sums(tp, h) / (2 * h) - b0)
    return {"N": np.concatenate([[0.0], np.cumsum(dN)]), "G1": g1, "G2": g2, "t": tp,
            "omega": omega, "a0": float(a0), "b0": float(b0), "groups": groups,
            "sigma_u": float(np.median(sd)) if sd else 0.0,
            "segments": [(float(a), float(b)) for a, b in zip(start_s, stop_s)]}


def covariance(c: dict, var_grid: np.ndarray, dt_s: float, q_V: float) -> tuple[np.ndarray, np.ndarray, dict]:
    """(C0, D, parts) of the module doc (turns^2; D in turns^2/s^2), ``var_grid`` the pulses' bracket
    variances (s^2), ``dt_s`` the sample interval, ``q_V`` the gyro channel's ADC step."""
    tp, om, a0 = c["t"], c["omega"], abs(c["a0"])
    su = c["sigma_u"]
    rw = a0**2 * su**2 * dt_s                          # turns^2 per second
    t_rel = tp - tp[0]
    C = np.diag(om**2 * var_grid) + rw * np.minimum.outer(t_rel, t_rel)
    sig_pre = float(np.sqrt(max(su**2 - q_V**2 / 12.0, 0.0)))
    A = a0 * rounding_bias_amplitude(q_V, sig_pre)     # turns/s
    if A > 0:
        L = np.array([np.clip(tp, a, b) - np.clip(tp[0], a, b) for a, b in c["segments"]])   # (S, K) s
        C += 0.5 * A**2 * (L.T @ L)
    return C, np.diag(om**2), {"random_walk_turns2_per_s": rw, "rounding_rate_offset_turns_s": A,
                               "sigma_pre_V": sig_pre}


def design(c: dict) -> np.ndarray:
    """The columns 1, t, G1, G2, omega of the module doc, each scaled to unit norm (the projector is unchanged)."""
    X = np.column_stack([np.ones_like(c["t"]), c["t"] - c["t"][0], c["G1"] - c["G1"][0], c["G2"] - c["G2"][0],
                         c["omega"]])
    return X / np.linalg.norm(X, axis=0)


def projector(C: np.ndarray, X: np.ndarray) -> np.ndarray:
    """P = C^-1 - C^-1 X (X' C^-1 X)^-1 X' C^-1 (generalised least squares residual form)."""
    Ci = np.linalg.inv(C)
    CiX = Ci @ X
    return Ci - CiX @ np.linalg.solve(X.T @ CiX, CiX.T)


def reml(y: np.ndarray, X: np.ndarray, C0: np.ndarray, D: np.ndarray, j2_max: float, j2_min: float) -> dict:
    """The REML estimate of j^2 in cov = C0 + j^2 D (j^2 in [0, j2_max], searched on a log grid from
    ``j2_min`` up, then refined), its expected-information SE and its likelihood-ratio interval
    (2 delta l <= 1)."""
    def ll(j2: float) -> float:
        C = C0 + j2 * D
        P = projector(C, X)
        ld = np.linalg.slogdet(C)[1] + np.linalg.slogdet(X.T @ np.linalg.solve(C, X))[1]
        return -0.5 * (ld + float(y @ P @ y))

    grid = np.concatenate([[0.0], np.geomspace(j2_min, j2_max, 121)])
    vals = np.array([ll(g) for g in grid])
    i = int(np.argmax(vals))
    if i == 0:
        j2, lmax = 0.0, vals[0]
    else:
        lo, hi = grid[i - 1], grid[min(i + 1, grid.size - 1)]
        res = optimize.minimize_scalar(lambda x: -ll(x), bounds=(lo, hi), method="bounded",
                                       options={"xatol": 1e-6 * hi})
        j2, lmax = float(res.x), -float(res.fun)
    P = projector(C0 + j2 * D, X)
    PD = P @ D
    se = float(1.0 / np.sqrt(0.5 * np.sum(PD * PD.T)))

    def end(a: float, b: float) -> float:
        return float(optimize.brentq(lambda x: lmax - ll(x) - 0.5, a, b, xtol=1e-9 * j2_max))

    lo_j = 0.0 if lmax - ll(0.0) <= 0.5 else end(0.0, j2)
    top = max(j2, j2_min)
    while lmax - ll(top) <= 0.5 and top < 1e3 * j2_max:
        top *= 2.0
    hi_j = end(j2, top) if lmax - ll(top) > 0.5 else float("inf")
    return {"j2": j2, "se": se, "interval": [lo_j, hi_j]}


def null_times(c: dict, var_grid: np.ndarray, dt_s: float, rng: np.random.Generator, n_sim: int) -> np.ndarray:
    """``n_sim`` draws (n_sim, K) of the pulses' true times under H0 (s, on the sample grid's phase only):
    each settled plateau's pulses at its fitted period within its SE with one uniform phase, the
    others at independent uniform phases."""
    K = c["t"].size
    tau = rng.uniform(0, dt_s, (n_sim, K)) + 1000.0 * dt_s
    for k in c["groups"]:
        n = np.round((c["t"][k] - c["t"][k[0]]) / np.median(np.diff(c["t"][k])))
        T = float(np.polyfit(n, c["t"][k], 1)[0])
        se_T = float(np.sqrt(np.mean(var_grid[k]) / np.sum((n - n.mean()) ** 2)))
        tau[:, k] = rng.uniform(0, dt_s, (n_sim, 1)) + (T + se_T * rng.standard_normal((n_sim, 1))) * n + 1000.0 * dt_s
    return tau


def gyro_draws(Cg: np.ndarray, rng: np.random.Generator, n_sim: int) -> np.ndarray:
    """``n_sim`` Gaussian draws (turns) of the gyro terms, covariance ``Cg``."""
    K = Cg.shape[0]
    Lg = np.linalg.cholesky(Cg + 1e-12 * np.max(np.diag(Cg), initial=0.0) * np.eye(K) + 1e-30 * np.eye(K))
    return rng.standard_normal((n_sim, K)) @ Lg.T


def score_null(c: dict, var_grid: np.ndarray, dt_s: float, width_s: float, Cg: np.ndarray, X: np.ndarray,
               rng: np.random.Generator, n_sim: int = N_SIM, batch: int = 250, w_range=None) -> np.ndarray:
    """``n_sim`` draws of Q under H0 (module doc): the grid's bracket errors of :func:`null_times`,
    times the rate, plus Gaussian draws of the gyro terms (covariance ``Cg``); each draw's Q weighs
    by its own brackets' variances, as the data's Q does by theirs."""
    tau = null_times(c, var_grid, dt_s, rng, n_sim)
    mid, vs = _bracket(tau, dt_s, width_s, w_range)
    eps = (mid - tau) * c["omega"][None, :] + gyro_draws(Cg, rng, n_sim)
    return scores(eps, vs, Cg, X, c["omega"], batch)


def scores(eps: np.ndarray, vs: np.ndarray, Cg: np.ndarray, X: np.ndarray, om: np.ndarray,
           batch: int = 250) -> np.ndarray:
    """Q = eps' P0 eps of each row of ``eps`` (turns), P0 from C0 = Cg + diag(om^2 vs) with that
    row's own bracket variances ``vs`` (s^2)."""
    n_sim, K = eps.shape
    if np.ptp(vs) <= 1e-12 * np.max(vs):              # one bracket width throughout: one weight matrix
        P = projector(Cg + np.diag(om**2 * vs[0]), X)
        return np.einsum("ik,kl,il->i", eps, P, eps)
    Q = np.empty(n_sim)
    p = X.shape[1]
    for i in range(0, n_sim, batch):               # Q = e'C^-1 e - (X'C^-1 e)' (X'C^-1 X)^-1 (X'C^-1 e)
        e = eps[i:i + batch]
        C = Cg[None] + (om**2)[None, :, None] * vs[i:i + batch, :, None] * np.eye(K)[None]
        R = np.broadcast_to(np.concatenate([X, np.zeros((K, 1))], axis=1), (e.shape[0], K, p + 1)).copy()
        R[:, :, p] = e
        S = np.linalg.solve(C, R)                    # C^-1 [X, e]
        XtS = np.swapaxes(R[:, :, :p], 1, 2) @ S     # X' C^-1 [X, e]
        b = np.linalg.solve(XtS[:, :, :p], XtS[:, :, p:])[:, :, 0]
        Q[i:i + batch] = np.einsum("bk,bk->b", e, S[:, :, p]) - np.einsum("bj,bj->b", XtS[:, :, p], b)
    return Q


def width_classes(edges: dict) -> np.ndarray | None:
    """c_k = 1 for the pulses with one high sample more than the fewest, 0 for the others, where every
    edge is binary and the counts take two adjacent values (a width of n + phi samples, 0 < phi < 1);
    else None (a whole-sample width: one count; a varying width: more)."""
    cnt = np.asarray(edges.get("high_samples", []))
    if edges["sloped"] or cnt.size == 0 or cnt.max() != cnt.min() + 1:
        return None
    return (cnt > cnt.min()).astype(float)


def class_var(cls: np.ndarray, phi, dt_s: float) -> np.ndarray:
    """The grid variance (s^2) of each pulse's centre at fractional width ``phi``: ((phi or 1 - phi) dt)^2 / 12."""
    return (np.where(cls > 0, phi, 1.0 - phi) * dt_s) ** 2 / 12.0


def class_test(c: dict, cls: np.ndarray, dt_s: float, Cg: np.ndarray, X: np.ndarray, rng: np.random.Generator,
               n_sim: int = N_SIM_WIDTH) -> dict:
    """The timer test where the width is n + phi samples and phi unknown (module doc): per phi on
    PHI_GRID, Q(phi) = y' P(phi) y with the pulses' centre variances at phi, and its p-value from
    draws of :func:`null_times` at that phi (the same draws for every phi), each centred by its own
    classes and weighed at phi; the test's p-value is the largest over the grid. Returns
    {p, p_phi, Q_phi, phi_H0}."""
    om, y = c["omega"], c["N"]
    tau = null_times(c, class_var(cls, 0.5, dt_s), dt_s, rng, n_sim)
    a1 = (np.ceil(tau / dt_s) - 1.0) * dt_s
    f = (tau - a1) / dt_s
    g = gyro_draws(Cg, rng, n_sim)
    Qd, pp, fits = [], [], []
    for phi in PHI_GRID:
        q = float(y @ projector(Cg + np.diag(om**2 * class_var(cls, phi, dt_s)), X) @ y)
        cs = (f > 1.0 - phi).astype(float)
        lo, hi = np.quantile(cs.sum(axis=1), [0.025, 0.975])
        fits.append(lo <= cls.sum() <= hi)
        eps = (a1 + 0.5 * dt_s * (1.0 + cs) - tau) * om[None, :] + g
        Un = scores(eps, class_var(cs, phi, dt_s), Cg, X, om)
        Qd.append(q)
        pp.append(float((1 + np.sum(Un >= q)) / (1 + n_sim)))
    i = int(np.argmax(pp))
    return {"p": pp[i], "p_phi": pp, "Q_phi": Qd, "phi_H0": float(PHI_GRID[i]), "count_fits": np.array(fits)}


def mixed_jitter(y: np.ndarray, X: np.ndarray, Cg: np.ndarray, D: np.ndarray, cls: np.ndarray, dt_s: float,
                 j2_max: float, fits: np.ndarray) -> dict:
    """The jitter's REML estimate with the width's fraction phi unknown (module doc): per phi of
    PHI_GRID whose simulated long-pulse counts hold the data's (``fits``; all where none does) the
    REML fit (:func:`reml`), then their equal mixture: j^2 the mean, its variance the mean of the
    fits' variances plus the variance of their estimates."""
    om = np.sqrt(np.diag(D))
    phis = PHI_GRID[fits] if np.any(fits) else PHI_GRID
    r = [reml(y, X, Cg + np.diag(om**2 * class_var(cls, phi, dt_s)), D, j2_max, 1e-6 * dt_s**2) for phi in phis]
    j2s, ses = np.array([x["j2"] for x in r]), np.array([x["se"] for x in r])
    j2, se = float(np.mean(j2s)), float(np.sqrt(np.mean(ses**2) + np.var(j2s)))
    return {"j2": j2, "se": se, "interval": [max(j2 - se, 0.0), j2 + se], "phis": phis,
            "phi": float(phis[int(np.argmin(np.abs(j2s - j2)))])}


def pulse_times(edges: dict, dt_s: float) -> np.ndarray:
    """The pulses' times for :func:`chain` (s): the rising edge's bracket middle, moved by dt/2 for a
    pulse of the longer count where the width is n + phi samples (:func:`width_classes`): the middle
    of the pulse, which puts both classes' brackets at one offset (phi dt / 2, the latency's column)."""
    cls = width_classes(edges)
    t = np.asarray(edges["time_s"], float)
    return t if cls is None else t + 0.5 * dt_s * cls


def angle_timer_test(c: dict, edges: dict, dt_s: float, q_V: float, rng: np.random.Generator,
                     alpha: float = 0.01) -> dict:
    """The timer test of the module doc on the chain ``c`` (:func:`chain`) and the pulses' ``edges``
    (:func:`imurig.diagnose.pulse_timer.edge_times`; the grid's simulated null only for binary edges)."""
    K = c["t"].size
    m = K - X_COLUMNS
    if m < 3:
        return {"tested": False, "why": f"{m} residual degrees of freedom from the pulses against the gyro's angle"}
    cls = width_classes(edges)
    X = design(c)
    y = c["N"]
    om = c["omega"]
    width = {}
    if cls is None:
        v = edges["var_s2"]
    else:                                            # the width's fraction of a sample unknown: the test over it
        Cg, D, parts = covariance(c, np.zeros(K), dt_s, q_V)
        ct = class_test(c, cls, dt_s, Cg, X, rng)
        v = class_var(cls, ct["phi_H0"], dt_s)
        n0 = int(np.min(edges["high_samples"]))
        width = {"pulse_width_range_s": [n0 * dt_s, (n0 + 1) * dt_s], "long_pulses": int(cls.sum()),
                 "width_fraction_grid": PHI_GRID.tolist(), "p_value_per_width": ct["p_phi"]}
    C0, D, parts = covariance(c, v, dt_s, q_V)
    P0 = projector(C0, X)
    Q = float(y @ P0 @ y)
    Cg = C0 - np.diag(om**2 * v)
    if cls is not None:
        p = ct["p"]
        null = (f"simulated: {N_SIM_WIDTH} draws of the grid's bracketing per fraction of the width (plateaus at their "
                "fitted periods) and the gyro; the largest p-value over the fractions")
    elif edges["sloped"] == 0:
        Un = score_null(c, v, dt_s, edges["width_s"], Cg, X, rng, w_range=edges.get("width_range_s"))
        null = f"simulated: {Un.size} draws of the grid's bracketing (plateaus at their fitted periods) and the gyro"
    else:                                            # a sloped edge: Gaussian errors of the bracket's variance
        Z = rng.standard_normal((N_SIM, K)) @ np.linalg.cholesky(C0).T
        Un = np.einsum("ik,kl,il->i", Z, P0, Z)
        null = "simulated Gaussian (sloped edges: the grid bracket does not apply)"
    if cls is None:
        p = float((1 + np.sum(Un >= Q)) / (1 + Un.size))
    res = y - X @ np.linalg.lstsq(X, y, rcond=None)[0]
    ts = res / np.where(np.abs(om) > 0, np.abs(om), np.inf)
    # the search reaches far past anything the residuals show (the grid's and the pulses' own scatter)
    j2_max = float(100.0 * max(np.max(v), np.median(ts[np.isfinite(ts)] ** 2), dt_s**2))
    if cls is None:
        r = reml(y, X, C0, D, j2_max, 1e-6 * dt_s**2)
    else:
        r = mixed_jitter(y, X, Cg, D, cls, dt_s, j2_max, ct["count_fits"])
        v = class_var(cls, r["phi"], dt_s)
        width.update({"pulse_width_s": (n0 + r["phi"]) * dt_s, "width_fraction": r["phi"],
                      "width_fractions_kept": r["phis"].tolist()})
    j2, se_j2 = r["j2"], r["se"]
    s2 = j2 + dt_s**2 / 12.0
    sig = float(np.sqrt(s2))
    out = {"tested": True, "method": "gyro angle", "statistic": Q, "dof": m, "p_value": p, "alpha": alpha,
           "pulses": K, "jitter2_s2": j2, "jitter2_se_s2": se_j2, "jitter2_interval_s2": r["interval"],
           "sigma_T_s": sig, "sigma_T_se_s": se_j2 / (2.0 * sig),
           "sigma_T_interval_s": [float(np.sqrt(x + dt_s**2 / 12.0)) for x in r["interval"]],
           "interval_level": 0.6827, "sample_interval_s": dt_s, "pulse_width_s": edges["width_s"],
           "sloped_edges": edges["sloped"], "null": null, "gyro_sigma_V": c["sigma_u"], **parts, **width,
           "scatter_rms_s": float(np.sqrt(np.mean(ts[np.isfinite(ts)] ** 2))),
           "grid_rms_s": float(np.sqrt(np.mean(v)))}
    out["accepted"] = bool(p < alpha and j2 > 0)
    if out["accepted"]:
        out["finding"] = timer_finding(
            "the index pulses scatter about the table angle the gyro integrates by more than the sample grid's "
            f"{np.sqrt(np.mean(v)) * 1e3:.2f} ms rms: a timer jitter of {np.sqrt(j2) * 1e3:.2f} ms", out,
            "pulse-time residual rms against the gyro's angle (ordinary fit), and the grid's alone")
    return out
