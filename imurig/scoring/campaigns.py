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

The names, kinds and seeds: :mod:`imurig.scoring.specs`; what is injected and the residual
data: :mod:`imurig.scoring.truth`; the residuals: :mod:`imurig.scoring.residuals`.
"""
from __future__ import annotations

from imurig.kernel.recording import Recording
from imurig.scoring.baselines import baseline_for
from imurig.scoring.interface import fitted_estimates, normalise_estimates
from imurig.scoring.score import TruthSet
from imurig.scoring.specs import CAMPAIGNS, QUICK, get_spec
from imurig.scoring.truth import RESIDUALS, TRUTH

__all__ = ["CAMPAIGNS", "QUICK", "BenchCampaign", "campaign", "get_spec", "parameter_template"]

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
