"""A set-point delay of the tilt table, from a recording whose logger writes the ramps (no protocol).

Another lab's logger writes the set-points (theta, phi) it sends to the table, ramped between
positions, but nothing of the table itself (slew law, servo, survey, where the IMU sits). The
trajectory is then the logged set-points themselves; a table (or logger) that follows them late
by tau gives, at every sample n (time tag t_n, calibrated specific force f_meas in the case frame C),

    f_meas(t_n) = f_ref(sp(t_n - tau)) + o(t_n) + c(t_n) + alpha x r + w x (w x r) + e_n,

- f_ref(theta, phi) the specific force at rest (the convention of
  :func:`imurig.rigs.tilt_kinematics.specific_force_C`: the mounting of the run, the site's gravity,
  the surveyed table errors where the file gives them), sp(t - tau) the logged set-points linearly
  interpolated at the shifted time (exact for any tau, any sample rate, using the time tags);
- o_j(t) = a_j,w + (b_j,w - a_j,w) p(t) per move window w and axis j: the levels of the plateau
  before and after (the table's setting error, a slow drift the static twin lacks), p the move's
  progress (0 before, 1 after, linear in time through it); 2 nuisance parameters per window and
  axis, estimated jointly (the plateaus' own means are noisy enough to bias a microsecond SE);
- c(t): on axis j, the static calibration's own errors carried through the move: columns f_ref,k - lerp
  (k = x, y, z) and f_ref,j^2 - lerp (gain, axes, square; 12 nuisance parameters);
- w, alpha (rad/s, rad/s^2) the table's angular rate and acceleration in C from the same shifted
  set-points, r (m, 3 nuisance parameters) the triad's unknown lever arm from the axes'
  intersection (tangential and centripetal accelerations of the moves);
- e the noise: per axis AR(1) on the 0.1-s block means within each move window.

tau is profiled exactly (the shifted interpolation, not a first-order expansion; to first order
r(t) = -tau df_ref/dt): a grid, a bounded search, then Gauss-Newton steps in the whitened space
with every nuisance projected out. SE(tau) is robust by move (a sandwich over the G move windows:
what a move shares, e.g. one rounding of its logged ramp or a servo transient, is not averaged as
if independent) with the CR2 small-sample correction; the test is t = tau / SE against Student's t
with Bell-McCaffrey degrees of freedom (:mod:`imurig.diagnose.cluster_robust`), alpha per record.
The likelihood-ratio F, the model-based and the plain (CR1) SEs are reported beside it. An accepted
delay gives the static diagnosis its settle guard (:func:`imurig.diagnose.tilt_table.settle_guard`).
"""
from __future__ import annotations

import numpy as np
import scipy.linalg
import scipy.optimize
import scipy.stats

from imurig.calibration.accelerometer import ACC
from imurig.diagnose.cluster_robust import cr2_test, two_sided_p
from imurig.diagnose.samples import SPIKE_SIGMAS, SPIKE_WINDOW, adc_step, despike
from imurig.diagnose.tilt_dynamics import _ar1_whitener
from imurig.kernel.recording import Recording
from imurig.kernel.site import Site
from imurig.rigs.tilt_kinematics import MOUNTS, rot_x, rot_y, rot_z

#: seconds of plateau kept either side of a move (they pin the move's offsets)
MARGIN_S = 0.5
#: the largest delay looked for (s)
MAX_DELAY_S = 0.3
#: the block over which samples are averaged (s): the regressors are smooth on this scale
BLOCK_S = 0.1
#: nuisance columns of the moves' model: lever arm (3), static calibration errors (3 x 4)
N_NUISANCE = 15
#: the physics of the finding
PHYSICS = ("the table follows the logged set-points tau late (servo lag, a logger that tags the set-point "
           "before the table moves): every channel reads f_ref(sp(t - tau)), to first order -tau df_ref/dt in "
           "the ramps")


def ramped(sp: np.ndarray) -> bool:
    """Whether logged set-points (n, 2) ramp: some change lasts three or more consecutive samples
    (a stepped log changes once per move, and the table's own trajectory is then unknown)."""
    moving = np.any(np.diff(sp, axis=0) != 0, axis=1).astype(np.int8)
    return bool(np.any(np.convolve(moving, np.ones(3, np.int8), mode="valid") == 3))


def _moves(sp: np.ndarray, blocks) -> np.ndarray:
    """(k, 2) first and last sample index of each ramped move inside a contiguous block (set-points
    changing on >= 3 samples; gaps < 3 samples merged); a step between runs is no move."""
    out = []
    for b in blocks:
        ch = b.start + np.flatnonzero(np.any(np.diff(sp[b], axis=0) != 0, axis=1))
        if ch.size == 0:
            continue
        brk = np.flatnonzero(np.diff(ch) > 3)
        starts = np.concatenate(([ch[0]], ch[brk + 1]))
        stops = np.concatenate((ch[brk], [ch[-1]])) + 1
        out += [(a, c) for a, c in zip(starts, stops) if c - a >= 3]
    return np.array(out, int).reshape(-1, 2)


def _attitude(theta, phi, mount: np.ndarray, survey: dict | None = None) -> np.ndarray:
    """A (n, 3, 3): lab vectors in C, A = R_MC^T Rz(phi + phi0)^T Ry(theta + theta0)^T Rx(level_x)^T
    (f_C = A (0, 0, g)); the table errors of the ``survey`` where the file gives one, else zero."""
    sv = survey or {}
    phi0 = sv.get("phi_zero_rad") or {}
    A = np.empty((np.size(theta), 3, 3))
    for m in np.unique(mount):
        sel = mount == m
        A[sel] = (MOUNTS[str(m)].T @ np.swapaxes(rot_z(phi[sel] + phi0.get(str(m), 0.0)), -1, -2)
                  @ np.swapaxes(rot_y(theta[sel] + sv.get("theta_zero_rad", 0.0)), -1, -2)
                  @ rot_x(np.float64(sv.get("level_x_rad", 0.0))).T)
    return A


def _kinematics(t, sp, mount, survey: dict | None, h: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """(w_C, alpha_C) (n, 3): the angular rate of C, [w]x = A dA^T/dt, and its derivative."""
    dsp = np.gradient(sp, t, axis=0)
    A = _attitude(sp[:, 0], sp[:, 1], mount, survey)
    dA = sum((_attitude(sp[:, 0] + h * (j == 0), sp[:, 1] + h * (j == 1), mount, survey)
              - _attitude(sp[:, 0] - h * (j == 0), sp[:, 1] - h * (j == 1), mount, survey)) / (2 * h)
             * dsp[:, j, None, None] for j in range(2))
    W = A @ np.swapaxes(dA, -1, -2)
    w = np.column_stack([W[:, 2, 1], W[:, 0, 2], W[:, 1, 0]])
    return w, np.gradient(w, t, axis=0)


class _Windows:
    """The move windows of a recording: samples, blocks, offsets o(t) and the block-mean operator."""

    def __init__(self, rec: Recording, f_meas: np.ndarray, mount: np.ndarray, g: float):
        t, sp = rec.time_s, np.column_stack([rec.channels["theta"], rec.channels["phi"]])
        self.t_all, self.sp_all, self.g = t, sp, g
        self.survey = rec.meta.get("table_survey") or {}
        blocks = rec.blocks()
        mv = _moves(sp, blocks)
        n, fs = t.size, rec.sample_rate_hz
        M, L = int(np.ceil(MARGIN_S * fs)), max(1, int(round(BLOCK_S * fs)))
        r_static = f_meas - self.f_ref(sp, mount)
        # each move's neighbours within its contiguous block: the plateau before and after it
        blk = np.array([next(i for i, b in enumerate(blocks) if b.start <= s0 < b.stop) for s0 in mv[:, 0]], int)
        prev_end = [mv[k - 1, 1] if k > 0 and blk[k - 1] == blk[k] else blocks[blk[k]].start for k in range(len(mv))]
        next_start = [mv[k + 1, 0] if k + 1 < len(mv) and blk[k + 1] == blk[k] else blocks[blk[k]].stop
                      for k in range(len(mv))]

        def plateau(lo, hi):
            """The mean static residual on [lo, hi) (None when shorter than a block)."""
            return r_static[lo:hi].mean(axis=0) if hi - lo >= L else None
        sel, o, lin, idx, prog, moving, win_first, nb = [], [], [], [], [], [], [], 0
        for k, (s0, s1) in enumerate(mv):
            a0, b1 = prev_end[k], next_start[k]
            oa = plateau(a0 + (M if k > 0 and a0 == mv[k - 1, 1] else 0), s0 - M)
            ob = plateau(s1 + M, b1 - (M if b1 < blocks[blk[k]].stop else 0))
            if oa is None and ob is None:
                continue
            oa, ob = (ob if oa is None else oa), (oa if ob is None else ob)
            lo, hi = max(s0 - M, (a0 + s0) // 2), min(s1 + M + 1, (s1 + b1) // 2)
            m = (hi - lo) // L
            if m < 3:
                continue
            ii = np.arange(lo, lo + m * L)
            p = np.clip((t[ii] - t[s0]) / max(t[s1] - t[s0], 1e-12), 0.0, 1.0)[:, None]
            sel.append(ii)
            o.append(oa + (ob - oa) * p)
            fa, fb = (self.f_ref(sp[[i]], mount[[i]]) for i in (s0, s1))
            lin.append(np.hstack([fa + (fb - fa) * p, fa ** 2 + (fb ** 2 - fa ** 2) * p]))
            idx.append(nb + np.arange(m * L) // L)
            prog.append(p[:, 0])
            moving.append((ii >= s0) & (ii <= s1))
            win_first.append(nb)
            nb += m
        self.n_moves = int(len(mv))
        self.ii = np.concatenate(sel) if sel else np.zeros(0, int)
        self.offset = np.concatenate(o) if o else np.zeros((0, 3))
        self.idx = np.concatenate(idx) if idx else np.zeros(0, int)
        self.nb, self.L = nb, L
        self.first = np.zeros(nb, bool)
        self.first[win_first] = True
        self.mount = mount[self.ii]
        self.y_meas = f_meas[self.ii] - self.offset
        self.f_meas_blocks = self.block(f_meas[self.ii])
        self.f_lin = np.concatenate(lin) if lin else np.zeros((0, 6))
        self._lever = {}
        self.progress = self.block(np.concatenate(prog)[:, None])[:, 0] if prog else np.zeros(0)
        self.window = np.cumsum(self.first) - 1
        self.moving = self.block(np.concatenate(moving)[:, None].astype(float))[:, 0] > 0 if moving else np.zeros(0, bool)

    def f_ref(self, sp: np.ndarray, mount: np.ndarray) -> np.ndarray:
        """f_ref (n, 3) m/s^2 of set-points sp (n, 2) rad on mountings ``mount`` (n,)."""
        return _attitude(sp[:, 0], sp[:, 1], mount, self.survey)[:, :, 2] * self.g

    def block(self, x: np.ndarray) -> np.ndarray:
        """Block means (nb, k) of per-window-sample values x (m, k)."""
        return np.stack([np.bincount(self.idx, x[:, k], minlength=self.nb) for k in range(x.shape[1])], 1) / self.L

    def model(self, tau: float) -> tuple[np.ndarray, np.ndarray]:
        """(y (3 nb,), X (3 nb, 15)): block residual f_meas - o - f_ref(sp(t - tau)) stacked per axis;
        the lever-arm columns (:meth:`lever_columns`) and the static calibration's errors through the
        move: on axis j, f_ref,k - o_k (k = x, y, z) and f_ref,j^2 - o_j^2, with o the straight line
        between the plateaus' values (an error of gain, axes or square the plateau offsets o(t) do
        not carry into the move)."""
        t = self.t_all[self.ii]
        sp = np.column_stack([np.interp(t - tau, self.t_all, self.sp_all[:, j]) for j in range(2)])
        F = self.f_ref(sp, self.mount)
        y = self.block(self.y_meas - F)
        chord = self.block(np.hstack([F, F ** 2]) - self.f_lin)
        cols = []
        for a in range(3):
            for k in (0, 1, 2, 3 + a):
                z = np.zeros((self.nb, 3))
                z[:, a] = chord[:, k]
                cols.append(z.T.reshape(-1))
        return y.T.reshape(-1), np.column_stack([self.lever_columns(tau), *cols])

    def lever_columns(self, tau: float) -> np.ndarray:
        """(3 nb, 3) alpha x e_k + w x (w x e_k) from the set-points shifted by tau rounded to 10 ms
        (a nuisance: its change within 5 ms of tau is far below its own uncertainty), cached."""
        key = round(tau / 0.01)
        if key not in self._lever:
            t = self.t_all[self.ii]
            sp = np.column_stack([np.interp(t - 0.01 * key, self.t_all, self.sp_all[:, j]) for j in range(2)])
            w, al = _kinematics(t, sp, self.mount, self.survey)
            X = [self.block(np.cross(al, e) + np.cross(w, np.cross(w, e))) for e in np.eye(3)]
            self._lever[key] = np.column_stack([c.T.reshape(-1) for c in X])
        return self._lever[key]


def _whitener(rho: np.ndarray, sig: np.ndarray, first: np.ndarray, nb: int):
    """x (3 nb, k) -> per axis AR(1) innovations / sigma, restarted at every window's first block."""
    ar1 = _ar1_whitener(rho, first, nb)
    scale = np.repeat(1.0 / np.asarray(sig, float), nb)[:, None]
    return lambda x: ar1(x) * scale


def _space(win: _Windows, rho: np.ndarray, sig: np.ndarray):
    """A (3 nb, k) -> whitened (:func:`_whitener`) and projected off each window's offsets: per window
    and axis the columns 1 and p (the move's progress), i.e. the level of the plateau before and of the
    plateau after, estimated with everything else (whitening acts within a window, so the whitened
    offset columns stay local to their window)."""
    nb = win.nb
    whiten = _whitener(rho, sig, win.first, nb)
    grp = np.concatenate([win.window + a * (int(win.window.max()) + 1) for a in range(3)])
    n_g = int(grp.max()) + 1
    N = whiten(np.column_stack([np.ones(3 * nb), np.tile(win.progress, 3)]))
    g11, g12, g22 = (np.bincount(grp, u * v, minlength=n_g) for u, v in ((N[:, 0], N[:, 0]), (N[:, 0], N[:, 1]),
                                                                         (N[:, 1], N[:, 1])))
    det = g11 * g22 - g12 ** 2

    def space(x):
        A = whiten(x)
        out = np.empty_like(A)
        for k in range(A.shape[1]):
            c1, c2 = np.bincount(grp, N[:, 0] * A[:, k], minlength=n_g), np.bincount(grp, N[:, 1] * A[:, k],
                                                                                     minlength=n_g)
            d1, d2 = (g22 * c1 - g12 * c2) / det, (g11 * c2 - g12 * c1) / det
            out[:, k] = A[:, k] - d1[grp] * N[:, 0] - d2[grp] * N[:, 1]
        return out
    return space


def _ssr(win: _Windows, tau: float, space) -> tuple[float, np.ndarray, np.ndarray]:
    """(SS, residual (3 nb,) in ``space``, nuisance coefficients) at ``tau``."""
    y, X = win.model(tau)
    yw, Xw = space(y)[:, 0], space(X)
    # least squares by QR on unit columns; a column the moves never excite (a lever arm along the only
    # rotation axis) is dropped, its coefficient 0
    norm = np.linalg.norm(Xw, axis=0)
    keep = norm > 1e-9 * norm.max()
    Q, R = np.linalg.qr(Xw[:, keep] / norm[keep])
    c = np.zeros(Xw.shape[1])
    c[keep] = scipy.linalg.solve_triangular(R, Q.T @ yw) / norm[keep]
    rw = yw - Xw @ c
    return float(rw @ rw), rw, c


def _profile(win: _Windows, whiten, lo: float, hi: float, step: float) -> float:
    """tau in [lo, hi] minimising SS: a grid of ``step``, then a bounded scalar search around its best point."""
    grid = np.arange(lo, hi + 1e-9, step)
    ss = [_ssr(win, float(tau), whiten)[0] for tau in grid]
    k = int(np.argmin(ss))
    a, b = grid[max(k - 1, 0)], grid[min(k + 1, grid.size - 1)]
    res = scipy.optimize.minimize_scalar(lambda tau: _ssr(win, tau, whiten)[0], bounds=(a, b), method="bounded",
                                         options={"xatol": 1e-6})
    return float(res.x)


def _sensitivity(win: _Windows, tau: float, space, h: float = 1e-4) -> np.ndarray:
    """d(model)/d tau (3 nb,) whitened and projected off the nuisance columns (central difference)."""
    yp, X = win.model(tau + h)
    ym, _ = win.model(tau - h)
    J, Xw = space((ym - yp) / (2 * h))[:, 0], space(X)
    norm = np.linalg.norm(Xw, axis=0)
    Q, _ = np.linalg.qr(Xw[:, norm > 1e-9 * norm.max()])
    return J - Q @ (Q.T @ J)


def _noise_model(win: _Windows, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per axis (rho, sigma) of the block residual r (3 nb,): AR(1) within windows."""
    nb, rho, sig = win.nb, np.zeros(3), np.zeros(3)
    pair = ~win.first
    pair[0] = False
    for a in range(3):
        ra = r[a * nb:(a + 1) * nb]
        rho[a] = float(np.clip(np.sum(ra[1:] * ra[:-1] * pair[1:]) / max(np.sum(ra[:-1] ** 2 * pair[1:]), 1e-300),
                               -0.95, 0.95))
        e = ra - rho[a] * np.concatenate(([0.0], ra[:-1])) * pair
        sig[a] = float(np.sqrt(np.mean(e[pair] ** 2)))
    return rho, np.maximum(sig, 1e-12)


def _not_tested(why: str) -> dict:
    return {"tested": False, "why": why}


def diagnose_setpoint_delay(rec: Recording, cal, alpha: float = 0.01, max_delay_s: float = MAX_DELAY_S) -> dict:
    """Test and estimate a set-point delay tau (s) of a tilt-table recording with ramped set-points
    (model and statistic: module doc); ``cal`` the static calibration (volts / nominal sensitivity
    -> f_C). Returns the findings (effect 'time_delay', channel 'acc', tau_s +- SE) and the test."""
    if not {"theta", "phi"} <= set(rec.channels):
        return _not_tested("the slews need per-sample theta/phi set-point channels")
    sp = np.column_stack([rec.channels["theta"], rec.channels["phi"]])
    if not ramped(sp):
        return _not_tested("the set-points step between positions: without the table's protocol (slew law, "
                           "servo) the trajectory through a move is unknown, so the slews are not compared")
    s = np.asarray(rec.meta["acc_nominal_sensitivity_V_per_m_s2"], float)
    f_meas = cal.predict(rec.stack(list(ACC)) / s)
    g = Site.from_dict(rec.meta.get("site", {})).gravity_m_s2
    mounts = _mounts(rec)
    q_SI = np.array([adc_step(rec, c) for c in ACC]) / s
    f_meas, n_spikes = despike(f_meas, f_meas - _attitude(sp[:, 0], sp[:, 1], mounts,
                                                          rec.meta.get("table_survey") or {})[:, :, 2] * g, q_SI)
    win = _Windows(rec, f_meas, mounts, g)
    if win.nb < 30:
        return _not_tested(f"{win.nb} blocks of {BLOCK_S:g} s in the moves: too few to test a delay")
    nb = win.nb
    unit = _space(win, np.zeros(3), np.ones(3))
    # first pass unweighted on a 50-ms grid, then the noise model, then the weighted fit from there
    tau = _profile(win, unit, -max_delay_s, max_delay_s, 0.05)
    rho, sig = _noise_model(win, _ssr(win, tau, unit)[1])
    space = _space(win, rho, sig)
    # Gauss-Newton steps to the minimum (the bounded search stops at a microsecond, near the SE)
    for _ in range(4):
        J = _sensitivity(win, tau, space)
        step = float(J @ _ssr(win, tau, space)[1] / max(J @ J, 1e-300))
        tau += step
        if abs(step) < 1e-9:
            break
    J = _sensitivity(win, tau, space)
    ss1, rw1, c1 = _ssr(win, tau, space)
    ss0 = _ssr(win, 0.0, space)[0]
    r0, r1 = _ssr(win, 0.0, unit)[1], _ssr(win, tau, unit)[1]
    dof = 3 * nb - N_NUISANCE - 2 * 3 * (int(win.window.max()) + 1) - 1
    F = max(ss0 - ss1, 0.0) / (ss1 / dof)
    se_model = float(np.sqrt(ss1 / dof / max(J @ J, 1e-300)))
    # cluster-robust (by move) SE, CR2 with Bell-McCaffrey dof (module doc): CR1 against t(G - 1) fired
    # on 4 of 120 delay-free records of the independent lab at alpha = 0.01 (2 of them at p 0.007-0.012)
    move = np.tile(np.cumsum(win.first) - 1, 3)
    cr = cr2_test(np.column_stack([space(win.model(tau)[1]), J]), rw1 - J * (J @ rw1) / max(J @ J, 1e-300), move)
    G, se = cr["clusters"], cr["se"]
    t_stat = tau / se
    pval = two_sided_p(t_stat, cr["dof"])
    fired = pval < alpha
    rms0, rms1 = (float(np.sqrt(np.mean(v ** 2))) for v in (r0, r1))
    test = {"statistic": "t = tau / SE_CR2 (profiled tau, whitened, SE robust by move, CR2) against t(dof, "
                         "Bell-McCaffrey)", "t": float(t_stat), "dof": cr["dof"], "p_value": pval, "alpha": alpha,
            "threshold": float(scipy.stats.t.isf(alpha / 2, cr["dof"])), "tau_s": tau, "tau_se_s": se,
            "tau_se_cr1_s": cr["se_cr1"], "tau_se_model_s": se_model, "F_likelihood_ratio": float(F), "moves": G}
    # statistic and threshold as F(1, G - 1) = t^2, the engine's findings' form
    finding = {"effect": "time_delay", "channel": "acc", "physics": PHYSICS, "statistic": float(t_stat ** 2),
               "threshold": test["threshold"] ** 2, "p_value": pval, "scan": None,
               "variance_share": float(max(ss0 - ss1, 0.0) / ss0) if ss0 > 0 else 0.0,
               "parameters": [{"name": "tau_s", "estimate": tau, "std_error": se}],
               "rms_before": rms0, "rms_after": rms1, "indistinguishable_from": None}
    return {"tested": True, "twin": "the logged set-points as the table's trajectory (ramps), shifted by tau; the "
                                    "static calibration's residual per position interpolated across each move; "
                                    "lever arm as nuisance",
            "findings": [finding] if fired else [], "test": test, "moves": win.n_moves, "blocks": nb,
            "despiked_samples": {"count": n_spikes, "rule": f"|r - median of {SPIKE_WINDOW}| > {SPIKE_SIGMAS:g} "
                                                            "robust sigma (floor q / sqrt(12)), r = f_meas - f_ref(sp)"},
            "averaging_s": BLOCK_S, "setpoint_sample_s": 1.0 / float(rec.sample_rate_hz),
            "noise_model": {"ar1": rho.tolist(), "innovation_sigma_m_s2": sig.tolist()},
            "lever_arm_m": {"estimate": c1[:3].tolist(), "note": "nuisance (tangential and centripetal accelerations)"},
            "residuals": _residuals(win, tau, r0, r1, fired)}


def _residuals(win: _Windows, tau: float, r0: np.ndarray, r1: np.ndarray, fired: bool) -> dict:
    """The report's residuals (nb, 3) m/s^2 on the 0.1-s blocks of the move windows (offsets, the
    calibration's errors and the lever arm fitted out): before (tau = 0) and after the fitted tau
    (when accepted), the set-points' df_ref/dt (the delay's revealing variable) and the effect's
    contribution (before - after)."""
    nb, h = win.nb, 1e-4
    dfdt = (win.model(tau + h)[0] - win.model(tau - h)[0]) / (2 * h)
    before, after = r0.reshape(3, nb).T, (r1 if fired else r0).reshape(3, nb).T
    return {"unit": "m/s^2", "time_s": win.block(win.t_all[win.ii][:, None])[:, 0].tolist(),
            "moving": win.moving.tolist(), "run": win.window.tolist(), "recording": win.f_meas_blocks.tolist(),
            "twin": (win.f_meas_blocks - before).tolist(), "corrected_twin": (win.f_meas_blocks - after).tolist(),
            "before": before.tolist(),
            "after": after.tolist(), "df_twin_dt_m_s3": dfdt.reshape(3, nb).T.tolist(),
            "effect_contribution_m_s2": {"time_delay": (before - after).tolist()},
            "convention": "block means of f_meas - f_ref(sp(t - tau)) with the per-move offsets, the static "
                          "calibration's errors and the lever arm fitted out: before at tau = 0, after at the fitted "
                          "tau (when accepted); 'run' is the move window of each block"}


def _mounts(rec: Recording) -> np.ndarray:
    """The mounting of every sample (n,): the run of the latest segment started (the first before any)."""
    runs = list(rec.meta.get("runs", ["z_up"]))
    seg = rec.segments
    if "mount" in seg:
        lab = np.asarray(seg["mount"]).astype(str)
    else:
        lab = np.array([runs[int(i)] for i in seg.get("run", np.zeros(rec.n_segments, int))])
    if lab.size == 0:
        return np.full(rec.n, runs[0])
    k = np.clip(np.searchsorted(np.asarray(seg["start_s"], float), rec.time_s, side="right") - 1, 0, lab.size - 1)
    return lab[k]
