"""Diagnosis of a tilt-table recording (seed 4.3.3-4.3.4: the cable, the pump, crosstalk).

The twin is the nominal model: the physical accelerometer calibration (linear in all axes plus
each axis' own square) fitted to the per-position medians. Two levels are examined:

1. **Position means** (per axis): the residual of the nominal fit, tested by the engine of
   :mod:`imurig.diagnose.engine` against the effect library's mean-level effects
   (:mod:`imurig.sensors.effects`, each offering its columns for a ``PositionView``):
   - ``adc_crosstalk``: the previously scanned channel's voltage leaks in (its per-position
     median is the column; amplitude = the settling residual c);
   - ``temperature_drift``: bias drifting with the accelerometer temperature;
   - ``axis_misalignment``, ``scale_nonlinearity``: where the twin lacks them;
   - ``cross_coupling``: products u_j u_k of the other axes.
2. **Within-position scatter** (per axis): the spread of the 100 Hz samples around each
   position's median; each scatter effect runs its own test on a ``ScatterView``:
   - ``building_vibration``: the spectrum holds a narrow peak (the pump's frequency), located
     in a time window (working hours), then refitted (amplitude at the peak frequency);
   - ``cable_fault_spikes``: isolated outliers (> 8 robust sigma) on one channel.
"""
from __future__ import annotations

import numpy as np

from imurig.calibration.accelerometer import AXES, indicated
from imurig.calibration.preprocess import lowpass_downsample, segment_statistic
from imurig.campaigns.tilt_table import calibrate, tilt_table_reference
from imurig.diagnose.engine import Candidate, select_effects
from imurig.kernel.errors import ConfigError, RecordingError
from imurig.kernel.recording import Recording
from imurig.kernel.site import parse_time
from imurig.sensors.effects import (AdcCrosstalk, ChannelSkew, LeverArm, PositionView, ScatterView, TemperatureDrift,
                                   for_view)


def _hours(rec: Recording, t: np.ndarray) -> np.ndarray:
    start = parse_time(rec.meta.get("start_time", "2005-01-01T00:00:00+00:00"))
    return (start.hour + start.minute / 60 + (t - rec.time_s[0]) / 3600) % 24


TWIN_MODELS = ("physical", "own_axis", "linear")


def diagnose_tilt_table(rec: Recording, rng: np.random.Generator, alpha: float = 0.01, n_sim: int = 300,
                        twin_model: str = "physical", dynamics: bool = False, skew_in_twin: bool = True) -> dict:
    """Diagnose a tilt-table recording against the twin ``twin_model``:

    - ``physical``: u_j = b + s (f_j + m_jk f_k + m_jl f_l) + k2 f_j^2 (the lab's final model);
    - ``own_axis``: b + s f_j + k2 f_j^2 (a twin without misalignment);
    - ``linear``: b + s f_j + m_jk f_k + m_jl f_l (a twin without nonlinearity).

    Effects the twin lacks (misalignment, nonlinearity) join the candidate library. With
    ``dynamics`` the slews between positions are compared with the dynamic twin as well
    (:func:`diagnose_tilt_dynamics`: time delay, lever arm, wrong local gravity; ``skew_in_twin``:
    whether that twin models the multiplexer's channel skew).
    """
    if twin_model not in TWIN_MODELS:
        raise ConfigError(f"unknown twin model '{twin_model}'; choose one of {', '.join(TWIN_MODELS)}")
    rec100 = lowpass_downsample(rec)
    cal = calibrate(rec, model=twin_model, processed=rec100)
    u, _ = indicated(rec100)
    seg = rec100.segments
    mid = 0.5 * (seg["start_s"] + seg["stop_s"])
    scan = list(rec.meta.get("adc", {}).get("scan_list", []))
    out = {"twin": f"'{twin_model}' accelerometer model fitted to per-position medians", "twin_model": twin_model,
           "axes": {}}
    inputs = {n: u[:, j] for j, n in enumerate(("ax", "ay", "az"))}
    median_cache = {}

    def medians(name: str):
        """Per-position median of a recorded channel (V), or None where it is not recorded."""
        if name not in median_cache:
            median_cache[name] = segment_statistic(rec100, [name], "median")[:, 0] if name in rec100.channels else None
        return median_cache[name]
    for j, a in enumerate(AXES):
        res = cal.results_[a]
        from imurig.calibration.terms import TermLibrary

        X0 = TermLibrary.from_names(res.names).design(inputs)
        ref, J, _ = tilt_table_reference(rec100)
        y = ref[:, j]
        # the survey leaves each table error uncertain (inclinometer accuracy): its effect on the
        # reference, dref/d(error), joins the twin as nuisance columns where the model terms do
        # not already hold it (a per-mounting phi-zero difference is not a misalignment)
        X0, names0 = _with_survey_nuisance(X0, list(res.names), J[:, j, :])
        ch = f"acc_{a}"
        view = PositionView(channel=ch, axis=a, readings=inputs, channel_median=medians, scan_list=tuple(scan),
                            model_terms=frozenset(res.names))
        # the mean-level effects of the library (crosstalk, temperature drift, misalignment and
        # nonlinearity where the twin lacks them, cross-coupling) offer their columns
        lib = [c for cls in for_view(PositionView.kind) for c in cls().candidates(view)]
        prev = AdcCrosstalk.previous_channel(scan, ch)
        alias = _crosstalk_alias_of_drift(lib, X0, prev)
        if alias is not None:
            lib = [c for c in lib if c.name != "adc_crosstalk"]
        d = select_effects(y, X0, names0, lib, rng, alpha=alpha, n_sim=n_sim)
        entry = d.to_dict()
        if alias is not None:
            entry["indistinguishable"] = [alias]
        entry["scatter"] = _scatter(rec100, ch, mid)
        entry.update(_position_residuals(y, X0, names0, lib, d, a, hours_elapsed=(mid - rec100.time_s[0]) / 3600.0,
                                         reading=inputs[f"a{a}"], prev=prev))
        out["axes"][a] = entry
    out["indistinguishable"] = [{
        "effects": ["wrong_local_gravity", "scale_factors"],
        "note": "a wrong local gravity in the twin scales every reference by g_twin / g_true: the position "
                "means cannot tell it from the scale factors, which absorb it exactly; only the slews' g-free "
                "kinematic accelerations could show it, and there it equals a lever-arm error along the phi axis"}]
    if dynamics:
        if rec.sample_rate_hz < 200 or not {"theta", "phi"} <= set(rec.channels):
            out["dynamic"] = {"tested": False, "why": "the slews need per-sample theta/phi set-point channels at "
                                                      ">= 200 Hz"}
        elif rec.n > MAX_DYNAMIC_SAMPLES:
            out["dynamic"] = {"tested": False, "why": f"{rec.n} samples: this version replays the whole record five "
                                                      f"times in MuJoCo and keeps it in memory; records up to "
                                                      f"{MAX_DYNAMIC_SAMPLES} samples (cut the record into runs)"}
        else:
            static_found = tuple(a for a in AXES if out["axes"][a]["findings"])
            crosstalk = tuple(a for a in AXES if any(f["effect"] == "adc_crosstalk" for f in out["axes"][a]["findings"]))
            out["dynamic"] = diagnose_tilt_dynamics(rec, cal, rng, alpha=alpha, n_sim=n_sim, skew_in_twin=skew_in_twin,
                                                    recalibrate_axes=static_found, crosstalk_axes=crosstalk)
    return out


#: what each position-mean effect's column is (the revealing variable of the report's plots): label, unit
_REVEAL = {"adc_crosstalk": ("median of the previously scanned channel '{prev}'", "V"),
           "temperature_drift": ("sensor temperature reading − mean (10 mV/K)", "V"),
           "axis_misalignment": ("indicated specific force of the other axis, {col}", "m/s²"),
           "scale_nonlinearity": ("own indicated specific force squared", "(m/s²)²"),
           "cross_coupling": ("product of the other two axes' indicated specific forces", "(m/s²)²")}


def _position_residuals(y, X0, names0, lib, d, a: str, hours_elapsed, reading, prev) -> dict:
    """The position means' fit step by step and the residuals before/after (m/s^2) with the
    revealing variable of each accepted effect (its column), for the report.

    Observable: y = the twin's reference specific force per position (m/s^2); the recording
    through the nominal calibration is y - r_before, the corrected twin y - r_before + r_after
    (so that twin - recording = r_before and corrected twin - recording = r_after)."""
    from imurig.reports.diagnosis import effect_steps

    st = effect_steps(y, X0, names0, lib, d)
    variables = []
    for f in d.findings:
        C = st["columns"][f.name]
        pnames = next(c.param_names for c in lib if c.name == f.name)
        for k in range(C.shape[1]):
            label, unit = _REVEAL.get(f.name, (f.name, "–"))
            col = f"u_{pnames[k][-1]}" if f.name == "axis_misalignment" else ""
            variables.append({"effect": f.name, "parameter": pnames[k], "label": label.format(prev=prev, col=col),
                              "unit": unit, "values": C[:, k].tolist(),
                              "coef": st["coef"].get(f"{f.name}:{pnames[k]}")})
    return {"fit_steps": st["steps"], "residuals": {
        "unit": "m/s^2", "reference": np.asarray(y, float).tolist(), "before": st["resid_before"].tolist(),
        "after": st["resid_after"].tolist(), "elapsed_h": np.asarray(hours_elapsed, float).tolist(),
        "reading_m_s2": np.asarray(reading, float).tolist(), "variables": variables,
        "convention": "residual = twin's reference - recording through the calibration (position medians)"}}


def _crosstalk_alias_of_drift(lib: list, X0: np.ndarray, prev: str | None, r_max: float = 0.9) -> dict | None:
    """Crosstalk from a temperature channel (the scan wraps from 'temp_box' to acc_x) moves
    with the temperature: across the positions its column, given the twin's columns X0, can
    match the temperature drift's. When |r| > ``r_max`` the two cannot be told apart; the
    drift is tested (a crosstalk c ~ 2e-4 of a 10 mV/K temperature channel is ~2 uV/K, far
    below a Q-Flex's bias tempco) and the pair is reported as indistinguishable."""
    cols = {c.name: c.design(None)[:, 0] for c in lib
            if c.name in ("adc_crosstalk", "temperature_drift")}
    if len(cols) < 2 or prev is None or not prev.startswith("temp"):
        return None
    Q, _ = np.linalg.qr(X0)
    a, b = (v - Q @ (Q.T @ v) for v in (cols["adc_crosstalk"], cols["temperature_drift"]))
    r = float(a @ b / np.sqrt((a @ a) * (b @ b)))
    if abs(r) <= r_max:
        return None
    return {"effects": ["temperature_drift", "adc_crosstalk"], "correlation": r,
            "note": f"crosstalk from the previously scanned channel '{prev}' (a temperature channel) has the "
                    f"temperature drift's signature across the positions (r = {r:.3f} given the twin); the drift, "
                    "the physically likely one, is tested"}


def _with_survey_nuisance(X0: np.ndarray, names: list, Jj: np.ndarray, rtol: float = 1e-6):
    """Append the survey-error columns of ``Jj`` (m, q) that add rank to X0 (m, p)."""
    X, out = X0, list(names)
    rank = np.linalg.matrix_rank(X, tol=rtol * np.linalg.norm(X, 2))
    for k in range(Jj.shape[1]):
        X1 = np.column_stack([X, Jj[:, k]])
        r1 = np.linalg.matrix_rank(X1, tol=rtol * np.linalg.norm(X1, 2))
        if r1 > rank:
            X, rank = X1, r1
            out.append(f"survey_error_{k}")
    return X, out


def _scatter(rec100: Recording, ch: str, mid: np.ndarray) -> dict:
    """Within-position scatter: each scatter effect of the library runs its own test (the pump's
    spectral peak located in the day, with its refit; the loose cable's spikes) on the samples
    of every position; a test that fires reports its finding under the effect's key."""
    j = "xyz".index(ch[-1])
    sens = rec100.meta.get("acc_nominal_sensitivity_V_per_m_s2")
    view = ScatterView(channel=ch, samples=rec100.channels[ch], positions=rec100.segment_slices(),
                       sample_rate_hz=rec100.sample_rate_hz, hour_of_day=_hours(rec100, mid),
                       sensitivity_V_per_SI=float(sens[j]) if sens is not None else None)
    out = {}
    for cls in for_view(ScatterView.kind):
        res = dict(cls().test(view))
        finding = res.pop("finding", None)
        out.update(res)
        if finding is not None:
            out[cls.finding_key] = finding
    return out


# ------------------------------------------------------------------ slews: the dynamic twin
#: the dynamic twin's memory (five replays in RAM) limits the record length it takes
MAX_DYNAMIC_SAMPLES = 1_500_000
#: effects of the slews between positions (the dynamic twin of :func:`diagnose_tilt_dynamics`)
DYNAMIC_EFFECTS = ("time_delay", "lever_arm", "wrong_local_gravity")


def slew_commands(setpoints: np.ndarray, slew_rate_rad_s: float, dt: float, min_slew_s: float = 0.5) -> np.ndarray:
    """The table controller's command (n, 2) rad for step set-points (n, 2) rad sampled every ``dt`` s.

    At every set-point change (sample i0, from p to q) the command follows the cosine slew of
    :func:`imurig.rigs.tilt_table._command_profile`: over N = max(round(min_slew / dt),
    ceil(max|q - p| / rate * pi / 2 / dt)) samples, c(i0 + k - 1) = p + (1 - cos(pi k / N)) / 2 (q - p),
    k = 1..N (peak rate ``slew_rate_rad_s``); elsewhere the command is the set-point.
    """
    sp = np.asarray(setpoints, float)
    out = sp.copy()
    for i0 in np.flatnonzero(np.any(np.diff(sp, axis=0) != 0, axis=1)) + 1:
        p, q = sp[i0 - 1], sp[i0]
        n = max(round(min_slew_s / dt), int(np.ceil(float(np.max(np.abs(q - p))) / slew_rate_rad_s * np.pi / 2 / dt)))
        s = (1 - np.cos(np.pi * np.arange(1, n + 1) / n)) / 2
        k = min(n, sp.shape[0] - i0)
        out[i0:i0 + k] = p + s[:k, None] * (q - p)
    return out


def _run_mounts(rec: Recording, blocks) -> list[str]:
    runs = list(rec.meta.get("runs", ["z_up"]))
    seg = rec.segments
    mounts = seg.get("mount")
    out = []
    for b in blocks:
        t0, t1 = rec.time_s[b.start], rec.time_s[b.stop - 1]
        inside = np.flatnonzero((seg["start_s"] >= t0) & (seg["start_s"] <= t1))
        if inside.size == 0:
            out.append(runs[0])
        elif mounts is not None:
            out.append(str(mounts[inside[0]]))
        else:
            out.append(runs[int(seg.get("run", np.zeros(rec.n_segments, int))[inside[0]])])
    return out


def tilt_table_twin(rec: Recording, gravity_m_s2: float | None = None, delta_rad: float = 1e-5) -> dict:
    """Replay the recording's set-points through the twin of the table (MuJoCo, the rig's own
    model and servo) with the surveyed table errors and the site's gravity; per contiguous run.

    Returns f_C (n, 3) m/s^2 and w_C (n, 3) rad/s at the 'imu' site (Earth's rate left out),
    r0_C (n, 3) m: the site's position from the axes' intersection in C (the lever arm the twin
    assumes), the set-point windows (start sample of each; a window runs to the next change),
    and the linear responses of f_C to a command offset of each window (see module doc of
    :func:`diagnose_tilt_dynamics`): ``resp`` (4, n, 3) for (theta, even windows), (theta,
    odd), (phi, even), (phi, odd), per rad.
    """
    from imurig.rigs.mujoco_rig import load_model, rollout_servo, sensor_slices
    from imurig.rigs.tilt_table import MOUNTS, _copy_model, _quat_wxyz, rot_x, rot_z
    from imurig.kernel.site import Site
    from imurig.kernel.units import DEG

    site = Site.from_dict(rec.meta.get("site", {}))
    g = site.gravity_m_s2 if gravity_m_s2 is None else gravity_m_s2
    sv = rec.meta.get("table_survey") or {}
    proto = rec.meta.get("protocol") or {}
    rate = float(proto.get("slew_rate_deg_s", 6.0)) * DEG
    fs = rec.sample_rate_hz
    dt = 1.0 / fs
    base = load_model("tilt_table.xml")
    base.opt.timestep = dt
    base.opt.gravity[:] = (0.0, 0.0, -g)
    bid_base, bid_mount = base.body("base").id, base.body("imu_mount").id
    R_WB = rot_z(np.float64(float(rec.meta.get("table_azimuth_deg", 0.0)) * DEG)) @ rot_x(
        np.float64(sv.get("level_x_rad", 0.0)))
    sl = sensor_slices(base)
    blocks = rec.blocks()
    mounts = _run_mounts(rec, blocks)
    n = rec.n
    f = np.empty((n, 3))
    w = np.empty((n, 3))
    r0 = np.empty((n, 3))
    resp = np.zeros((4, n, 3))
    starts = []
    for b, mnt in zip(blocks, mounts):
        if mnt not in MOUNTS:
            raise RecordingError(f"unknown mounting '{mnt}' in the recording; the tilt table knows {sorted(MOUNTS)}")
        m = _copy_model(base)
        m.body_quat[bid_base] = _quat_wxyz(R_WB)
        m.body_quat[bid_mount] = _quat_wxyz(MOUNTS[mnt])
        sp = np.stack([rec.channels["theta"][b], rec.channels["phi"][b]], 1)
        cmd = slew_commands(sp, rate, dt) + np.array([sv.get("theta_zero_rad", 0.0),
                                                      sv.get("phi_zero_rad", {}).get(mnt, 0.0)])
        ch = np.concatenate(([0], np.flatnonzero(np.any(np.diff(sp, axis=0) != 0, axis=1)) + 1))
        win = np.searchsorted(ch, np.arange(sp.shape[0]), side="right") - 1
        ctrl = [cmd]
        for j in range(2):
            for parity in (0, 1):
                c = cmd.copy()
                c[:, j] += delta_rad * (win % 2 == parity)
                ctrl.append(c)
        ctrl = np.array(ctrl)
        sd = rollout_servo([m] * 5, ctrl[:, 0], ctrl, desc="tilt-table twin (MuJoCo)")
        f[b] = sd[0][:, sl["f_C"]]
        w[b] = sd[0][:, sl["w_C"]]
        resp[:, b] = (sd[1:, :, sl["f_C"]] - sd[0][None, :, sl["f_C"]]) / delta_rad
        r0[b] = MOUNTS[mnt].T @ base.body_pos[bid_mount] + base.site_pos[base.site("imu").id]
        starts.append(b.start + ch)
    return {"f_C": f, "w_C": w, "r0_C": r0, "resp": resp, "window_start": np.concatenate(starts), "gravity_m_s2": g,
            "mounts": mounts}


def _block_mean(x: np.ndarray, idx: np.ndarray, nb: int) -> np.ndarray:
    """Means of x (n,) or (n, k) over the averaging blocks ``idx`` (n,), -1 = dropped."""
    keep = idx >= 0
    cnt = np.bincount(idx[keep], minlength=nb).astype(float)
    if x.ndim == 1:
        return np.bincount(idx[keep], weights=x[keep], minlength=nb) / cnt
    return np.stack([np.bincount(idx[keep], weights=x[keep, k], minlength=nb) for k in range(x.shape[1])], 1) / cnt[:, None]


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
    from imurig.calibration.accelerometer import ACC

    rec.require({c: "V" for c in ACC})
    tw = twin if twin is not None else tilt_table_twin(rec)
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
    # nuisance: per-window responses (a window's offset holds until the next change; its transient
    # may spill into the next window, so the label runs to the start of the window after next)
    ws = tw["window_start"]
    win = np.searchsorted(ws, np.arange(rec.n), side="right") - 1
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
    N = N[:, np.linalg.norm(N, axis=0) > 0]
    # per axis a bias; on the axes in ``recalibrate_axes`` also a linear re-calibration against the
    # twin's specific force: where the position means found an effect the static fit lacked
    # (crosstalk...), that fit absorbed part of it, which acts in the slews as an error of gain and
    # axes (a false lever arm of 4 cm on the crosstalk case without it). Not added elsewhere: in
    # constant-rate slews df/dt is a rotation of f, so these columns also take power from a delay.
    F_tw = _block_mean(f_tw, idx, nb)
    consts = np.column_stack([np.kron(np.eye(3), np.ones((nb, 1)))]
                             + [np.kron(np.eye(3)[:, [a]], F_tw) for a, ax in enumerate(AXES) if ax in recalibrate_axes])
    const_names = [f"bias_{a}" for a in AXES] + [f"gain_{a}{k}" for a in AXES if a in recalibrate_axes for k in AXES]
    y = R.T.reshape(-1)
    # noise model: AR(1) per axis from the blocks where the twin rests (no rotation: no candidate
    # acts there), each resting stretch's mean removed (the window's angle offset), within runs
    first = np.concatenate(([True], run_of_block[1:] != run_of_block[:-1]))
    moving = _block_mean((np.linalg.norm(w_tw, axis=1) > 1e-6).astype(float), idx, nb) > 0
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

    ew = whiten(e)[:, 0]
    for a in range(3):
        # each resting stretch's mean took one degree of freedom
        n_rest = int(rest.sum())
        sig[a] = float(np.sqrt(np.sum(ew[a * nb:(a + 1) * nb][rest] ** 2) / max(n_rest - np.unique(stretch[rest]).size, 1)))
    scale = np.repeat(1.0 / sig, nb)[:, None]
    yw, Nw = (whiten(y) * scale)[:, 0], whiten(N) * scale
    Q, _ = np.linalg.qr(Nw)
    proj = lambda A: A - Q @ (Q.T @ A)                                       
    yp = proj(yw[:, None])[:, 0]

    def stacked(cols3):  # (nb, 3) per-axis pattern -> (3 nb,) stacked
        return cols3.T.reshape(-1)

    def axis_only(col, a):
        z = np.zeros((nb, 3))
        z[:, a] = col[:, a]
        return stacked(z)

    lib_cols = {}
    for a, ax in enumerate(AXES):
        lib_cols[f"time_delay_{ax}"] = proj(whiten(axis_only(cand_cols["delay"], a)) * scale)
    lib_cols["lever_arm"] = proj(whiten(np.column_stack([stacked(c) for c in cand_cols["lever"]])) * scale)
    lib_cols["wrong_local_gravity"] = proj(whiten(stacked(cand_cols["gravity"])) * scale)
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
    # the multiplexer's crosstalk acts sample by sample: in the slews the previously scanned channel
    # (a magnetometer turning in the Earth's field, a neighbour accelerometer) moves. Where the
    # position means found it (``crosstalk_axes``), its column joins the nuisance here, so that its
    # dynamic signature is not forced onto a delay or a lever arm; it is tested (and reported) in
    # the position means only (as a slew candidate too it fired on 6/30 null records)
    for a, ax in enumerate(AXES):
        ch = f"acc_{ax}"
        if ax in crosstalk_axes and ch in scan and len(scan) > 1:
            prev = scan[scan.index(ch) - 1]
            if prev in rec.channels:
                z = np.zeros((nb, 3))
                z[:, a] = _block_mean(np.asarray(rec.channels[prev], float), idx, nb)
                consts = np.column_stack([consts, stacked(z)])
                const_names.append(f"crosstalk_{ax}_from_{prev}")
    X0 = proj(whiten(consts) * scale)
    d = select_effects(yp, X0, const_names, lib, rng, alpha=alpha, n_sim=n_sim)
    out = d.to_dict()
    # the report: the fit step by step (whitened space) and the residuals in m/s^2 before and after,
    # from the full GLS fit (nuisance, constants and the accepted effects; by Frisch-Waugh-Lovell its
    # effect coefficients are the engine's)
    from imurig.reports.diagnosis import effect_steps

    out["fit_steps"] = effect_steps(yp, X0, const_names, lib, d)["steps"]
    raw = {f"time_delay_{ax}": axis_only(cand_cols["delay"], a) for a, ax in enumerate(AXES)}
    raw["lever_arm"] = np.column_stack([stacked(c) for c in cand_cols["lever"]])
    raw["wrong_local_gravity"] = stacked(cand_cols["gravity"])
    A0 = np.column_stack([N, consts])
    A1 = np.column_stack([A0] + [raw[f.name] for f in d.findings])
    resid = []
    for A in (A0, A1):
        coef = np.linalg.lstsq(whiten(A) * scale, whiten(y)[:, 0] * scale[:, 0], rcond=None)[0]
        resid.append((y - A @ coef).reshape(3, nb).T)
    F_meas = _block_mean(f_meas, idx, nb)
    contrib = {}
    for f in d.findings:
        C = np.asarray(raw[f.name], float).reshape(3 * nb, -1)
        c = np.array([v[0] for v in f.params.values()])
        contrib[f.name] = (C @ c).reshape(3, nb).T.tolist()
    out["residuals"] = {
        "unit": "m/s^2", "time_s": _block_mean(t, idx, nb).tolist(), "moving": moving.tolist(),
        "run": run_of_block.tolist(), "recording": F_meas.tolist(), "twin": (F_meas - resid[0]).tolist(),
        "corrected_twin": (F_meas - resid[1]).tolist(), "before": resid[0].tolist(), "after": resid[1].tolist(),
        "df_twin_dt_m_s3": cand_cols["delay"].tolist(),
        "angular_acceleration_rad_s2": _block_mean(alpha_w, idx, nb).tolist(),
        "angular_rate_rad_s": _block_mean(w_tw, idx, nb).tolist(), "effect_contribution_m_s2": contrib,
        "convention": "residual = recording - twin (20 Hz block means of the calibrated samples); the twin "
                      "includes the fitted per-window angle offsets and per-axis constants (before), and the "
                      "accepted effects (corrected twin)"}
    for fd in out["findings"]:
        if fd["effect"].startswith(("time_delay_", "adc_crosstalk_")):
            fd["channel"] = fd["effect"][-1]
            fd["effect"] = fd["effect"][:-2]
        else:
            fd["channel"] = "acc"
        if fd["effect"] == "wrong_local_gravity":
            fd["indistinguishable_from"] = "lever_arm along the phi axis (platform frame) and the scale factors"
    # what the slews say of g whether or not it is selected: eps jointly with the accepted effects
    Xg = np.column_stack([lib_cols["wrong_local_gravity"], X0] + [lib_cols[f.name] for f in d.findings
                                                                if f.name != "wrong_local_gravity"])
    cg, *_ = np.linalg.lstsq(Xg, yp, rcond=None)
    rg = yp - Xg @ cg
    covg = np.linalg.inv(Xg.T @ Xg) * float(rg @ rg) / max(yp.size - Xg.shape[1], 1)
    out.update({
        "twin": "set-points -> the table's slew law and servo (MuJoCo replay), surveyed table errors, g = "
                f"{tw['gravity_m_s2']:.8g} m/s^2" + ("; multiplexer skew modelled" if skew_in_twin else
                                                     "; channels taken as sampled at their time tags"),
        "skew_in_twin": bool(skew_in_twin), "skew_s": skew.tolist(), "averaging_samples": block,
        "noise_model": {"ar1": rho.tolist(), "innovation_sigma_m_s2": sig.tolist()},
        "gravity_check": {"g_twin_m_s2": tw["gravity_m_s2"], "eps": float(cg[0]), "eps_se": float(np.sqrt(covg[0, 0])),
                          "note": "a g error scales the static fit's scale factors by g_twin / g_true and is "
                                  "invisible in the position means; in the slews it equals a lever-arm error "
                                  "eps x r0 along the phi axis (r0 = the IMU's height above the axes)"},
        "lever_arm_r0_m": [float(v) for v in np.abs(tw["r0_C"]).max(axis=0)]})
    return out


# ------------------------------------------------------------------ concealed-effect cases
#: a protocol whose slews carry both axes (used by the dynamic cases): 3 x 4 positions per mounting
DYNAMIC_PROTOCOL = {"theta_deg": (0, 45, 90), "phi_deg": (0, 90, 180, 270), "dwell_s": 3.0, "settle_s": 1.0,
                    "slew_rate_deg_s": 30.0}
#: the lever-arm pattern (times the size, m, case frame): the triad's centre off the case's
LEVER_PATTERN = np.array([1.0, -0.75, 0.5])
#: the DAQ's channel count is fixed by the scan list; the skew of acc_y (slot 2) is 2 / f_mux
SKEW_SLOT_Y = 2


def _dyn_record(seed: int, change=None, **camp_kw):
    from imurig.concealed.suite import _tilt_lab
    from imurig.rigs.tilt_table import TiltTableProtocol

    return _tilt_lab(seed, change or (lambda lab: lab), protocol=TiltTableProtocol(**DYNAMIC_PROTOCOL), **camp_kw)


def case_recording(effect: str, seed: int, size: float) -> Recording:
    """A recording with ``effect`` at ``size`` (see :data:`CASE_SIZES`), everything else as drawn.

    - ``time_delay``: the DAQ's multiplexer skew with acc_y delayed by ``size`` s (f_mux = 2 / size,
      crosstalk off so that only the skew changes with f_mux);
    - ``lever_arm``: the triad senses at ``size`` x (1, -0.75, 0.5) m from the case's reference point;
    - ``wrong_local_gravity``: the recording's site metadata (what the twin uses) states
      g_true (1 + ``size``) while the rig ran at the true local gravity;
    - ``temperature_drift``: the lab air drifts 3 K/h and the accelerometer biases have a linear
      tempco of ``size`` x (1, -1, 1) m/s^2/K (no curvature, no scale tempco).
    """
    from dataclasses import replace

    from imurig.sensors.chain import LabClimate

    if effect == "time_delay":
        rec = _dyn_record(seed, lambda lab: replace(lab, adc=replace(lab.adc, crosstalk_enabled=False,
                                                                      mux_frequency_hz=SKEW_SLOT_Y / size)))
    elif effect == "lever_arm":
        rec = _dyn_record(seed, lambda lab: replace(lab, accelerometers=replace(
            lab.accelerometers, position_C_m=size * LEVER_PATTERN)))
    elif effect == "wrong_local_gravity":
        rec = _dyn_record(seed)
        rec.truth["site_gravity_m_s2"] = rec.meta["site"]["gravity_m_s2"]
        rec.meta["site"] = dict(rec.meta["site"], gravity_m_s2=rec.meta["site"]["gravity_m_s2"] * (1 + size))
    elif effect == "temperature_drift":
        from imurig.concealed.suite import _tilt_lab

        def change(lab):
            acc = replace(lab.accelerometers, bias_tempco_m_s2_per_K=size * np.array([1.0, -1.0, 1.0]),
                          bias_tempco2_m_s2_per_K2=np.zeros(3), bias_tempco3_m_s2_per_K3=np.zeros(3),
                          scale_tempco_per_K=np.zeros(3))
            return replace(lab, accelerometers=acc, climate=LabClimate(drift_C_per_h=3.0))

        rec = _tilt_lab(seed, change)
    else:
        raise ConfigError(f"no tilt-table case for '{effect}'")
    return rec


def null_case_recording(effect: str, seed: int) -> Recording:
    """The same kind of record with the effect absent (the twin then lacks nothing)."""
    if effect == "temperature_drift":
        return case_recording(effect, seed, 0.0)
    if effect == "time_delay":  # the seed's 20 kHz skew, which the null twin models
        return _dyn_record(seed)
    return _dyn_record(seed)


def truth_param(effect: str, rec: Recording) -> float:
    """The injected parameter the case's finding estimates, from the effect's own truth map."""
    if effect == "time_delay":  # acc_y's multiplexer skew
        return ChannelSkew().fitted(rec.truth, "acc_y")["tau_s"]
    if effect == "lever_arm":
        return LeverArm().fitted(rec.truth)["dr_x_m"]
    if effect == "wrong_local_gravity":
        return rec.meta["site"]["gravity_m_s2"] / rec.truth["site_gravity_m_s2"] - 1.0
    if effect == "temperature_drift":
        # inverse model: f = u / D - b - kb dT, the column being the temp_acc_x volts (10 mV/K)
        return TemperatureDrift().fitted(rec.truth, "acc_x")["drift"]
    raise ConfigError(f"no truth for '{effect}'")


def found_param(effect: str, d: dict):
    """(estimate, std_error) of the case's parameter in a diagnosis, None if not found."""
    if effect == "wrong_local_gravity":  # what the slews say of g, found or not
        g = d.get("dynamic", {}).get("gravity_check")
        return None if g is None else (g["eps"], g["eps_se"])
    if effect == "temperature_drift":
        src = d["axes"]["x"]["findings"]
    else:
        src = d.get("dynamic", {}).get("findings", [])
    want = {"time_delay": ("time_delay", "y"), "lever_arm": ("lever_arm", "acc"),
            "temperature_drift": ("temperature_drift", None)}[effect]
    for f in src:
        if f["effect"] == want[0] and (want[1] is None or f.get("channel") == want[1]):
            return f["parameters"][0]["estimate"], f["parameters"][0]["std_error"]
    return None
