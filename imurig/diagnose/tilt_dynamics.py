"""Diagnosis of the tilt table's slews against the dynamic twin (:mod:`imurig.diagnose.tilt_twin`).

Between positions the table slews; the static twin (the position means) cannot see what acts
only while it moves: a time delay of a channel against the set-points (the multiplexer's scan
skew), a lever arm of the triad, a wrong local gravity (its g-free kinematic part). The
measurement, the nuisance, the noise model and the candidates are set out in
:func:`diagnose_tilt_dynamics`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from imurig.calibration.accelerometer import ACC, AXES
from imurig.diagnose.engine import Candidate, select_effects
from imurig.diagnose.samples import scan_order
from imurig.diagnose.steps import effect_steps
from imurig.diagnose.tilt_twin import tilt_table_twin
from imurig.kernel.recording import Recording

#: the dynamic twin's memory (five replays' f_C in RAM) limits the record length it takes
MAX_DYNAMIC_SAMPLES = 1_500_000
#: effects of the slews between positions (the dynamic twin of :func:`diagnose_tilt_dynamics`)
DYNAMIC_EFFECTS = ("time_delay", "lever_arm", "wrong_local_gravity")


def _block_mean(x: np.ndarray, idx: np.ndarray, nb: int) -> np.ndarray:
    """Means of x (n,) or (n, k) over the averaging blocks ``idx`` (n,), -1 = dropped."""
    keep = idx >= 0
    cnt = np.bincount(idx[keep], minlength=nb).astype(float)
    if x.ndim == 1:
        return np.bincount(idx[keep], weights=x[keep], minlength=nb) / cnt
    return np.stack([np.bincount(idx[keep], weights=x[keep, k], minlength=nb) for k in range(x.shape[1])], 1) / cnt[:, None]


def _stacked(cols3: np.ndarray) -> np.ndarray:
    """(nb, 3) per-axis pattern -> (3 nb,) stacked (x blocks, y blocks, z blocks)."""
    return cols3.T.reshape(-1)


def _axis_only(col: np.ndarray, a: int) -> np.ndarray:
    """Axis ``a``'s column of the (nb, 3) pattern ``col``, zero on the other axes, stacked (3 nb,)."""
    z = np.zeros((col.shape[0], 3))
    z[:, a] = col[:, a]
    return _stacked(z)


@dataclass
class _Slews:
    """The slews on averaging blocks: the recording through the static calibration and the twin.

    Per sample (n): t [s], idx (the block of each sample, -1 = dropped), f_meas (n, 3) [m/s^2],
    the twin's w_tw (n, 3) [rad/s] and dw/dt alpha_w (n, 3) [rad/s^2]; per block (nb): the
    residual R = block mean of f_meas - f_model (nb, 3) [m/s^2], the twin's F_tw (nb, 3) [m/s^2],
    the run of each block, whether the twin moves in it and whether it starts a run; the
    channels' skew (3,) [s] and the candidates' block-mean patterns ``cand_cols``."""

    t: np.ndarray
    idx: np.ndarray
    nb: int
    run_of_block: np.ndarray
    f_meas: np.ndarray
    w_tw: np.ndarray
    alpha_w: np.ndarray
    skew: np.ndarray
    R: np.ndarray
    F_tw: np.ndarray
    moving: np.ndarray
    first: np.ndarray
    cand_cols: dict


def _slews(rec: Recording, cal, tw: dict, skew_in_twin: bool, block: int) -> _Slews:
    """The residual r = f_meas - f_model averaged over ``block`` samples inside each run, and the
    candidates' patterns on the same blocks (see :func:`diagnose_tilt_dynamics`)."""
    s = np.asarray(rec.meta["acc_nominal_sensitivity_V_per_m_s2"], float)
    f_meas = cal.predict(rec.stack(list(ACC)) / s)
    t = rec.time_s
    blocks = rec.blocks()
    f_tw, w_tw = tw["f_C"], tw["w_C"]
    dfdt = np.empty_like(f_tw)
    alpha_w = np.empty_like(w_tw)
    for b in blocks:
        dfdt[b] = np.gradient(f_tw[b], t[b], axis=0)
        alpha_w[b] = np.gradient(w_tw[b], t[b], axis=0)
    adc = rec.meta.get("adc", {})
    scan = list(adc.get("scan_list", []))
    skew = np.array([scan.index(c) / float(adc["mux_frequency_hz"]) if (c in scan and adc.get("skew_enabled", True))
                     else 0.0 for c in ACC]) if scan and "mux_frequency_hz" in adc else np.zeros(3)
    f_model = f_tw + (skew * dfdt if skew_in_twin else 0.0)
    r = f_meas - f_model
    # averaging blocks of `block` samples inside each run
    idx = -np.ones(rec.n, int)
    run_of_block, nb = [], 0
    for i, b in enumerate(blocks):
        k = (b.stop - b.start) // block
        idx[b.start:b.start + k * block] = nb + np.arange(k * block) // block
        run_of_block += [i] * k
        nb += k
    run_of_block = np.array(run_of_block)
    R = _block_mean(r, idx, nb)                                                   # (nb, 3)
    kin = lambda v: np.cross(alpha_w, v) + np.cross(w_tw, np.cross(w_tw, v))
    cand_cols = {"delay": _block_mean(dfdt, idx, nb),
                 "lever": [_block_mean(kin(np.broadcast_to(e, w_tw.shape)), idx, nb) for e in np.eye(3)],
                 "gravity": _block_mean(kin(tw["r0_C"]), idx, nb)}
    first = np.concatenate(([True], run_of_block[1:] != run_of_block[:-1]))
    moving = _block_mean((np.linalg.norm(w_tw, axis=1) > 1e-6).astype(float), idx, nb) > 0
    return _Slews(t=t, idx=idx, nb=nb, run_of_block=run_of_block, f_meas=f_meas, w_tw=w_tw, alpha_w=alpha_w,
                  skew=skew, R=R, F_tw=_block_mean(f_tw, idx, nb), moving=moving, first=first, cand_cols=cand_cols)


def _window_nuisance(tw: dict, idx: np.ndarray, nb: int, n: int) -> np.ndarray:
    """The nuisance columns (3 nb, q): per set-point window and table axis the block means of the
    twin's response to a constant command offset over that window (its setting error)."""
    # nuisance: per-window responses (a window's offset holds until the next change; its transient
    # may spill into the next window, so the label runs to the start of the window after next)
    ws = tw["window_start"]
    win = np.searchsorted(ws, np.arange(n), side="right") - 1
    nuis = []
    for j in range(2):
        for parity in (0, 1):
            lab = win - ((win - parity) % 2)          # the window of this parity the sample's response belongs to
            lab = np.where(lab >= 0, lab, -1)
            keep = (idx >= 0) & (lab >= 0)
            K = int(ws.size)
            cols = np.zeros((3 * nb, K))
            cnt = np.bincount(idx[keep], minlength=nb).astype(float)
            for a in range(3):
                M = np.bincount(idx[keep] * K + lab[keep], weights=tw["resp"][2 * j + parity][keep, a],
                                minlength=nb * K).reshape(nb, K)
                cols[a * nb:(a + 1) * nb] = M / np.maximum(cnt, 1)[:, None]
            used = sorted(set(range(parity, K, 2)))
            nuis.append(cols[:, used])
    N = np.column_stack(nuis)
    return N[:, np.linalg.norm(N, axis=0) > 0]


def _constant_columns(F_tw: np.ndarray, nb: int, recalibrate_axes: tuple) -> tuple[np.ndarray, list]:
    """Per axis a bias; on ``recalibrate_axes`` also a linear re-calibration against the twin's f."""
    # per axis a bias; on the axes in ``recalibrate_axes`` also a linear re-calibration against the
    # twin's specific force: where the position means found an effect the static fit lacked
    # (crosstalk...), that fit absorbed part of it, which acts in the slews as an error of gain and
    # axes (a false lever arm of 4 cm on the crosstalk case without it). Not added elsewhere: in
    # constant-rate slews df/dt is a rotation of f, so these columns also take power from a delay.
    consts = np.column_stack([np.kron(np.eye(3), np.ones((nb, 1)))]
                             + [np.kron(np.eye(3)[:, [a]], F_tw) for a, ax in enumerate(AXES) if ax in recalibrate_axes])
    const_names = [f"bias_{a}" for a in AXES] + [f"gain_{a}{k}" for a in AXES if a in recalibrate_axes for k in AXES]
    return consts, const_names


def _ar1_whitener(rho: np.ndarray, first: np.ndarray, nb: int):
    """x (3 nb,) or (3 nb, k) -> its AR(1) innovations per axis, restarted at every run's first block."""
    def whiten(x):
        x = np.asarray(x, float).reshape(3 * nb, -1)
        out = np.empty_like(x)
        for a in range(3):
            xa = x[a * nb:(a + 1) * nb]
            prev = np.vstack([np.zeros((1, xa.shape[1])), xa[:-1]])
            prev[first] = 0.0
            wa = xa - rho[a] * prev
            wa[first] *= np.sqrt(1 - rho[a] ** 2)
            out[a * nb:(a + 1) * nb] = wa
        return out
    return whiten


def _ar1_noise_model(y: np.ndarray, sl: _Slews):
    """(rho (3,), innovation sigma (3,) [m/s^2], whiten) of the stacked block residual ``y``."""
    nb, moving, first = sl.nb, sl.moving, sl.first
    # noise model: AR(1) per axis from the blocks where the twin rests (no rotation: no candidate
    # acts there), each resting stretch's mean removed (the window's angle offset), within runs
    stretch = np.cumsum(moving | first)                  # a new label after every moving block / run start
    rest = ~moving & ~first & np.concatenate(([False], ~moving[:-1]))     # pairs of resting neighbours
    rho, sig = np.zeros(3), np.zeros(3)
    e = np.zeros(3 * nb)
    for a in range(3):
        ya = y[a * nb:(a + 1) * nb]
        mean = np.bincount(stretch[~moving], ya[~moving], minlength=stretch.max() + 1) / np.maximum(
            np.bincount(stretch[~moving], minlength=stretch.max() + 1), 1)
        ea = np.where(moving, 0.0, ya - mean[stretch])
        e[a * nb:(a + 1) * nb] = ea
        rho[a] = float(np.sum(ea[1:] * ea[:-1] * rest[1:]) / np.sum(ea[:-1] ** 2 * rest[1:]))
    whiten = _ar1_whitener(rho, first, nb)
    ew = whiten(e)[:, 0]
    for a in range(3):
        # each resting stretch's mean took one degree of freedom
        n_rest = int(rest.sum())
        sig[a] = float(np.sqrt(np.sum(ew[a * nb:(a + 1) * nb][rest] ** 2) / max(n_rest - np.unique(stretch[rest]).size, 1)))
    return rho, sig, whiten


def _slew_library(cand_cols: dict, unit) -> tuple[list, dict]:
    """The slews' candidates (their columns in the whitened, nuisance-projected space ``unit(x)``)."""
    lib_cols = {}
    for a, ax in enumerate(AXES):
        lib_cols[f"time_delay_{ax}"] = unit(_axis_only(cand_cols["delay"], a))
    lib_cols["lever_arm"] = unit(np.column_stack([_stacked(c) for c in cand_cols["lever"]]))
    lib_cols["wrong_local_gravity"] = unit(_stacked(cand_cols["gravity"]))
    lib = [Candidate(f"time_delay_{ax}", f"acc_{ax} is sampled later than its time tag (the set-points' clock) by "
                     "tau: a time delay of the channel against the set-points (e.g. the multiplexer's scan skew, "
                     "slot / f_mux)", ("tau_s",), lambda _, c=lib_cols[f"time_delay_{ax}"]: c) for ax in AXES]
    lib.append(Candidate("lever_arm", "the accelerometers sense off the point the twin assumes (lever arm dr in "
                         "the case frame): tangential and centripetal accelerations of the slews",
                         ("dr_x_m", "dr_y_m", "dr_z_m"), lambda _, c=lib_cols["lever_arm"]: c))
    lib.append(Candidate("wrong_local_gravity", "the twin's local gravity is wrong: the static fit absorbs it into "
                         "the scale factors, so the slews' g-free kinematic accelerations read eps too large "
                         "(eps = g_twin / g_true - 1); identical to a lever arm eps x r0 along the phi axis",
                         ("eps",), lambda _, c=lib_cols["wrong_local_gravity"]: c))
    return lib, lib_cols


def _crosstalk_columns(rec: Recording, sl: _Slews, crosstalk_axes: tuple) -> tuple[list, list]:
    """Nuisance columns (3 nb,) of the previously scanned channel on ``crosstalk_axes``, and their names."""
    # the multiplexer's crosstalk acts sample by sample: in the slews the previously scanned channel
    # (a magnetometer turning in the Earth's field, a neighbour accelerometer) moves. Where the
    # position means found it (``crosstalk_axes``), its column joins the nuisance here, so that its
    # dynamic signature is not forced onto a delay or a lever arm; it is tested (and reported) in
    # the position means only (as a slew candidate too it fired on 6/30 null records)
    scan, _ = scan_order(rec)
    cols, names = [], []
    for a, ax in enumerate(AXES):
        ch = f"acc_{ax}"
        if ax in crosstalk_axes and ch in scan and len(scan) > 1:
            prev = scan[scan.index(ch) - 1]
            if prev in rec.channels:
                z = np.zeros((sl.nb, 3))
                z[:, a] = _block_mean(np.asarray(rec.channels[prev], float), sl.idx, sl.nb)
                cols.append(_stacked(z))
                names.append(f"crosstalk_{ax}_from_{prev}")
    return cols, names


def diagnose_tilt_dynamics(rec: Recording, cal, rng: np.random.Generator, alpha: float = 0.01, n_sim: int = 300,
                           skew_in_twin: bool = True, block: int = 50, twin: dict | None = None,
                           recalibrate_axes: tuple = (), crosstalk_axes: tuple = ()) -> dict:
    """Compare the slews between positions with the dynamic twin and test delay, lever arm and g.

    Measurement: f_meas (n, 3) = the nominal static calibration ``cal`` applied to every sample
    (volts / nominal sensitivity). Twin (:func:`tilt_table_twin`): the set-points through the
    table's slew law and servo (MuJoCo), f_twin at the 'imu' site; with ``skew_in_twin`` the
    DAQ's multiplexer skew is modelled too: slot j of the scan list is read j / f_mux after the
    time tag, f_twin,j(t + j / f_mux) ~ f_twin,j + (j / f_mux) df_twin,j/dt. Residual
    r = f_meas - f_twin, averaged over ``block`` samples (20 Hz), stacked over the three axes.

    Nominal (nuisance) columns: per axis a constant, and per set-point window and axis (theta,
    phi) the twin's linear response to a constant command offset over that window (the table's
    setting error: angle offset plus the servo's transient), from four extra MuJoCo replays.
    Candidates (columns are exact first-order forward models):

    - ``time_delay`` on acc_j: r_j = tau_j df_twin,j/dt (tau > 0: sampled later than its time tag);
    - ``lever_arm``: r = dw/dt x dr + w x (w x dr), dr (3,) m in C (the triad senses at dr
      from where the twin puts it);
    - ``wrong_local_gravity``: r = eps f_kin, f_kin = dw/dt x r0 + w x (w x r0) the twin's
      kinematic part, eps = g_twin / g_true - 1. (The static fit scales everything by
      g_twin / g_true, so only the g-free kinematic part shows; it equals a lever arm
      eps r0 along the phi axis in the platform frame: the two are indistinguishable.)

    ``recalibrate_axes``: axes whose position means showed an effect the static fit lacks; their
    bias, gains and axes are re-fitted in the slews (nuisance columns f_twin,k on axis j).
    ``crosstalk_axes``: axes whose position means found crosstalk; the previously scanned
    channel's block means join the nuisance on them.

    Noise model first: per axis an AR(1) fitted to the nuisance-only residual whitens rows and
    columns within each run; each axis is then scaled to unit innovation variance.
    """
    rec.require({c: "V" for c in ACC})
    tw = twin if twin is not None else tilt_table_twin(rec)
    sl = _slews(rec, cal, tw, skew_in_twin, block)
    nb = sl.nb
    N = _window_nuisance(tw, sl.idx, nb, rec.n)
    consts, const_names = _constant_columns(sl.F_tw, nb, recalibrate_axes)
    y = sl.R.T.reshape(-1)
    rho, sig, whiten = _ar1_noise_model(y, sl)
    scale = np.repeat(1.0 / sig, nb)[:, None]
    yw, Nw = (whiten(y) * scale)[:, 0], whiten(N) * scale
    Q, _ = np.linalg.qr(Nw)
    proj = lambda A: A - Q @ (Q.T @ A)
    yp = proj(yw[:, None])[:, 0]
    lib, lib_cols = _slew_library(sl.cand_cols, lambda x: proj(whiten(x) * scale))
    xt_cols, xt_names = _crosstalk_columns(rec, sl, crosstalk_axes)
    consts = np.column_stack([consts, *xt_cols])
    const_names += xt_names
    X0 = proj(whiten(consts) * scale)
    d = select_effects(yp, X0, const_names, lib, rng, alpha=alpha, n_sim=n_sim)
    out = d.to_dict()
    # the report: the fit step by step (whitened space) and the residuals in m/s^2 before and after
    out["fit_steps"] = effect_steps(yp, X0, const_names, lib, d)["steps"]
    out["residuals"] = _slew_residuals(sl, y, np.column_stack([N, consts]), d, lambda A: whiten(A) * scale)
    _name_channels(out["findings"])
    out.update({
        "twin": "set-points -> the table's slew law and servo (MuJoCo replay), surveyed table errors, g = "
                f"{tw['gravity_m_s2']:.8g} m/s^2" + ("; multiplexer skew modelled" if skew_in_twin else
                                                     "; channels taken as sampled at their time tags")
                + "".join(f"; {note}" for note in tw.get("stops_removed", [])),
        "skew_in_twin": bool(skew_in_twin), "skew_s": sl.skew.tolist(), "averaging_samples": block,
        "noise_model": {"ar1": rho.tolist(), "innovation_sigma_m_s2": sig.tolist()},
        "gravity_check": {"g_twin_m_s2": tw["gravity_m_s2"], **_gravity_check(yp, X0, lib_cols, d)},
        "lever_arm_r0_m": [float(v) for v in np.abs(tw["r0_C"]).max(axis=0)]})
    return out


def _slew_residuals(sl: _Slews, y: np.ndarray, A0: np.ndarray, d, unit) -> dict:
    """The residuals (nb, 3) [m/s^2] before and after, from the full GLS fit (nuisance, constants
    ``A0`` and the accepted effects, whitened by ``unit``; by Frisch-Waugh-Lovell its effect
    coefficients are the engine's), with the recording, the twins and the revealing variables."""
    nb, cand_cols = sl.nb, sl.cand_cols
    raw = {f"time_delay_{ax}": _axis_only(cand_cols["delay"], a) for a, ax in enumerate(AXES)}
    raw["lever_arm"] = np.column_stack([_stacked(c) for c in cand_cols["lever"]])
    raw["wrong_local_gravity"] = _stacked(cand_cols["gravity"])
    A1 = np.column_stack([A0] + [raw[f.name] for f in d.findings])
    resid = []
    for A in (A0, A1):
        coef = np.linalg.lstsq(unit(A), unit(y)[:, 0], rcond=None)[0]
        resid.append((y - A @ coef).reshape(3, nb).T)
    F_meas = _block_mean(sl.f_meas, sl.idx, nb)
    contrib = {}
    for f in d.findings:
        C = np.asarray(raw[f.name], float).reshape(3 * nb, -1)
        c = np.array([v[0] for v in f.params.values()])
        contrib[f.name] = (C @ c).reshape(3, nb).T.tolist()
    return {
        "unit": "m/s^2", "time_s": _block_mean(sl.t, sl.idx, nb).tolist(), "moving": sl.moving.tolist(),
        "run": sl.run_of_block.tolist(), "recording": F_meas.tolist(), "twin": (F_meas - resid[0]).tolist(),
        "corrected_twin": (F_meas - resid[1]).tolist(), "before": resid[0].tolist(), "after": resid[1].tolist(),
        "df_twin_dt_m_s3": cand_cols["delay"].tolist(),
        "angular_acceleration_rad_s2": _block_mean(sl.alpha_w, sl.idx, nb).tolist(),
        "angular_rate_rad_s": _block_mean(sl.w_tw, sl.idx, nb).tolist(), "effect_contribution_m_s2": contrib,
        "convention": "residual = recording - twin (20 Hz block means of the calibrated samples); the twin "
                      "includes the fitted per-window angle offsets and per-axis constants (before), and the "
                      "accepted effects (corrected twin)"}


def _name_channels(findings: list) -> None:
    """Per-axis findings 'time_delay_y' -> effect 'time_delay', channel 'y'; joint ones: channel 'acc'."""
    for fd in findings:
        if fd["effect"].startswith(("time_delay_", "adc_crosstalk_")):
            fd["channel"] = fd["effect"][-1]
            fd["effect"] = fd["effect"][:-2]
        else:
            fd["channel"] = "acc"
        if fd["effect"] == "wrong_local_gravity":
            fd["indistinguishable_from"] = "lever_arm along the phi axis (platform frame) and the scale factors"


def _gravity_check(yp: np.ndarray, X0: np.ndarray, lib_cols: dict, d) -> dict:
    """What the slews say of g whether or not it is selected: eps jointly with the accepted effects."""
    Xg = np.column_stack([lib_cols["wrong_local_gravity"], X0] + [lib_cols[f.name] for f in d.findings
                                                                if f.name != "wrong_local_gravity"])
    cg, *_ = np.linalg.lstsq(Xg, yp, rcond=None)
    rg = yp - Xg @ cg
    covg = np.linalg.inv(Xg.T @ Xg) * float(rg @ rg) / max(yp.size - Xg.shape[1], 1)
    return {"eps": float(cg[0]), "eps_se": float(np.sqrt(covg[0, 0])),
            "note": "a g error scales the static fit's scale factors by g_twin / g_true and is "
                    "invisible in the position means; in the slews it equals a lever-arm error "
                    "eps x r0 along the phi axis (r0 = the IMU's height above the axes)"}
