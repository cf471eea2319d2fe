"""Gyro calibration on the turn table (seed sections 4.4.2-4.4.4, eq. 4.39-4.41).

Reference rate. For each step, the table's rate comes from the once-per-round pulses as
time-tagged by one timer (the seed's algorithm): with the first and last rising edges
t_1 and t_N inside the acquisition window,

    Omega_table = s * 2 pi (N - 1) / (t_N - t_1)                     [rad/s]

(s: the direction from the dial's sign). The gyro output is averaged over exactly those
whole rounds, so the Earth's horizontal rate, the once-per-round ripple and slip-ring
noise average out; the Earth's vertical rate adds along the table axis:

    w_ref,C = e_axis * (Omega_table + Omega_E sin(latitude))         [rad/s, (3,)]

where e_axis is the IMU axis on the table (+-p, q or r, from the mounting).

:class:`GyroCalibration` fits the inverse model on these references (``fit(rec)``: whole-round
windows from a timer, the reference rates, and generalised least squares with the gyro's noise
model, :func:`segment_covariance`), or on references given (``fit(rec, reference)``).
"""
from __future__ import annotations

from typing import Self

import numpy as np

from imurig.calibration.paper_models import paper_eq3_terms
from imurig.calibration.terms import TermLibrary, polynomial
from imurig.calibration.triad import TriadCalibration, TriadSpec, forward_parameters
from imurig.kernel.errors import RecordingError
from imurig.kernel.recording import Recording
from imurig.kernel.site import EARTH_RATE_RAD_S, Site
from imurig.rigs.turn_table import MOUNTS, TurnTableErrors

AXES = ("p", "q", "r")
GYRO = tuple(f"gyro_{a}" for a in AXES)
INPUTS = ("wp", "wq", "wr")

MODELS = {
    "linear": lambda a: TermLibrary.from_names(["1", *INPUTS]),
    "physical": lambda a: TermLibrary.from_names(["1", *INPUTS, f"w{a}^2"]),
    # seed eq. 4.39-4.41: bias, scale, second order, cross-axis (1st and 2nd order), cross-coupling
    "seed_final": lambda a: polynomial(INPUTS, 2),
    "paper_eq3": paper_eq3_terms,          # EUCASS paper eq. 3: own axis to the cube, cross-axis, cross products
}

SPEC = TriadSpec(kind="gyro", axes=AXES, channels=GYRO, inputs=INPUTS,
                 sensitivity_key="gyro_nominal_sensitivity_V_per_rad_s", quantity_unit="rad/s",
                 cal_prefix="gyro_cal_", models=MODELS, sensitivity_hint=", e.g. 6 mV/(deg/s) = 0.3438")

#: mounting -> (index of the IMU axis on the table axis, sign)
AXIS_OF_MOUNT = {f"{a}_{d}": ("pqr".index(a), 1.0 if d == "up" else -1.0) for a in "pqr" for d in ("up", "down")}


class GyroCalibration(TriadCalibration):
    """Inverse-model calibration of the gyro triad (models: 'linear', 'physical',
    'seed_final' (eq. 4.39-4.41), 'paper_eq3' (the EUCASS paper's eq. 3), 'stepwise', 'backward').

    Settings as :class:`~imurig.calibration.triad.TriadCalibration` (``statistic`` defaults to the
    window mean), plus the turn table's reference: ``timer`` ('adc', 'gps_mark', 'hp6700') times the
    whole rounds, and ``gls`` fits by generalised least squares with the gyro's noise model when the
    recording carries one (``gyro_noise_model`` metadata; fixed models only).

    ``fit(rec)`` derives the references from a turn-table recording (module doc) and adds the fitted
    ``windows_`` (the recording with segments narrowed to whole rounds), ``table_rate_`` (n_seg,)
    rad/s and ``reference_`` (n_seg, 3) rad/s; ``fit(rec, reference, ...)`` uses the given ones.
    """

    SPEC = SPEC

    def __init__(self, model: str | dict = "physical", statistic: str = "mean", stepwise_criterion: str = "bic",
                 stepwise_library_degree: int = 2, timer: str = "hp6700", gls: bool = True):
        super().__init__(model, statistic, stepwise_criterion, stepwise_library_degree)
        self.timer = timer
        self.gls = gls

    def fit(self, rec: Recording, reference: np.ndarray | None = None, reference_jacobian: np.ndarray | None = None,
            reference_sigma: np.ndarray | None = None, response_cov: np.ndarray | None = None,
            segment_cov: np.ndarray | None = None) -> Self:
        """The triad fit (:meth:`TriadCalibration.fit`) on ``reference`` (n_seg, 3) rad/s, or, when it is
        None, on the turn table's whole rounds timed by ``timer`` with the reference rates
        w_ref,C = e_axis (Omega_table + Omega_E sin(latitude)) and, with ``gls``, the per-segment error
        covariance of :func:`segment_covariance`."""
        if reference is not None:
            return super().fit(rec, reference, reference_jacobian, reference_sigma, response_cov, segment_cov)
        rw, rate = round_windows(rec, self.timer)
        ref = reference_rates(rw, rate)
        refuse_unexcited_axes(rw, ref)
        cov = None
        if self.gls and self.model not in ("stepwise", "backward") and "gyro_noise_model" in rec.meta:
            cov = segment_covariance(rw, rate, rec.meta["gyro_noise_model"], timer_difference_sigma(rec, self.timer))
        super().fit(rw, ref, response_cov=cov)
        self.windows_, self.table_rate_, self.reference_ = rw, rate, ref
        return self


def unexcited_axes(ref: np.ndarray) -> list[str]:
    """The gyro axes never on the table axis: their reference (n_seg, 3) is 0 in every step."""
    span = np.max(np.abs(ref), axis=0)
    return [AXES[j] for j in range(3) if span[j] <= 1e-6 * span.max()]


def refuse_unexcited_axes(rw: Recording, ref: np.ndarray) -> None:
    """A triad model needs every gyro on the table axis in some step: its own-axis input is otherwise
    the Earth's rate alone, and its scale factor (and every term in that input) has no information.
    Refuses such a recording with the mountings it has and those it lacks."""
    idle = unexcited_axes(ref)
    if idle:
        seen = sorted({str(m) for m in np.asarray(rw.segments.get("mount", []))})
        raise RecordingError(
            f"the table turned only about the {', '.join(sorted(set(AXES) - set(idle)))} gyro's axis"
            f"{' (mountings: ' + ', '.join(seen) + ')' if seen else ''}: the {' and '.join(idle)} gyros' scale "
            f"factors and every model term in {', '.join('w' + a for a in idle)} cannot be fitted. Record steps with "
            f"{' and '.join(a + '_up' for a in idle)} as well (each gyro in turn on the table axis); `imurig "
            f"diagnose` reads this recording as it is, and `imurig calibrate` (model physical) calibrates the turned gyro")


def pulse_edges(rec: Recording, channel: str = "pulse", threshold: float | None = None) -> np.ndarray:
    """Rising edges of the index pulse as the ADC sees them: the time of the first sample at
    or above the threshold after one below it (resolution: one sample period)."""
    if channel not in rec.channels:
        raise RecordingError(f"no '{channel}' channel: record the table's index pulse on an ADC channel "
                             f"(CSV column '{channel}_V'), or use a timer's events")
    x = rec.channels[channel]
    thr = threshold if threshold is not None else rec.meta.get("pulse_threshold_V", 0.5 * float(np.max(x)))
    above = x >= thr
    idx = np.flatnonzero(~above[:-1] & above[1:]) + 1
    # an edge across a gap between blocks is not an edge
    gaps = np.flatnonzero(np.diff(rec.time_s) > 1.5 / rec.sample_rate_hz) + 1
    idx = idx[~np.isin(idx, gaps)]
    return rec.time_s[idx]


def timer_pulses(rec: Recording, timer: str) -> np.ndarray:
    """Pulse times from 'adc' (the pulse channel) or a timer's events (e.g. 'hp6700', 'gps_mark')."""
    if timer == "adc":
        return pulse_edges(rec)
    key = f"pulse_{timer}"
    if key not in rec.events:
        have = ["adc"] * ("pulse" in rec.channels) + [k[6:] for k in rec.events if k.startswith("pulse_")
                                                       and not k.endswith("true")]
        raise RecordingError(f"no pulse times from timer '{timer}'; this recording has {have}")
    return rec.events[key]


def round_windows(rec: Recording, timer: str = "hp6700", min_rounds: int = 1) -> tuple[Recording, np.ndarray]:
    """Segments narrowed to whole rounds between pulses, and the table rate of each (rad/s).

    Returns (recording with segments [t_1, t_N) and a column ``rounds``, rate (n_seg,)). A step
    whose dial is 0 is the table at rest: its whole window, rate 0, 0 rounds.
    Raises RecordingError naming a step whose window holds fewer than ``min_rounds`` rounds.
    """
    if "rate_dial" not in rec.segments:
        raise RecordingError("turn-table segments need the 'rate_dial' set-point (CSV column rate_dial_dps)")
    pulses = timer_pulses(rec, timer)
    seg = rec.segments
    start, stop, rate, rounds = [], [], [], []
    for i, (a, b) in enumerate(zip(seg["start_s"], seg["stop_s"])):
        if seg["rate_dial"][i] == 0.0:   # the table at rest: its rate is exactly 0, no pulse to time
            start.append(a)
            stop.append(b)
            rate.append(0.0)
            rounds.append(0)
            continue
        p = pulses[(pulses >= a) & (pulses < b)]
        n = p.size - 1
        if n < min_rounds:
            raise RecordingError(f"step {i} (dial {np.degrees(seg['rate_dial'][i]):.3g} deg/s, "
                                 f"{a:.1f}-{b:.1f} s) holds {max(n, 0)} whole round(s) by timer '{timer}'; "
                                 f"lengthen its window to at least {min_rounds + 1} pulses")
        start.append(p[0])
        stop.append(p[-1])
        rate.append(np.sign(seg["rate_dial"][i]) * 2 * np.pi * n / (p[-1] - p[0]))
        rounds.append(n)
    new = dict(seg)
    new["start_s"], new["stop_s"], new["rounds"] = np.array(start), np.array(stop), np.array(rounds)
    units = dict(rec.segment_units)
    units["rounds"] = "1"
    return rec.replace(segments=new, segment_units=units), np.array(rate)


def reference_rates(rec: Recording, table_rate: np.ndarray) -> np.ndarray:
    """Reference angular rate in C (n_seg, 3) rad/s: table rate plus the Earth's vertical rate
    along the IMU axis on the table (see module doc)."""
    site = Site.from_dict(rec.meta.get("site", {}))
    mounts = rec.segments.get("mount")
    if mounts is None:
        runs = rec.meta.get("runs", ["r_up"])
        mounts = np.array([runs[int(i)] for i in rec.segments.get("run", np.zeros(len(table_rate), int))])
    ref = np.zeros((len(table_rate), 3))
    earth_up = EARTH_RATE_RAD_S * np.sin(site.latitude_rad)
    for i, m in enumerate(mounts):
        if str(m) not in AXIS_OF_MOUNT:
            raise RecordingError(f"unknown mounting {m!r}; use one of {sorted(AXIS_OF_MOUNT)}")
        j, s = AXIS_OF_MOUNT[str(m)]
        ref[i, j] = s * (table_rate[i] + earth_up)
    return ref


def injected_parameters(truth: dict, mounts=None) -> dict:
    """Forward-model gyro parameters from a simulation's truth (SI).

    On a turn table the estimated misalignment of column j (the axis on the table) also holds
    the table's wobble as seen in that mounting: M_eff[:, j] = M[:, j] + (R_CP w)_off-axis,
    with w the spin axis in the platform frame tilted by the wobble. Pass the mountings used
    to get those effective values (one mounting per axis; otherwise the sensor's own M).
    """
    g = truth["sensors"]["gyros"]
    M = np.asarray(g["misalignment_rad"], float).copy()
    if mounts:
        tt = truth["rig"]["turn_table"]
        e = TurnTableErrors(**{k: v for k, v in tt.items() if k in TurnTableErrors.__dataclass_fields__})
        R_PM = e.wobble_rotation()
        for m in dict.fromkeys(mounts):
            j, s = AXIS_OF_MOUNT[m]
            # spin axis (platform z) expressed in C, signed so that it is ~ +e_j: s R_MC^T R_PM^T z
            a_C = MOUNTS[m].T @ R_PM.T @ np.array([0.0, 0.0, 1.0]) * s
            col = (np.eye(3) + np.asarray(g["misalignment_rad"])) @ a_C
            for i in range(3):
                if i != j:
                    M[i, j] = col[i] / col[j]
    return forward_parameters(AXES, g["scale_V_per_rad_s"], g["bias_rad_s"], g["k2_per_rad_s"], M)


def segment_covariance(rec_windows: Recording, table_rate: np.ndarray, noise: dict,
                       timer_sigma_s: float) -> np.ndarray:
    """Covariance (n_seg, n_seg), (rad/s)^2, of the per-segment errors of one axis model.

    For segment windows [a_i, b_i) of length T_i:
    - angle random walk N (rad/s/sqrt(Hz)): white, N^2 / T_i on the diagonal;
    - bias instability, Gauss-Markov (sigma_b, tau): the covariance of window means,
          sigma_b^2 / (T_i T_j) * int_Ii int_Ij exp(-|t - s| / tau) ds dt,
      in closed form: for disjoint windows (b_i <= a_j)
          tau^2 (e^-(a_j-b_i)/tau - e^-(a_j-a_i)/tau - e^-(b_j-b_i)/tau + e^-(b_j-a_i)/tau),
      and 2 tau^2 (T/tau - 1 + e^-T/tau) for a window with itself;
      windows in different blocks (remounts) are taken as independent;
    - the reference rate from the timer: (Omega_i sigma_dT / T_i)^2 on the diagonal, with
      sigma_dT the timer's error on a round-time difference;
    - a scale-factor wander, Gauss-Markov (sigma_s, tau_s; ``scale_instability`` and
      ``scale_instability_tau_s`` in ``noise`` when the lab has one): Omega_i Omega_j sigma_s^2 times
      the same window integrals with tau_s, over (T_i T_j).
    """
    a = np.asarray(rec_windows.segments["start_s"], float)
    b = np.asarray(rec_windows.segments["stop_s"], float)
    T = b - a
    N = noise.get("arw_rad_s_per_sqrt_hz", 0.0)
    sb = noise.get("bias_instability_rad_s", 0.0)
    tau = noise.get("bias_instability_tau_s", 100.0)
    cov = np.diag(N**2 / T + (table_rate * timer_sigma_s / T) ** 2)
    block = _block_index(rec_windows, a)
    if sb > 0:
        cov = cov + sb**2 * _gauss_markov_window_integrals(a, b, tau, block) / np.outer(T, T)
    ss = noise.get("scale_instability", 0.0)
    if ss > 0:
        I = _gauss_markov_window_integrals(a, b, noise.get("scale_instability_tau_s", 10.0), block)
        cov = cov + ss**2 * np.outer(table_rate, table_rate) * I / np.outer(T, T)
    return cov


def _gauss_markov_window_integrals(a: np.ndarray, b: np.ndarray, tau: float, block: np.ndarray) -> np.ndarray:
    """int_Ii int_Ij exp(-|t - s| / tau) ds dt for the windows [a_i, b_i) (segment_covariance's doc); 0 across blocks."""
    T = b - a
    # order so that i precedes j: for i < j in time use the disjoint formula
    ai, aj = a[:, None], a[None, :]
    bi, bj = b[:, None], b[None, :]
    first_a, first_b = np.where(ai <= aj, ai, aj), np.where(ai <= aj, bi, bj)
    second_a, second_b = np.where(ai <= aj, aj, ai), np.where(ai <= aj, bj, bi)
    e = lambda x: np.exp(-np.clip(x, 0, None) / tau)  # noqa: E731
    I = tau**2 * (e(second_a - first_b) - e(second_a - first_a) - e(second_b - first_b) + e(second_b - first_a))
    I[np.diag_indices_from(I)] = 2 * tau**2 * (T / tau - 1 + np.exp(-T / tau))
    return np.where(block[:, None] == block[None, :], I, 0.0)


def _block_index(rec: Recording, t: np.ndarray) -> np.ndarray:
    """The contiguous block of each time ``t``: the record's blocks (:meth:`Recording.blocks`), or, for a record
    that holds only some rows of one (the streamed campaign's acquisition windows), the first times of the
    full record's blocks as ``meta["block_start_s"]``."""
    starts = rec.meta.get("block_start_s")
    if starts is None:
        starts = [rec.time_s[s.start] for s in rec.blocks()]
    return np.searchsorted(np.asarray(starts, float), t, side="right") - 1


def timer_difference_sigma(rec: Recording, timer: str) -> float:
    """1-sigma error of a round-time difference t_N - t_1 for a timer (s)."""
    if timer == "adc":
        q = 1.0 / rec.sample_rate_hz
        return q * np.sqrt(2 / 12)
    tm = rec.meta.get("timers", {}).get(timer, {})
    q = tm.get("resolution_s", 1e-6)
    j = tm.get("jitter_s", 0.0)
    return float(np.sqrt(2 * (q**2 / 12 + j**2)))
