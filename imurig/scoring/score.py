"""Scoring estimates against the injected truth.

For every parameter k with injected value x_k, estimate x̂_k and standard error s_k:

    error_k = x̂_k - x_k,     z_k = error_k / s_k,     within_bound_k = |z_k| <= z_bound

An estimator passes when every parameter is within the bound (default 4, as in the
campaigns). Because a huge standard error passes any z bound, the score also gives the
RMS of the z-scores (about 1 for honest standard errors) and each standard error over the
bench's own (``se_ratio``: below 1 is more precise than the bench).

Residuals: where the campaign defines them (:mod:`imurig.scoring.residuals`), the
estimated parameters are put into the sensor's forward model with the true input of each
segment, and the measured output is compared with that prediction; the RMS per axis is
reported beside the same figure with the injected parameters (the floor set by the noise).
The same function scores in process and from files, so both give identical numbers.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from imurig.scoring.interface import EstimatesError, ParameterEstimate, normalise_estimates
from imurig.scoring.residuals import compute_residuals
from imurig.scoring.units import UnitError, conversion_factor

TRUTH_FORMAT = "imurig-truth"
Z_BOUND = 4.0


@dataclass
class TruthSet:
    """What the bench injected, per named parameter, in SI units; plus what scoring needs
    beyond the parameters (residual data) and the bench's own estimates for comparison."""

    campaign: str
    seed: int
    parameters: list[dict]                 # {name, unit, injected}
    residuals: dict | None = None          # see imurig.scoring.truth.RESIDUALS
    bench: list[dict] | None = None        # the bench's estimates {name, unit, estimate, std_error}
    z_bound: float = Z_BOUND
    notes: str = ""

    @property
    def names(self) -> list[str]:
        return [p["name"] for p in self.parameters]

    @property
    def units(self) -> dict[str, str]:
        return {p["name"]: p["unit"] for p in self.parameters}

    def to_dict(self) -> dict:
        return {"format": TRUTH_FORMAT, "version": 1, "campaign": self.campaign, "seed": self.seed,
                "z_bound": self.z_bound, "notes": self.notes, "parameters": self.parameters,
                "bench": self.bench, "residuals": self.residuals}

    @classmethod
    def from_dict(cls, d: dict) -> TruthSet:
        if not isinstance(d, dict) or d.get("format") != TRUTH_FORMAT:
            got = d.get("format") if isinstance(d, dict) else type(d).__name__
            raise EstimatesError(f"not an imurig truth file (format must be '{TRUTH_FORMAT}', got "
                                 f"{got!r}); pass the truth.json written by 'imurig export'")
        try:
            ts = cls(campaign=str(d["campaign"]), seed=int(d["seed"]), parameters=d["parameters"],
                     residuals=d.get("residuals"), bench=d.get("bench"), z_bound=float(d.get("z_bound", Z_BOUND)),
                     notes=d.get("notes", ""))
            ts.units    # every parameter has a unit: checked here, not in the scoring
        except (KeyError, TypeError, ValueError, AttributeError) as e:
            raise EstimatesError(f"the truth file is damaged ({type(e).__name__}: {e}); write it again with "
                                 "'imurig export'") from None
        return ts

    @classmethod
    def load(cls, path) -> TruthSet:
        p = Path(path)
        if p.is_dir():
            p = p / "truth.json"
        try:
            return cls.from_dict(json.loads(p.read_text()))
        except FileNotFoundError:
            raise EstimatesError(f"truth file {p} does not exist") from None
        except (json.JSONDecodeError, UnicodeDecodeError) as e:
            raise EstimatesError(f"truth file {p} is not valid JSON text: {e}") from None


def check_estimates(truth: TruthSet, estimates: list[ParameterEstimate], source: str = "estimates",
                    allow_missing: bool = False) -> dict[str, ParameterEstimate]:
    """Validate estimates against the campaign's parameters and convert them to its SI units.

    Refuses, naming every offender: duplicate rows, unknown (extra) parameters, missing
    parameters (unless ``allow_missing``), NaN/inf values or standard errors, standard
    errors <= 0, and units of the wrong dimension. Convertible units (``mg`` for m/s^2,
    ``mrad`` for rad, ``mV/(deg/s)`` for V/(rad/s)) are converted.
    """
    units = truth.units
    problems: list[str] = []
    seen: dict[str, ParameterEstimate] = {}
    dups = sorted({e.name for e in estimates if sum(x.name == e.name for x in estimates) > 1})
    if dups:
        problems.append(f"duplicate rows for {dups}: give each parameter once")
    extra = [e.name for e in estimates if e.name not in units]
    if extra:
        problems.append(f"unknown parameters {extra}: this campaign ({truth.campaign}) estimates only "
                        f"{truth.names}")
    missing = [n for n in truth.names if n not in {e.name for e in estimates}]
    if missing and not allow_missing:
        problems.append(f"missing parameters {missing}: every parameter of the template must be estimated")
    for e in estimates:
        if e.name not in units or e.name in seen:
            continue
        if not (math.isfinite(e.value) and math.isfinite(e.std_error)):
            problems.append(f"{e.name}: value {e.value!r} and std_error {e.std_error!r} must be finite numbers "
                            "(no NaN/inf)")
            continue
        if e.std_error <= 0:
            problems.append(f"{e.name}: std_error {e.std_error!r} must be > 0")
            continue
        try:
            f = conversion_factor(e.unit, units[e.name])
        except UnitError as err:
            problems.append(f"{e.name}: {err}")
            continue
        seen[e.name] = ParameterEstimate(e.name, e.value * f, e.std_error * abs(f), units[e.name])
    if problems:
        raise EstimatesError(f"{source} refused:\n  - " + "\n  - ".join(problems))
    return seen


@dataclass
class Score:
    """The score of one estimator on one campaign."""

    campaign: str
    seed: int
    estimator: str
    z_bound: float
    rows: list[dict]                              # parameter rows, see score_estimates
    residuals: dict = field(default_factory=dict)
    extra: dict = field(default_factory=dict)     # e.g. in-process calibrated-output residuals

    @property
    def passed(self) -> bool:
        return all(r["within_bound"] for r in self.rows)

    @property
    def failures(self) -> list[dict]:
        return [r for r in self.rows if not r["within_bound"]]

    @property
    def rms_z(self) -> float:
        return float(np.sqrt(np.mean([r["z"] ** 2 for r in self.rows]))) if self.rows else float("nan")

    @property
    def max_abs_z(self) -> tuple[str, float]:
        r = max(self.rows, key=lambda r: abs(r["z"]))
        return r["name"], float(r["z"])

    def failure_message(self) -> str:
        """Which parameters missed, by how much, in units of their standard error."""
        if self.passed:
            return ""
        lines = [(f"{self.estimator} on {self.campaign} (seed {self.seed}): {len(self.failures)} of "
                 f"{len(self.rows)} parameters outside |z| <= {self.z_bound:g}:")]
        for r in sorted(self.failures, key=lambda r: -abs(r["z"])):
            lines.append(f"  {r['name']}: estimate {r['estimate']:+.6e} vs injected {r['injected']:+.6e} {r['unit']}"
                         f" -> off by {r['error']:+.3e} {r['unit']} = {r['z']:+.2f} SE (SE {r['std_error']:.2e})")
        return "\n".join(lines)

    def summary(self) -> dict:
        name, z = self.max_abs_z
        ratios = [r["se_ratio"] for r in self.rows if r.get("se_ratio") is not None]
        return {"campaign": self.campaign, "seed": self.seed, "estimator": self.estimator, "z_bound": self.z_bound,
                "passed": self.passed, "n_parameters": len(self.rows),
                "n_within_bound": sum(bool(r["within_bound"]) for r in self.rows), "rms_z": self.rms_z,
                "max_abs_z": abs(z), "max_abs_z_parameter": name,
                "median_se_ratio": float(np.median(ratios)) if ratios else None,
                "residuals": self.residuals, **({"extra": self.extra} if self.extra else {})}

    def to_dict(self) -> dict:
        return {**self.summary(), "parameters": self.rows}

    def table(self) -> str:
        """Plain-text table for the terminal."""
        out = [(f"{'parameter':28s} {'unit':12s} {'injected':>14s} {'estimate':>14s} {'std.err':>9s} {'z':>7s} "
               f"{'SE/bench':>8s}  ok")]
        for r in self.rows:
            ratio = "–" if r.get("se_ratio") is None else f"{r['se_ratio']:.2f}"
            out.append(f"{r['name']:28s} {r['unit']:12s} {r['injected']:+.7e} {r['estimate']:+.7e} "
                       f"{r['std_error']:.2e} {r['z']:+7.2f} {ratio:>8s}  {'yes' if r['within_bound'] else 'NO'}")
        s = self.summary()
        out.append(f"{s['n_within_bound']}/{s['n_parameters']} within |z| <= {self.z_bound:g}; RMS z "
                   f"{s['rms_z']:.2f}; max |z| {s['max_abs_z']:.2f} ({s['max_abs_z_parameter']}) -> "
                   f"{'PASS' if self.passed else 'FAIL'}")
        for k, v in self.residuals.items():
            if isinstance(v, dict) and "rms" in v:
                out.append(f"residual {k}: " + ", ".join(f"{a}={x:.3e}" for a, x in v["rms"].items())
                           + f" {v.get('unit', '')} (floor with injected parameters: "
                           + ", ".join(f"{a}={x:.3e}" for a, x in v["floor_rms"].items()) + ")")
        return "\n".join(out)


def score_estimates(truth: TruthSet, estimates, estimator: str = "estimator", source: str = "estimates",
                    z_bound: float | None = None) -> Score:
    """Score estimates (any form :func:`normalise_estimates` accepts) against ``truth``."""
    est = check_estimates(truth, normalise_estimates(estimates, truth.units), source)
    zb = truth.z_bound if z_bound is None else float(z_bound)
    bench = {b["name"]: b for b in (truth.bench or [])}
    rows = []
    for p in truth.parameters:
        e = est[p["name"]]
        err = e.value - p["injected"]
        z = err / e.std_error
        b = bench.get(p["name"])
        rows.append({"name": p["name"], "unit": p["unit"], "injected": float(p["injected"]),
                     "estimate": float(e.value), "std_error": float(e.std_error), "error": float(err),
                     "z": float(z), "within_bound": bool(abs(z) <= zb),
                     "se_ratio": None if not b else float(e.std_error / b["std_error"])})
    values = {k: v.value for k, v in est.items()}
    residuals = compute_residuals(truth, values) if truth.residuals else {}
    return Score(truth.campaign, truth.seed, estimator, zb, rows, residuals)
