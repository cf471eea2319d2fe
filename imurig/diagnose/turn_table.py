"""Diagnosis of a turn-table gyro recording (seed 4.4: the Genisco C181, whole-round windows).

The twin is the nominal gyro model of :mod:`imurig.calibration.gyro`: per step, the mean
indicated rate over whole rounds u (n_seg, 3) maps to the reference rate along the table axis,

    w_ref,j = e_j (Omega_table + [Omega_E sin(lat)])           [rad/s]   (twin: Earth term optional)
    w_ref,j = b + sum_k a_k u_k + c u_j^2                      (physical inverse model, per gyro j)

with e_j = +-1 for the gyro on the table axis (mounting up/down) and 0 otherwise. Per-step
errors are correlated (angle random walk, Gauss-Markov bias instability, the timer), so the
engine works in the space whitened by :func:`imurig.calibration.gyro.segment_covariance`.

Candidate effects, per gyro j:

- ``earth_rate_left_out`` (only if the twin leaves the Earth's rate out): the column -e_j,
  amplitude Omega_E sin(lat) (rad/s);
- ``g_sensitivity``: the column -f_j, the step's mean specific force along the gyro axis from
  the accelerometer channels (m/s^2), amplitude G_jj ((rad/s)/(m/s^2)).

On a table with a vertical spin axis and the IMU at its centre both columns are gravity-aligned
and proportional (whitened correlation > 0.99): the data cannot tell them apart. The diagnosis
then tests the Earth's rate (which certainly acts) and names the g-sensitivity as
indistinguishable from it; only a horizontal specific force (the arm, a tilted mounting)
separates them.
"""
from __future__ import annotations

import numpy as np
from scipy import ndimage

from imurig.calibration.accelerometer import indicated as acc_indicated
from imurig.calibration.gyro import (
    AXES,
    AXIS_OF_MOUNT,
    INPUTS,
    MODELS,
    SPEC,
    reference_rates,
    segment_covariance,
    timer_difference_sigma,
)
from imurig.calibration.triad import indicated
from imurig.diagnose.engine import select_effects
from imurig.diagnose.pulse_angle import angle_timer_test, chain_from, pulse_times
from imurig.diagnose.pulse_timer import SETTLE_S, pulse_timer_test
from imurig.diagnose.steps import effect_steps
from imurig.diagnose.table_rate import diagnose_table_rate
from imurig.diagnose.turn_record import InMemoryTurn, StreamedTurn, as_turn
from imurig.kernel.errors import RecordingError
from imurig.kernel.filerecord import FileRecord
from imurig.kernel.recording import Recording
from imurig.kernel.site import EARTH_RATE_RAD_S, Site
from imurig.sensors.effects import GSensitivity, SlipRingNoise, TurnSampleView, TurnView, for_view


def _mounts(rw: Recording) -> list[str]:
    m = rw.segments.get("mount")
    if m is None:
        runs = rw.meta.get("runs", ["r_up"])
        m = [runs[int(i)] for i in rw.segments.get("run", np.zeros(rw.n_segments, int))]
    return [str(x) for x in m]


def diagnose_turn_table(rec: Recording | FileRecord, rng: np.random.Generator, alpha: float = 0.01, n_sim: int = 300,
                        timer: str = "hp6700", earth_rate: bool = True) -> dict:
    """Diagnose the gyro channels of a turn-table recording against the nominal twin
    (``earth_rate``: whether the twin's reference includes the Earth's vertical rate). ``rec``: a
    Recording, or a FileRecord read in row ranges (:mod:`imurig.diagnose.turn_record`: the same
    findings in memory of one window)."""
    src = as_turn(rec)
    src.require({"gyro_p": "V", "gyro_q": "V", "gyro_r": "V"})
    if "pulse" not in src.channels and not any(k.startswith("pulse_") for k in rec.events):
        raise RecordingError("the turn-table diagnosis times the table's whole rounds by its index pulses, and "
                             "this recording has none; add the index pulse as a voltage column 'pulse_V' (high "
                             "once per revolution; another column by --pulse-channel NAME) or a timer's pulse "
                             "times as 'event_pulse_<timer>_s'. Without them the table's true rate (mains factor, "
                             "slip) cannot be told from the gyros' own scale factor")
    rw, rate = src.windows(timer)
    ref = reference_rates(rw, rate)
    mounts = _mounts(rw)
    site = Site.from_dict(rec.meta.get("site", {}))
    omega_v = EARTH_RATE_RAD_S * np.sin(site.latitude_rad)
    e = np.zeros((rw.n_segments, 3))
    for i, m in enumerate(mounts):
        j, s = AXIS_OF_MOUNT[m]
        e[i, j] = s
    if not earth_rate:
        ref = ref - omega_v * e
    u = src.per_window(rw, SPEC.channels, lambda r: indicated(r, SPEC, "mean")[0])
    inputs = {n: u[:, k] for k, n in enumerate(INPUTS)}
    if {"acc_x", "acc_y", "acc_z"} <= set(src.channels):
        f = src.per_window(rw, ("acc_x", "acc_y", "acc_z"), lambda r: acc_indicated(r, "mean")[0])
        f_source = "accelerometer channels (nominal sensitivity)"
    else:
        f = e * site.gravity_m_s2  # at rest on a level table the specific force points up the spin axis
        f_source = "gravity along the table axis (no accelerometer channels)"
    noise = rec.meta.get("gyro_noise_model")
    if noise is None:
        raise RecordingError("the recording's metadata lacks 'gyro_noise_model' (arw_rad_s_per_sqrt_hz, "
                             "bias_instability_rad_s, bias_instability_tau_s): the diagnosis needs it to weight "
                             "the steps; add it as a '# gyro_noise_model: {...}' line in the CSV")
    cov = segment_covariance(rw, rate, noise, timer_difference_sigma(rec, timer))
    # the table's rate on its own stream (spawned: the gyros' threshold draws stay as they were)
    timer_test = _pulse_timer(src, rng.spawn(1)[0], alpha)
    table = diagnose_table_rate(rw.segments["rate_dial"], rate, rng.spawn(1)[0], mains_hz=float(rec.meta.get("mains_hz", 50.0)),
                                alpha=alpha, n_sim=n_sim, window_s=rw.segments["stop_s"] - rw.segments["start_s"],
                                edge_sigma_s=timer_test.get("sigma_T_s"))
    table["timer"] = timer_test
    out = {"table_rate": table,
           "twin": "physical gyro model on whole-round means, reference from timer '" + timer + "'"
                   + (" plus the Earth's vertical rate" if earth_rate else " without the Earth's rate"),
           "earth_rate_in_twin": earth_rate, "specific_force_from": f_source, "gyros": {}}
    for j, a in enumerate(AXES):
        lib_names = MODELS["physical"](a)
        X0 = lib_names.design(inputs)
        view = TurnView(channel=f"gyro_{a}", axis=a, on_axis=e[:, j], specific_force_m_s2=f[:, j],
                        table_rate_rad_s=np.asarray(rate, float), mount=tuple(mounts), earth_rate_in_twin=earth_rate)
        lib = [c for cls in for_view(TurnView.kind) for c in cls().candidates(view)]
        corr = _whitened_correlation(-f[:, j], -e[:, j], X0, cov)
        alias = None
        # a g-sensitivity whose column the data cannot tell from the Earth's is not tested
        # separately: the Earth's rate certainly acts; the finding names the alias
        if not earth_rate and abs(corr) > 0.99:
            alias = GSensitivity.name
            lib = [c for c in lib if c.name != alias]
        d = select_effects(ref[:, j], X0, list(lib_names.names), lib, rng, alpha=alpha, n_sim=n_sim, cov=cov)
        for fd in d.findings:
            if alias and fd.name == "earth_rate_left_out":
                fd.runner_up = alias
        earth_alias = earth_rate_guard(d.findings, omega_v, site.gravity_m_s2)
        entry = d.to_dict()
        if earth_alias:
            entry["earth_rate_alias"] = earth_alias
        entry["earth_vs_g_sensitivity_correlation"] = float(corr)
        if alias:
            entry["indistinguishable"] = {"effects": ["earth_rate_left_out", "g_sensitivity"], "correlation": float(corr),
                                          "note": "gravity and the Earth's vertical rate both lie along the table "
                                                  "axis: a bias Omega found here equals a g-sensitivity G = Omega / g; "
                                                  "a horizontal specific force (the arm) would separate them"}
        entry["truth_hint"] = {"Omega_vertical_rad_s": float(omega_v)}
        # the report: the fit step by step (GLS-whitened) and the round-mean residuals in rad/s
        # (residual = the twin's reference - the recording through the calibration)
        st = effect_steps(ref[:, j], X0, list(lib_names.names), lib, d, cov=cov)
        entry["fit_steps"] = st["steps"]
        entry["residuals"] = {"unit": "rad/s", "reference": ref[:, j].tolist(), "before": st["resid_before"].tolist(),
                              "after": st["resid_after"].tolist(), "table_rate_rad_s": np.asarray(rate, float).tolist(),
                              "on_axis": e[:, j].tolist(), "specific_force_m_s2": f[:, j].tolist(),
                              "mount": mounts, "time_s": (0.5 * (rw.segments["start_s"] + rw.segments["stop_s"])).tolist(),
                              "convention": "residual = the twin's reference rate - the recording through the "
                                            "gyro calibration (whole-round means per step)"}
        entry["scatter"] = _slip_rings(src, rw, timer, f"gyro_{a}", alpha / 3)
        entry["scatter"].update(src.raw_tests(f"gyro_{a}", alpha))
        out["gyros"][a] = entry
    return out


def _pulse_timer(rec: Recording | FileRecord | InMemoryTurn | StreamedTurn, rng: np.random.Generator,
                 alpha: float) -> dict:
    """The index pulses' timing error from the pulse voltage channel: every pulse against the
    table-axis gyro's integrated angle (:mod:`imurig.diagnose.pulse_angle`) where one mounting puts
    one gyro on the axis, else the dial plateaus' lines (:mod:`imurig.diagnose.pulse_timer`, reported
    beside the first as ``plateau_test``); untested without a pulse channel or plateaus."""
    rec = as_turn(rec)
    seg = rec.segments
    if "pulse" not in rec.channels or not {"start_s", "stop_s", "rate_dial"} <= set(seg):
        return {"tested": False, "why": "no pulse voltage channel with dial plateaus"}
    edges = rec.edges(rec.meta.get("pulse_threshold_V"))
    dt = rec.dt
    plateau = pulse_timer_test(edges, seg["start_s"], seg["stop_s"], seg["rate_dial"], dt, rng.spawn(1)[0], alpha)
    # every pulse against the table-axis gyro's angle, where one mounting puts one gyro on the axis
    mounts = set(_mounts(rec))
    if len(mounts) != 1 or next(iter(mounts)) not in AXIS_OF_MOUNT:
        plateau["angle_test"] = {"tested": False, "why": f"mountings {sorted(mounts)}: no single gyro on the table "
                                                         "axis throughout"}
        return plateau
    j, sign = AXIS_OF_MOUNT[next(iter(mounts))]
    ch = f"gyro_{AXES[j]}"
    c = chain_from(rec.gyro(ch, sign), pulse_times(edges, dt), seg["start_s"], seg["stop_s"], seg["rate_dial"])
    if c is None:
        plateau["angle_test"] = {"tested": False, "why": f"{ch}'s integral does not count the table's turns "
                                                         "between the index pulses"}
        return plateau
    out = angle_timer_test(c, edges, dt, rec.adc_step(ch), rng.spawn(1)[0], alpha)
    if not out.get("tested"):
        plateau["angle_test"] = out
        return plateau
    out["gyro_channel"] = ch
    out["plateau_test"] = {k: v for k, v in plateau.items() if k != "finding"}
    return out


def earth_rate_guard(findings: list, omega_v_rad_s: float, g_m_s2: float, k: float = 4.0) -> list[dict]:
    """Mark a g-sensitivity that may be the Earth's vertical rate in disguise; returns the marks.

    On a level table the g-sensitivity column is the specific force g e_j, the Earth-rate column
    Omega_v e_j: a fitted G with |G g -+ Omega_v| < ``k`` SE(G) g may be the Earth's vertical rate that
    the twin's reference holds and the recording does not (an Earth-rate-compensated output,
    mountings other than the metadata say), as well as a g-sensitivity of that size: the data cannot
    tell. The finding is then never a plain g-sensitivity: it names the Earth-rate mismatch as its
    indistinguishable alternative (``indistinguishable_from``), and the mark says so."""
    marks = []
    for f in findings:
        est = next((v for n, v in f.params.items() if n.endswith(":G")), None) if f.name == "g_sensitivity" else None
        if est is None or not np.isfinite(est[1]):
            continue
        gap = min(abs(est[0] * g_m_s2 - s * omega_v_rad_s) for s in (1.0, -1.0))
        if gap < k * est[1] * g_m_s2:
            f.runner_up = EARTH_RATE_MISMATCH
            marks.append({"effect": f.name, "G": est[0], "G_se": est[1], "G_times_g_rad_s": est[0] * g_m_s2,
                          "earth_vertical_rate_rad_s": omega_v_rad_s, "gap_in_se": gap / (est[1] * g_m_s2),
                          "indistinguishable_from": EARTH_RATE_MISMATCH,
                          "note": "G g equals the Earth's vertical rate within its standard errors: the twin's Earth "
                                  "term may be missing from the recording (an Earth-rate-compensated output, wrong "
                                  "mountings) rather than a g-sensitivity; check the mountings, or rerun with "
                                  "--twin-without-earth-rate"})
    return marks


#: the alternative a g-sensitivity of the Earth's vertical rate's size cannot be told from
EARTH_RATE_MISMATCH = "earth_rate_mismatch"


def _whitened_correlation(a: np.ndarray, b: np.ndarray, X0: np.ndarray, cov: np.ndarray) -> float:
    """Correlation of two candidate columns after whitening by ``cov`` and projecting out X0."""
    L = np.linalg.cholesky(0.5 * (cov + cov.T))
    W = np.linalg.solve(L, np.column_stack([X0, a, b]))
    X, A = W[:, :-2], W[:, -2:]
    R = A - X @ np.linalg.lstsq(X, A, rcond=None)[0]
    n = np.linalg.norm(R, axis=0)
    return float(R[:, 0] @ R[:, 1] / (n[0] * n[1])) if np.all(n > 0) else 0.0


def _slip_rings(rec: InMemoryTurn | StreamedTurn, rw: Recording, timer: str, ch: str, alpha: float) -> dict:
    """Is the sample noise of ``ch`` periodic in the table angle (slip-ring contact noise)?

    Within each whole-round window (on inferred dial plateaus, its rounds from ``SETTLE_S`` after
    the plateau began, so that the table's settling after a ramp stays out) the table angle of sample t is 2 pi (t - t_k) / (t_k+1 - t_k)
    after index pulse t_k (mirrored for the negative direction). The fast residual r (the
    channel minus its running mean over the effect's window: white noise, slow ripple removed)
    goes with the angles into a :class:`TurnSampleView`; the slip-ring effect's own test
    (:meth:`imurig.sensors.effects.SlipRingNoise.test`: Brown-Forsythe across angle bins, then
    the refit of the excess noise by angle) gives the statistics and, when p < ``alpha``, the
    finding with the angles where the spread rises and by how much.
    """
    pulses = rec.timer_pulses(timer)
    w = SlipRingNoise.window
    h = w // 2
    # segments inferred as dial plateaus begin where a ramp ended, the table still settling (its lag
    # is a rate transient, not a ripple): the rounds count from SETTLE_S later. A logged segment
    # (acquisition started on an index pulse) is taken as it is.
    inferred = "segments" in (rec.meta.get("inferred") or {}) and rec.segments["start_s"].size == rw.n_segments
    plateau_start = rec.segments["start_s"] + SETTLE_S if inferred else rw.segments["start_s"]
    spans = []
    for a, b, rate, a0 in zip(rw.segments["start_s"], rw.segments["stop_s"], rw.segments["rate_dial"], plateau_start):
        p = pulses[(pulses >= max(a, a0) - 1e-9) & (pulses <= b + 1e-9)]   # the angle: the window's rounds
        if p.size < 2:      # the table at rest (dial 0): no angle to lock to
            continue
        if p.size >= 4:     # the first round holds the table's settling after the dial change: whole
            p = p[1:]       # rounds kept (they keep the Earth's once-per-round rate out of the ripple)
        spans.append((p, b, rate))

    def pieces():
        """Each window's (angle, residual, signal, time), its ends cut by the running mean's half-length."""
        for (p, b, rate), (tt, xx) in zip(spans, rec.window_samples(ch, [(p[0], b) for p, b, _ in spans])):
            if tt.size < 200:
                continue
            r = xx - ndimage.uniform_filter1d(xx, w, mode="nearest")
            k = np.clip(np.searchsorted(p, tt, side="right") - 1, 0, p.size - 2)
            frac = (tt - p[k]) / (p[k + 1] - p[k])
            # the signal as logged (the ripple test removes each window's mean and trend): a ripple
            # locked to the angle stays
            cut = slice(h, -h) if r.size > 2 * h else slice(None)
            yield (2 * np.pi * (frac if rate >= 0 else 1 - frac))[cut], r[cut], xx[cut], tt[cut]
    view = TurnSampleView(channel=ch, angle_rad=np.zeros(0), residual_V=np.zeros(0), alpha=alpha,
                          quantum_V=rec.adc_step(ch))
    return rec.slip_ring_test(view, pieces)
