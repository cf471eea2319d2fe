"""The diagnosis report's tables: the fit before and after per observable, each accepted effect
step by step (:func:`imurig.diagnose.steps.effect_steps`), and the pairs the data cannot tell apart."""
from __future__ import annotations

import numpy as np

from imurig.reports.common import md_table


def with_aic(stats: dict) -> dict:
    """``stats`` (sigma_res, r2_adj, bic, n, p) with the AIC added where it is missing: both use the
    same Gaussian log-likelihood, so AIC = BIC - p ln n + 2 p."""
    if isinstance(stats, dict) and "aic" not in stats and {"bic", "n", "p"} <= set(stats) and stats["bic"] is not None:
        stats["aic"] = float(stats["bic"] - stats["p"] * np.log(stats["n"]) + 2 * stats["p"])
    return stats


def fit_entries(d: dict) -> list[tuple[str, dict, str]]:
    """(observable, engine entry with fit_before/fit_after[/fit_steps], unit and space) per fitted
    observable of a diagnosis, AIC filled in."""
    kind = d.get("kind")
    out = []
    if kind == "tilt_table":
        out += [(f"acc_{a} position means", e, "m/s², ordinary least squares") for a, e in d["axes"].items()]
        if "fit_before" in d.get("dynamic", {}):
            out.append(("acc slews (x, y, z stacked)", d["dynamic"], ("σ_res: unit innovations (AR(1)-whitened, "
                        "nuisance projected out); RMS: m/s²")))
    elif kind == "turn_table":
        out += [(f"gyro_{g} whole-round means", e, "rad/s, GLS-whitened by the gyro noise model")
                for g, e in d["gyros"].items()]
    elif kind == "thermal":
        out += [(f"{ch} step biases", e, f"{e.get('residuals', {}).get('unit', 'SI')}, AR(1)-whitened")
                for ch, e in d["channels"].items()]
    elif kind == "magnetometer":
        out.append(("mag x, y, z block means (joint)", d["magnetometer"], "nT, ordinary least squares"))
    else:
        if "fit_before" in d.get("shortfall", {}).get("diagnosis", {}):
            out.append(("rate shortfall (stopwatch)", d["shortfall"]["diagnosis"], "relative rate, weighted"))
        if "fit_before" in d.get("voltmeter", {}):
            out.append(("gyro voltages (one voltmeter, joint)", d["voltmeter"], "V, whitened"))
        out += [(f"gyro {g} voltage", e, "V, weighted") for g, e in d.get("gyros", {}).items() if "fit_before" in e]
    for _, e, _ in out:
        with_aic(e["fit_before"])
        with_aic(e["fit_after"])
    return out


def _rms(e: dict) -> list:
    """Residual RMS before and after in the observable's own unit (the residual arrays where the
    diagnosis keeps them, else the unwhitened fit steps)."""
    rs = e.get("residuals", {})
    b, a = (rs.get(k, rs.get(k + "_V")) for k in ("before", "after"))
    if b is not None and a is not None:
        return [float(np.sqrt(np.mean(np.square(b)))), float(np.sqrt(np.mean(np.square(a))))]
    if e.get("fit_steps"):
        return [e["fit_steps"][0]["residual_rms"], e["fit_steps"][-1]["residual_rms"]]
    return ["–", "–"]


def fit_tables(d: dict) -> list[str]:
    """report.md sections: the fit before and after per observable, and step by step per effect."""
    ents = fit_entries(d)
    md = ["\n## Fit before and after\n",
          ("σ_res, R²adj, BIC and AIC in the space the effects are tested in (the unit column says which); "
          "residual RMS in the observable's own unit.\n"),
          md_table(["observable", "unit / space", "σ_res before", "σ_res after", "RMS before", "RMS after",
                    "R²adj before", "R²adj after", "BIC before", "BIC after", "AIC before", "AIC after",
                    "residual white?"],
                   [[name, unit, e["fit_before"]["sigma_res"], e["fit_after"]["sigma_res"], *_rms(e),
                     e["fit_before"]["r2_adj"], e["fit_after"]["r2_adj"], e["fit_before"]["bic"],
                     e["fit_after"]["bic"], e["fit_before"]["aic"], e["fit_after"]["aic"],
                     e.get("unexplained", {}).get("white", "–")] for name, e, unit in ents])]
    rows = []
    for name, e, _ in ents:
        fs = {f["effect"]: f for f in e.get("findings", [])}
        fs.update({f"{f['effect']}_{f['channel']}": f for f in e.get("findings", []) if len(f.get("channel", "")) == 1})
        for st in e.get("fit_steps", [])[1:]:
            f = fs.get(st["after_effect"], {})
            ps = "; ".join(f"{p['name'].split(':')[-1]} = {p['estimate']:.4g} ± {p['std_error']:.2g}"
                           for p in f.get("parameters", []))
            rows.append([name, st["after_effect"], ps, f"{st['variance_share'] * 100:.1f} %",
                         f"{st.get('unique_variance_share', 0) * 100:.1f} %", st["sigma_res"], st["residual_rms"],
                         st["r2_adj"], st["bic"], st["aic"]])
    if rows:
        md += ["\n## Each accepted effect: parameters and the fit after adding it\n",
               ("Share = the part of the nominal fit's residual sum of squares the effect removes when added in "
               "turn (the shares of one observable sum to 1 − SS_after / SS_before); unique share = what it "
               "removes from the final model. σ_res, RMS, R²adj, BIC, AIC: the fit with the effects up to this "
               "one.\n"),
               md_table(["observable", "effect added", "parameters ± SE", "share", "unique share", "σ_res",
                         "RMS", "R²adj", "BIC", "AIC"], rows)]
    return md


def indistinguishable_notes(d: dict) -> list[str]:
    """report.md lines for the pairs the data cannot tell apart (whole record and per channel)."""
    notes = [f"- {' / '.join(n['effects'])}: {n['note']}" for n in d.get("indistinguishable", [])]
    for ch, e in (d.get("axes") or d.get("gyros") or d.get("channels") or {}).items():
        pairs = e.get("indistinguishable", [])
        notes += [f"- {ch}: {' / '.join(n['effects'])}: {n['note']}" for n in ([pairs] if isinstance(pairs, dict)
                                                                                  else pairs)]
    return ["\n## Indistinguishable here (the runner-up named, not silently dropped)\n", *notes, ""] if notes else []
