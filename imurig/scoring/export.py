"""``imurig export``: a campaign's recording without truth, for estimators in any language.

    DIR/                      <- give this folder to the user's code
      recording.csv           lab CSV (README "The lab CSV format"), no truth
      recording.mat           the same for MATLAB/Octave (scipy.io.savemat, v5): see MAT_LAYOUT
      segments.csv            one row per acquisition window, numbers only (see segment_table)
      parameters.csv          template: name,value,std_error,unit with value/std_error empty
      parameters.json         the same template as JSON
      manifest.json           campaign name, kind, channels, files, what to estimate
      README.txt              the above in words
    TRUTH (default DIR.truth.json, a sibling file, never inside DIR)
                              the injected parameters and residual data: only `imurig score` reads it

Nothing in DIR holds truth: the recording is :meth:`Recording.without_truth` (no truth
parameters, truth signals or true event times) and the campaign's seed is dropped from the
metadata (it would regenerate the truth).
"""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
from scipy.io import savemat

from imurig.calibration.gyro import reference_rates, round_windows
from imurig.campaigns.tilt_table import tilt_table_reference
from imurig.kernel.errors import ImurigError, OutputExistsError
from imurig.kernel.labcsv import write_csv
from imurig.kernel.outputs import OutputFolder, atomic_write, to_json
from imurig.kernel.recording import Recording
from imurig.scoring.campaigns import BenchCampaign, campaign

MAT_LAYOUT = """recording.mat (MATLAB v5, load('recording.mat') or Octave load):
  time_s        (n x 1) s
  channels      struct, one field per channel, (n x 1) in SI (V for sensor outputs)
  units         struct, the SI unit of each channel (char)
  events        struct, one field per timer, sorted event times (s), e.g. pulse_hp6700
  segments      struct of (m x 1) columns, the same as segments.csv
  runs          cell array of the mountings (index = run + 1)
  meta_json     char, the recording's metadata as JSON (nominal sensitivities, site, survey...)
  campaign      char, the campaign name
  parameter_names, parameter_units   cell arrays: what to estimate, in which SI unit"""


def segment_table(c: BenchCampaign, rec: Recording) -> tuple[list[str], np.ndarray]:
    """Numeric per-segment table: windows, set-points, and the nominal reference.

    The reference is what the lab computes from its set-points and survey (no truth):
    tilt table ``ref_f_<x|y|z>_m_s2`` (seed eq. 4.31-4.38 with the surveyed table errors,
    :func:`imurig.campaigns.tilt_table.tilt_table_reference`); turn table the whole-round
    windows timed by the HP counter (``start_s``, ``stop_s``), ``rounds``, the measured table
    rate and ``ref_w_<p|q|r>_rad_s`` (table rate plus the Earth's vertical rate along the
    axis on the table, :func:`imurig.calibration.gyro.reference_rates`).
    """
    seg = rec.segments
    cols: dict[str, np.ndarray] = {"segment": np.arange(rec.n_segments)}
    if c.kind == "turn-table":
        rw, rate = round_windows(rec, "hp6700")
        ref = reference_rates(rw, rate)
        cols.update(start_s=rw.segments["start_s"], stop_s=rw.segments["stop_s"], run=seg["run"],
                    rate_dial_dps=np.degrees(seg["rate_dial"]), rounds=rw.segments["rounds"],
                    table_rate_dps=np.degrees(rate))
        cols.update({f"ref_w_{a}_rad_s": ref[:, j] for j, a in enumerate("pqr")})
    else:
        cols.update(start_s=seg["start_s"], stop_s=seg["stop_s"])
        if "run" in seg:
            cols["run"] = seg["run"]
        for k, v in seg.items():
            if k in cols or k in ("mount",) or np.asarray(v).dtype.kind in "USO":
                continue
            unit = rec.segment_units.get(k, "1")
            cols[f"{k}_deg" if unit == "rad" else k] = np.degrees(v) if unit == "rad" else v
        if c.kind == "tilt-table":
            ref, _, _ = tilt_table_reference(rec)
            cols.update({f"ref_f_{a}_m_s2": ref[:, j] for j, a in enumerate("xyz")})
    names = list(cols)
    return names, np.column_stack([np.asarray(cols[k], float) for k in names])


def _string_columns(rec: Recording) -> dict:
    return {k: v for k, v in rec.segments.items() if np.asarray(v).dtype.kind in "USO"}


def write_mat(path: Path, c: BenchCampaign, rec: Recording, seg_names, seg_table, template) -> None:
    col = lambda x: np.asarray(x, float).reshape(-1, 1)
    segs = {k: col(seg_table[:, j]) for j, k in enumerate(seg_names)}
    for k, v in _string_columns(rec).items():
        segs[k] = np.array([str(s) for s in v], dtype=object).reshape(-1, 1)
    runs = rec.meta.get("runs", [])
    savemat(path, {"time_s": col(rec.time_s), "channels": {k: col(v) for k, v in rec.channels.items()},
                   "units": dict(rec.units), "events": {k: col(v) for k, v in rec.events.items()},
                   "segments": segs, "runs": np.array(list(runs), dtype=object).reshape(-1, 1),
                   "meta_json": to_json(rec.meta), "campaign": c.name,
                   "parameter_names": np.array([p["name"] for p in template], dtype=object).reshape(-1, 1),
                   "parameter_units": np.array([p["unit"] for p in template], dtype=object).reshape(-1, 1)},
            do_compression=True, oned_as="column")


def _readme(c: BenchCampaign, truth_path: Path, template) -> str:
    lines = [f"imurig export of campaign '{c.name}' ({c.spec.description}).", "",
             "recording.csv   the recording in the lab CSV format (imurig README, 'The lab CSV format')",
             "recording.mat   the same for MATLAB/Octave", ("segments.csv    one row per acquisition window "
             "(windows, set-points, the nominal reference the lab computes from them)"),
             ("parameters.csv  fill in value and std_error (1 sigma) for every row; any unit of the right "
             "dimension is accepted"), "", MAT_LAYOUT, "", "Parameters to estimate:"]
    lines += [f"  {p['name']:28s} {p['unit']}" for p in template]
    lines += ["", "Score your estimates (the truth is kept outside this folder):",
              f"  imurig score --truth {truth_path} --estimates estimates.csv --out score", ""]
    return "\n".join(lines)


def export_campaign(name: str, out, seed: int | None = None, truth_out=None, overwrite: bool = False,
                    mat: bool = True) -> dict:
    """Write the export folder ``out`` and the truth file (module doc). Returns the manifest."""
    c = campaign(name, seed)
    out = Path(out)
    truth_path = Path(truth_out) if truth_out else out.with_name(out.name + ".truth.json")
    if truth_path.resolve().is_relative_to(out.resolve()):
        raise ImurigError(f"the truth file {truth_path} would sit inside the export folder {out}; put it elsewhere "
                          "(the user's code must never see it)")
    if truth_path.exists() and not overwrite:
        raise OutputExistsError(f"{truth_path} exists; choose another --truth-out or pass --overwrite")
    rec = c.recording()
    truth = c.truth()
    template = c.template()
    seg_names, seg_table = segment_table(c, rec)
    with OutputFolder(out, overwrite=overwrite) as folder:
        write_csv(rec, folder.file("recording.csv"), overwrite=True)
        files = {"recording_csv": "recording.csv", "segments": "segments.csv", "template_csv": "parameters.csv",
                 "template_json": "parameters.json", "manifest": "manifest.json",
                 "readme": "README.txt"}
        if mat:
            write_mat(folder.file("recording.mat"), c, rec, seg_names, seg_table, template)
            files["recording_mat"] = "recording.mat"
        np.savetxt(folder.file("segments.csv"), seg_table, delimiter=",", header=",".join(seg_names), comments="",
                   fmt="%.12g")
        with open(folder.file("parameters.csv"), "w", encoding="utf-8") as fh:
            fh.write("name,value,std_error,unit\n")
            fh.writelines(f"{p['name']},,,{p['unit']}\n" for p in template)
        folder.write_json("parameters.json", {"parameters": template})
        digest = hashlib.sha256(folder.file("recording.csv").read_bytes()).hexdigest()
        manifest = {"format": "imurig-export", "version": 1, "campaign": c.name, "kind": c.kind,
                    "description": c.spec.description, "channels": {k: rec.units[k] for k in rec.channels},
                    "segment_columns": seg_names, "samples": rec.n, "segments": rec.n_segments,
                    "parameters": template, "files": files, "recording_csv_sha256": digest}
        folder.write_json("manifest.json", manifest)
        folder.write_text("README.txt", _readme(c, truth_path, template))
        text = json.dumps({**json.loads(to_json(truth.to_dict())), "recording_csv_sha256": digest}, indent=1)
        atomic_write(truth_path, lambda tmp: tmp.write_text(text + "\n"), overwrite)
    return {**manifest, "out": str(out), "truth": str(truth_path)}
