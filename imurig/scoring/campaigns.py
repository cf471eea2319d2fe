"""Named campaigns with fixed seeds: what a user's estimator is scored on.

Each name fixes a rig, a protocol and a default seed, so ``tilt-table-quick`` with seed 1
is the same data everywhere (same seed, same data, bit for bit):

| name | protocol | what is estimated |
|---|---|---|
| ``tilt-table-quick`` | 4 tilts x 6 rotations x 2 mountings, 2 s per position | 15 accelerometer parameters |
| ``tilt-table`` | the seed's 240 positions, 15 s each (README defaults) | the same |
| ``turn-table-quick`` | dial 40, 70, 100 deg/s, both directions, p/q/r up, >= 4 s | 15 gyro parameters |
| ``turn-table`` | the seed's final schedule (9 rates) | the same |
| ``thermal-quick`` | -30..+30 C in 20 C steps, two cycles, 10 min soak | 33 temperature coefficients |
| ``thermal`` | -50..+50 C in 10 C steps, 40 min soak | the same |
| ``magnetometer`` | level circle, tumble, compass swing, validation circle | 14 field-model invariants |

What is "injected" for each:
- **tilt-table**: the accelerometers' forward model V_i = s_i (a_i + b_i + k2_i a_i^2),
  a = (I + M) f_C (:func:`imurig.calibration.accelerometer.injected_parameters`);
- **turn-table**: the gyros' forward model, with the misalignment column of the axis on the
  table including the table's wobble (:func:`imurig.calibration.gyro.injected_parameters`);
- **thermal**: the coefficients of the bench's temperature model on the noise-free twin
  (the true sensors' output through the same six-position analysis);
- **magnetometer**: the invariants a field-domain fit can identify: b and A A' (3-D, tumble)
  and b2, A2 A2' (2-D, level circle, with the vertical field's leak into b2).

Residuals (tilt and turn table): per segment, the measured output (1 kHz median, or mean
over whole rounds) against the forward model with the estimated parameters and the true
input (truth-signal median of f_C; the table rate along the axis on the table), as the
indicated quantity r_i = V_i / s_i - (a_i + b_i + k2_i a_i^2) in m/s^2 or rad/s.
Magnetometer: the calibrated field norm on the tumble, |A^-1 (m - b)| - F in tesla,
from b and A A' alone. Thermal: none.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from imurig.kernel.errors import ImurigError
from imurig.kernel.recording import Recording
from imurig.scoring.score import TruthSet

ACC_UNITS = {"sensitivity": "V/(m/s^2)", "misalignment": "rad", "bias": "m/s^2", "nonlinearity": "1/(m/s^2)"}
GYRO_UNITS = {"sensitivity": "V/(rad/s)", "misalignment": "rad", "bias": "rad/s", "nonlinearity": "1/(rad/s)"}


def _triad_names(axes) -> list[str]:
    """Parameter names in the order of TriadCalibration.physical_parameters."""
    return ([f"sensitivity_{a}" for a in axes]
            + [f"misalignment_{axes[i]}{axes[j]}" for i in range(3) for j in range(3) if i != j]
            + [f"bias_{a}" for a in axes] + [f"nonlinearity_{a}" for a in axes])


@dataclass(frozen=True)
class CampaignSpec:
    """A named campaign: ``make(seed)`` builds the campaign object (with ``simulate()``)."""

    name: str
    kind: str
    description: str
    seed: int
    make: Callable[[int], object]


def _tilt_quick(seed):
    from imurig.campaigns.tilt_table import TiltTableCampaign
    from imurig.rigs.tilt_table import TiltTableProtocol

    return TiltTableCampaign(protocol=TiltTableProtocol(theta_deg=(0, 30, 60, 90), phi_deg=(0, 60, 120, 180, 240, 300),
                                                        dwell_s=2.0, settle_s=1.0, slew_rate_deg_s=60.0), seed=seed)


def _tilt_full(seed):
    from imurig.campaigns.tilt_table import TiltTableCampaign

    return TiltTableCampaign(seed=seed)


def _turn_quick(seed):
    from imurig.campaigns.turn_table import TurnTableCampaign
    from imurig.rigs.turn_table import TurnTableProtocol

    return TurnTableCampaign(protocol=TurnTableProtocol(dial_rates_dps=(40, 70, 100), min_window_s=4.0, settle_s=2.0,
                                                        remount_s=30.0), seed=seed)


def _turn_full(seed):
    from imurig.campaigns.turn_table import TurnTableCampaign

    return TurnTableCampaign(seed=seed)


def _thermal_quick(seed):
    from imurig.campaigns.thermal import ThermalCampaign
    from imurig.rigs.thermal_chamber import ThermalProfile

    return ThermalCampaign(profile=ThermalProfile(low_C=-30.0, high_C=30.0, step_C=20.0, soak_s=600.0,
                                                  attitude_dwell_s=20.0), seed=seed)


def _thermal_full(seed):
    from imurig.campaigns.thermal import ThermalCampaign

    return ThermalCampaign(seed=seed)


def _mag(seed):
    from imurig.campaigns.magnetometer import MagnetometerCampaign

    return MagnetometerCampaign(seed=seed)


CAMPAIGNS: dict[str, CampaignSpec] = {s.name: s for s in [
    CampaignSpec("tilt-table-quick", "tilt-table", "accelerometers on the tilt table, 48 positions x 2 s", 1,
                 _tilt_quick),
    CampaignSpec("tilt-table", "tilt-table", "accelerometers on the tilt table, the seed's 240 positions x 15 s",
                 2005, _tilt_full),
    CampaignSpec("turn-table-quick", "turn-table", "gyros on the turn table, dial 40/70/100 deg/s, 18 steps", 1,
                 _turn_quick),
    CampaignSpec("turn-table", "turn-table", "gyros on the turn table, the seed's final schedule, 54 steps", 2005,
                 _turn_full),
    CampaignSpec("thermal-quick", "thermal", "thermal chamber -30..+30 C, 20 C steps, two cycles", 1,
                 _thermal_quick),
    CampaignSpec("thermal", "thermal", "thermal chamber -50..+50 C, 10 C steps, two cycles (seed 4.5)", 2005,
                 _thermal_full),
    CampaignSpec("magnetometer", "magnetometer", "fluxgate with hard and soft iron: circle, tumble, swing", 2005,
                 _mag),
]}
QUICK = ("tilt-table-quick", "turn-table-quick", "thermal-quick", "magnetometer")


def get_spec(name: str) -> CampaignSpec:
    if name not in CAMPAIGNS:
        raise ImurigError(f"unknown campaign {name!r}; choose from {sorted(CAMPAIGNS)}")
    return CAMPAIGNS[name]


_CACHE: dict[tuple[str, int], BenchCampaign] = {}


class BenchCampaign:
    """One named campaign with one seed: its recording (with and without truth) and its truth.

    Simulation happens once per (name, seed) per process (cached).
    """

    def __init__(self, name: str, seed: int | None = None):
        self.spec = get_spec(name)
        self.name = name
        self.kind = self.spec.kind
        self.seed = self.spec.seed if seed is None else int(seed)
        self._rec: Recording | None = None
        self._truth: TruthSet | None = None

    def __repr__(self):
        return f"BenchCampaign({self.name!r}, seed={self.seed})"

    @property
    def campaign(self):
        return self.spec.make(self.seed)

    def simulate(self) -> Recording:
        """The recording with its truth (cached)."""
        if self._rec is None:
            self._rec = self.campaign.simulate()
        return self._rec

    def recording(self) -> Recording:
        """What an estimator sees: no truth, no seed (the seed would regenerate the truth)."""
        rec = self.simulate().without_truth()
        meta = dict(rec.meta)
        if isinstance(meta.get("campaign"), dict):
            meta["campaign"] = {k: v for k, v in meta["campaign"].items() if k != "seed"}
            meta["campaign"]["name"] = self.name
        return rec.replace(meta=meta)

    def truth(self, with_bench: bool = True) -> TruthSet:
        """The injected parameters, residual data and (optionally) the bench's own estimates."""
        if self._truth is None:
            rec = self.simulate()
            params, notes = TRUTH[self.kind](rec)
            self._truth = TruthSet(self.name, self.seed, params, RESIDUALS.get(self.kind, lambda r: None)(rec),
                                   notes=notes)
        if with_bench and self._truth.bench is None:
            from imurig.scoring.baselines import baseline_for
            from imurig.scoring.interface import fitted_estimates, normalise_estimates

            est = normalise_estimates(fitted_estimates(baseline_for(self.kind), self.recording()), self._truth.units)
            self._truth.bench = [{"name": e.name, "unit": e.unit, "estimate": e.value, "std_error": e.std_error}
                                 for e in est]
        return self._truth

    def template(self) -> list[dict]:
        """The parameters to estimate: name and unit (values left empty)."""
        return parameter_template(self.truth(with_bench=False))


def campaign(name: str, seed: int | None = None) -> BenchCampaign:
    """The (cached) BenchCampaign ``name`` with ``seed`` (default: the campaign's fixed seed)."""
    spec = get_spec(name)
    key = (name, spec.seed if seed is None else int(seed))
    if key not in _CACHE:
        _CACHE[key] = BenchCampaign(name, key[1])
    return _CACHE[key]


def parameter_template(truth: TruthSet) -> list[dict]:
    return [{"name": p["name"], "unit": p["unit"], "value": None, "std_error": None} for p in truth.parameters]


# ------------------------------------------------------------------ truth builders
def _tilt_truth(rec: Recording):
    from imurig.calibration.accelerometer import AXES, injected_parameters

    inj = injected_parameters(rec.truth)
    params = [{"name": n, "unit": ACC_UNITS[n.split("_")[0]], "injected": float(inj[n])} for n in _triad_names(AXES)]
    return params, ("forward model V_i = s_i (a_i + b_i + k2_i a_i^2), a = (I + M) f_C; misalignment M_ij "
                    "is the sensitivity of axis i to f_C along j")


def _turn_truth(rec: Recording):
    from imurig.calibration.gyro import AXES, injected_parameters

    inj = injected_parameters(rec.truth, list(rec.segments["mount"]))
    params = [{"name": n, "unit": GYRO_UNITS[n.split("_")[0]], "injected": float(inj[n])} for n in _triad_names(AXES)]
    return params, ("forward model V_i = s_i (w_i + b_i + k2_i w_i^2), w = (I + M) w_table; the misalignment "
                    "column of the axis on the table includes the table's wobble (effective misalignment)")


def _thermal_truth(rec: Recording):
    from imurig.calibration.thermal import ThermalCalibration, step_table
    from imurig.campaigns.thermal import twin_channels

    twin = ThermalCalibration().fit(step_table(rec, channels=twin_channels(rec)))
    unit = {"acc_bias": "m/s^2", "acc_scale": "1", "gyro_bias": "rad/s"}
    params = []
    for key, r in twin.results_.items():
        kind = key.rsplit("_", 1)[0]
        for n, c in zip(r.names, r.coef_):
            k = 0 if n in ("1", "hysteresis") else (1 if n == "dT" else int(n.split("^")[1]))
            u = unit[kind] + ("" if k == 0 else f"/K^{k}" if k > 1 else "/K")
            params.append({"name": f"{key}:{n}", "unit": u, "injected": float(c)})
    return params, ("coefficients of b(T) = c0 + c1 dT + c2 dT^2 + c3 dT^3 + H s (accelerometer bias), "
                    "s(T) = c0 + c1 dT + H s (scale), b(T) = c0 + c1 dT + H s (gyro bias) against each sensor's "
                    "temperature reading, dT = T - 298.15 K, s = +1/2 heating, -1/2 cooling; injected = the same "
                    "six-position analysis on the noise-free twin")


def _mag_truth(rec: Recording):
    from imurig.campaigns.magnetometer import manoeuvre_mask, true_invariants

    t = true_invariants(rec)
    A, b = t["A"], t["b"]
    AAt = A @ A.T
    params = [{"name": f"3d:AAt_{n}", "unit": "1", "injected": float(AAt[i, j])}
              for n, (i, j) in zip(("xx", "xy", "xz", "yy", "yz", "zz"), zip(*np.triu_indices(3)))]
    params += [{"name": f"3d:b_{a}", "unit": "T", "injected": float(b[k])} for k, a in enumerate("xyz")]
    circ = manoeuvre_mask(rec, "level_circle")
    Bz = float(np.mean(rec.truth_signals["B_C_z"][circ]))
    b2 = b[:2] + A[:2, 2] * Bz
    T2 = A[:2, :2] @ A[:2, :2].T
    params += [{"name": "2d:A2A2t_xx", "unit": "1", "injected": float(T2[0, 0])},
               {"name": "2d:A2A2t_xy", "unit": "1", "injected": float(T2[0, 1])},
               {"name": "2d:A2A2t_yy", "unit": "1", "injected": float(T2[1, 1])},
               {"name": "2d:b2_x", "unit": "T", "injected": float(b2[0])},
               {"name": "2d:b2_y", "unit": "T", "injected": float(b2[1])}]
    return params, ("indicated field m = V / s_nom = A B_C + b (+ noise); 3-D on the tumble: b and A A'; 2-D on "
                    "the level circle: m_xy = A2 B_xy + b2 with b2 = b_xy + A_xy,z B_z")


TRUTH = {"tilt-table": _tilt_truth, "turn-table": _turn_truth, "thermal": _thermal_truth,
         "magnetometer": _mag_truth}


# ------------------------------------------------------------------ residual data
def _tilt_residual_data(rec: Recording) -> dict:
    from imurig.calibration.accelerometer import ACC
    from imurig.calibration.preprocess import segment_statistic

    v = segment_statistic(rec, list(ACC), "median")
    f = segment_statistic(rec, ["f_C_x", "f_C_y", "f_C_z"], "median", source="truth_signals")
    return {"kind": "triad_forward", "axes": ["x", "y", "z"], "unit": "m/s^2", "true_input": f.tolist(),
            "measured_volts": v.tolist(), "what": "per-position 1 kHz median volts vs the forward model at the "
            "true specific force"}


def _turn_residual_data(rec: Recording) -> dict:
    from imurig.calibration.gyro import AXIS_OF_MOUNT, GYRO, round_windows
    from imurig.calibration.preprocess import segment_statistic

    rw, _ = round_windows(rec, "hp6700")
    v = segment_statistic(rw, list(GYRO), "mean")
    w = segment_statistic(rw, ["w_C_x", "w_C_y", "w_C_z"], "mean", source="truth_signals")
    q = np.zeros_like(w)
    for i, m in enumerate(rw.segments["mount"]):
        j, _ = AXIS_OF_MOUNT[str(m)]
        q[i, j] = w[i, j]   # the other components belong to the effective misalignment
    return {"kind": "triad_forward", "axes": ["p", "q", "r"], "unit": "rad/s", "true_input": q.tolist(),
            "measured_volts": v.tolist(), "what": "whole-round mean volts (HP counter windows) vs the forward "
            "model at the true table rate"}


def _mag_residual_data(rec: Recording) -> dict:
    from imurig.campaigns.magnetometer import indicated_field, manoeuvre_mask

    tum = manoeuvre_mask(rec, "tumble")
    m = indicated_field(rec)[tum]
    step = max(1, m.shape[0] // 2000)
    return {"kind": "field_norm", "unit": "T", "indicated_T": m[::step].tolist(),
            "field_T": float(rec.meta["igrf_total_T"]),
            "what": f"calibrated field norm |A^-1 (m - b)| - F on the tumble (every {step}-th sample)"}


RESIDUALS = {"tilt-table": _tilt_residual_data, "turn-table": _turn_residual_data,
             "magnetometer": _mag_residual_data}


def _triad_indicated_residual(d: dict, values: dict) -> dict:
    axes = d["axes"]
    q = np.asarray(d["true_input"], float)
    V = np.asarray(d["measured_volts"], float)
    M = np.eye(3)
    for i, a in enumerate(axes):
        for j, c in enumerate(axes):
            if i != j:
                M[i, j] = values[f"misalignment_{a}{c}"]
    aS = q @ M.T
    s = np.array([values[f"sensitivity_{a}"] for a in axes])
    b = np.array([values[f"bias_{a}"] for a in axes])
    k2 = np.array([values[f"nonlinearity_{a}"] for a in axes])
    r = V / s - (aS + b + k2 * aS**2)
    return {a: float(np.sqrt(np.mean(r[:, j] ** 2))) for j, a in enumerate(axes)}


def _field_norm_residual(d: dict, values: dict) -> dict:
    n = ("xx", "xy", "xz", "yy", "yz", "zz")
    T = np.zeros((3, 3))
    for k, (i, j) in zip(n, zip(*np.triu_indices(3))):
        T[i, j] = T[j, i] = values[f"3d:AAt_{k}"]
    b = np.array([values[f"3d:b_{a}"] for a in "xyz"])
    m = np.asarray(d["indicated_T"], float) - b
    try:
        Ti = np.linalg.inv(T)
    except np.linalg.LinAlgError:
        return {"norm": float("inf")}
    q = np.einsum("ni,ij,nj->n", m, Ti, m)
    norm = np.sqrt(np.clip(q, 0, None))
    return {"norm": float(np.sqrt(np.mean((norm - d["field_T"]) ** 2)))}


def compute_residuals(truth: TruthSet, values: dict) -> dict:
    """Residual RMS with the estimated ``values`` (SI, by name) and with the injected ones."""
    d = truth.residuals
    if not d:
        return {}
    f = {"triad_forward": _triad_indicated_residual, "field_norm": _field_norm_residual}[d["kind"]]
    inj = {p["name"]: p["injected"] for p in truth.parameters}
    return {"forward_model": {"unit": d["unit"], "rms": f(d, values), "floor_rms": f(d, inj), "what": d["what"]}}
