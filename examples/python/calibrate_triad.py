#!/usr/bin/env python3
"""A user's own triad calibrator, out of process: standard library + numpy only (no imurig).

Reads an `imurig export` folder (tilt-table or turn-table campaign), fits the sensor's
FORWARD model per axis by ordinary least squares on per-window statistics, and writes
estimates.csv (name,value,std_error,unit) for `imurig score`.

Forward model of axis i (q: the reference quantity per window from segments.csv, SI):

    V_i = s_i (a_i + b_i + k2_i a_i^2),   a = (I + M) q
        ~ c0 q_i + c1 q_j + c2 q_k + c3 + c4 q_i^2     (dropping k2 * M terms, ~1e-8 relative)

so s_i = c0, M_ij = c1 / c0, M_ik = c2 / c0, b_i = c3 / c0, k2_i = c4 / c0, with standard
errors from the OLS covariance sigma^2 (X'X)^-1 by the delta method.

    python3 calibrate_triad.py EXPORT_DIR [--out estimates.csv]
"""
import argparse
import json
import sys
from pathlib import Path

import numpy as np

KINDS = {  # channels, reference columns, window statistic, axis names, SI quantity unit
    "tilt-table": (("acc_x_V", "acc_y_V", "acc_z_V"), ("ref_f_x_m_s2", "ref_f_y_m_s2", "ref_f_z_m_s2"),
                   np.median, "xyz", "m/s^2"),
    "turn-table": (("gyro_p_V", "gyro_q_V", "gyro_r_V"), ("ref_w_p_rad_s", "ref_w_q_rad_s", "ref_w_r_rad_s"),
                   np.mean, "pqr", "rad/s"),
}


def read_lab_csv(path):
    """(header names, data array) of a lab CSV: '#' metadata lines, a header row, numbers."""
    skip = 0
    with open(path, encoding="utf-8") as fh:
        for line in fh:
            skip += 1
            if not line.startswith("#"):
                header = line.strip().split(",")
                break
    data = np.loadtxt(path, delimiter=",", skiprows=skip, usecols=None, ndmin=2)
    return header, data


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("export_dir")
    ap.add_argument("--out", default="estimates.csv")
    a = ap.parse_args(argv)
    d = Path(a.export_dir)
    kind = json.loads((d / "manifest.json").read_text())["kind"]
    if kind not in KINDS:
        sys.exit(f"this example calibrates tilt-table and turn-table exports, not {kind}")
    chans, refcols, stat, axes, qunit = KINDS[kind]
    header, data = read_lab_csv(d / "recording.csv")
    t = data[:, header.index("time_s")]
    V = data[:, [header.index(c) for c in chans]]
    seg = np.genfromtxt(d / "segments.csv", delimiter=",", names=True)
    q = np.column_stack([seg[c] for c in refcols])                      # reference per window, SI
    lo = np.searchsorted(t, seg["start_s"], side="left")
    hi = np.searchsorted(t, seg["stop_s"], side="left")
    Vw = np.array([stat(V[i:j], axis=0) for i, j in zip(lo, hi)])       # per-window statistic, volts

    rows = []
    for i, ai in enumerate(axes):
        j, k = [m for m in range(3) if m != i]
        X = np.column_stack([q[:, i], q[:, j], q[:, k], np.ones(len(q)), q[:, i] ** 2])
        c, *_ = np.linalg.lstsq(X, Vw[:, i], rcond=None)
        r = Vw[:, i] - X @ c
        sigma2 = r @ r / (len(r) - X.shape[1])
        C = sigma2 * np.linalg.inv(X.T @ X)
        est = {"sensitivity": c[0], f"misalignment_{axes[j]}": c[1] / c[0], f"misalignment_{axes[k]}": c[2] / c[0],
               "bias": c[3] / c[0], "nonlinearity": c[4] / c[0]}
        # delta method: d(c_m / c0)/dc = e_m / c0 - e_0 c_m / c0^2
        se = {"sensitivity": np.sqrt(C[0, 0])}
        for key, m in ((f"misalignment_{axes[j]}", 1), (f"misalignment_{axes[k]}", 2), ("bias", 3),
                       ("nonlinearity", 4)):
            g = np.zeros(5)
            g[m] = 1 / c[0]
            g[0] = -c[m] / c[0] ** 2
            se[key] = np.sqrt(g @ C @ g)
        units = {"sensitivity": f"V/({qunit})", "bias": qunit, "nonlinearity": f"1/({qunit})"}
        for key, v in est.items():
            name = f"misalignment_{ai}{key[-1]}" if key.startswith("misalignment") else f"{key}_{ai}"
            rows.append((name, v, se[key], units.get(key, "rad")))

    with open(a.out, "w", encoding="utf-8") as fh:
        fh.write("name,value,std_error,unit\n")
        for name, v, s, u in rows:
            fh.write(f"{name},{float(v)!r},{float(s)!r},{u}\n")
    print(f"wrote {a.out}: {len(rows)} parameters from {len(q)} windows")


if __name__ == "__main__":
    main()
