"""The six-position-and-rotation protocol (as imucal and imu_tk users run it): a box turned onto
its six faces, then rotated by hand through a known angle about each axis.

Recognition (:func:`detect`), from the data alone:
- still samples: over a moving window of ``window_s``, every accelerometer and gyro channel's
  standard deviation is below ``k_still`` x its noise floor (the 10th percentile of those moving
  standard deviations over the record), and the gyro's moving mean departs from its record median
  by less than ``max(gyro_still_rad_s, k_still x floor / sqrt(window))``;
- a static window (a face) is a run of still samples lasting at least ``min_still_s``; its face is
  the sign and axis of the mean specific force when that axis carries >= 90 % of its norm
  (windows on no face are listed and left out);
- a rotation is the motion between two static windows on the same face whose integrated gyro
  rate (bias removed) has one axis within 25 % of the known angle (default 360 deg); other
  motions (90 and 180 deg face changes) are not used.
All six faces (+-x, +-y, +-z) must be present, else the recording is refused.

Observations. Windows of one face (a face seen several times, or cut into sub-windows) pool into
one observation per face: its mean over all its samples, and the variance of that mean by batch
means over the same samples (``batches`` consecutive batches: var(batch means) / batches), which
follows the noise's correlation up to a batch length and does not change when a face is cut.

Accelerometer (forward model, indicated u = x / s_nom, per axis j, faces f = +-g e_k)::

    u_j = c_j + sum_k C_jk f_k [+ selected terms] + e_j,   cov(e_j) = diag(v_face,j) + s_j^2 I

fitted by generalised least squares with s_j^2 (face-level scatter beyond the noise: surface level,
model misfit) by REML; cov(beta) = (X' V^-1 X)^-1. A term beyond the linear model enters only when
it is identifiable on these faces and leaves at least ``min_dof`` residual degrees of freedom, and
then only if it lowers the BIC; the others are listed with the reason. Parameters:
sensitivity_j = C_jj s_nom,j, misalignment_jk = C_jk / C_jj, bias_j = c_j / C_jj (SI).

Gyro (integrated angles, :mod:`imurig.calibration.six_face_gyro`).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from imurig.calibration.accelerometer import SPEC as ACC_SPEC
from imurig.calibration.gls import delta_cov, white_variance_reml
from imurig.calibration.triad import nominal_sensitivity
from imurig.kernel.errors import RecordingError
from imurig.kernel.recording import Recording
from imurig.kernel.site import Site

FACES = ("+x", "-x", "+y", "-y", "+z", "-z")
GYRO_NAMES = (("gyro_p", "gyro_q", "gyro_r"), ("gyro_x", "gyro_y", "gyro_z"))


@dataclass
class Protocol:
    """What :func:`detect` found: sample slices per face, rotations, and what was left out."""

    faces: dict[str, list[slice]]
    rotations: list[dict] = field(default_factory=list)   # {slice, axis, sign, angle_rad, face}
    left_out: list[str] = field(default_factory=list)
    gyro_channels: tuple[str, ...] | None = None


def gyro_channels(rec: Recording) -> tuple[str, ...] | None:
    """The gyro triad's channel names in ``rec`` (gyro_p/q/r or gyro_x/y/z), or None."""
    return next((c for c in GYRO_NAMES if all(n in rec.channels for n in c)), None)


def _moving(x: np.ndarray, w: int) -> tuple[np.ndarray, np.ndarray]:
    """Centred moving mean and standard deviation (n, m) over w samples (edges: shorter windows)."""
    c1 = np.cumsum(np.vstack([np.zeros((1, x.shape[1])), x]), axis=0)
    c2 = np.cumsum(np.vstack([np.zeros((1, x.shape[1])), x * x]), axis=0)
    n = x.shape[0]
    lo = np.clip(np.arange(n) - w // 2, 0, n)
    hi = np.clip(np.arange(n) + w - w // 2, 0, n)
    cnt = (hi - lo)[:, None]
    m = (c1[hi] - c1[lo]) / cnt
    v = np.clip((c2[hi] - c2[lo]) / cnt - m * m, 0, None)
    return m, np.sqrt(v)


def still_mask(acc_u: np.ndarray, gyro_u: np.ndarray | None, fs: float, window_s: float = 0.5,
               k_still: float = 4.0, gyro_still_rad_s: float = np.radians(1.0)) -> np.ndarray:
    """Still samples (n,) by the rules of the module doc (acc_u, gyro_u indicated, SI)."""
    w = max(int(round(window_s * fs)), 5)
    x = acc_u if gyro_u is None else np.hstack([acc_u, gyro_u])
    m, s = _moving(x, w)
    floor = np.maximum(np.percentile(s, 10, axis=0), 1e-12)
    still = np.all(s < k_still * floor, axis=1)
    if gyro_u is not None:
        dev = np.abs(m[:, 3:] - np.median(gyro_u, axis=0))
        still &= np.all(dev < np.maximum(gyro_still_rad_s, k_still * floor[3:] / np.sqrt(w)), axis=1)
    return still


def face_of(f_mean: np.ndarray, share: float = 0.9) -> str | None:
    """'+x' ... '-z' when one axis carries >= ``share`` of the norm of f_mean, else None."""
    k = int(np.argmax(np.abs(f_mean)))
    if abs(f_mean[k]) < share * np.linalg.norm(f_mean):
        return None
    return ("+" if f_mean[k] > 0 else "-") + "xyz"[k]


def _runs(mask: np.ndarray) -> list[slice]:
    d = np.diff(np.concatenate(([0], mask.astype(int), [0])))
    return [slice(int(a), int(b)) for a, b in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1))]


def detect(rec: Recording, rotation_deg: float = 360.0, min_still_s: float = 1.0, window_s: float = 0.5) -> Protocol:
    """Recognise the six faces and the rotations in ``rec`` (module doc); RecordingError when a face lacks."""
    acc_s, _ = nominal_sensitivity(rec, ACC_SPEC)
    acc_u = rec.stack(ACC_SPEC.channels) / acc_s
    gch = gyro_channels(rec)
    gyro_u = None if gch is None else rec.stack(gch) / nominal_sensitivity(rec, _gyro_spec(), gch)[0]
    fs = rec.sample_rate_hz
    still = still_mask(acc_u, gyro_u, fs, window_s)
    windows, left = [], []
    for sl in _runs(still):
        if (sl.stop - sl.start) / fs < min_still_s:
            continue
        face = face_of(acc_u[sl].mean(axis=0))
        if face is None:
            left.append(f"static window {rec.time_s[sl.start]:.1f}-{rec.time_s[sl.stop - 1]:.1f} s: on no face "
                        "(no axis carries 90 % of gravity)")
            continue
        windows.append((sl, face))
    faces = {f: [sl for sl, g in windows if g == f] for f in FACES}
    missing = [f for f in FACES if not faces[f]]
    if missing:
        found = {f: len(v) for f, v in faces.items() if v}
        raise RecordingError(f"{rec.meta.get('source', 'the recording')}: the six-face protocol needs a static "
                             f"window (>= {min_still_s:g} s still) on each face; found {found}, missing {missing}. "
                             "Hold the box still on every face, or lower min_still_s")
    rotations = []
    if gyro_u is not None:
        bias = np.mean([np.concatenate([gyro_u[s] for s in faces[f]]).mean(axis=0) for f in FACES], axis=0)
        dt = 1.0 / fs
        for (a, fa), (b, fb) in zip(windows[:-1], windows[1:]):
            mv = slice(a.stop, b.start)
            if mv.stop - mv.start < 2:
                continue
            ang = (gyro_u[mv] - bias).sum(axis=0) * dt
            k = int(np.argmax(np.abs(ang)))
            if abs(abs(ang[k]) - np.radians(rotation_deg)) > 0.25 * np.radians(rotation_deg):
                continue
            if fa != fb:
                left.append(f"motion {rec.time_s[mv.start]:.1f}-{rec.time_s[mv.stop - 1]:.1f} s turns "
                            f"{np.degrees(ang[k]):.0f} deg but ends on face {fb}, not {fa}: not a closed rotation")
                continue
            rotations.append({"slice": mv, "axis": k, "sign": float(np.sign(ang[k])),
                              "angle_rad": float(np.sign(ang[k]) * np.radians(rotation_deg)), "face": fa})
    return Protocol(faces=faces, rotations=rotations, left_out=left, gyro_channels=gch)


def _gyro_spec():
    from imurig.calibration.gyro import SPEC  # the gyro module imports the turn table's rig

    return SPEC


def pooled_statistics(x: np.ndarray, slices: list[slice], batches: int = 10) -> tuple[np.ndarray, np.ndarray, int]:
    """(mean (m,), variance of the mean (m,), samples) of x over the union of ``slices`` (module doc)."""
    v = np.concatenate([x[s] for s in slices])
    n = v.shape[0] // batches
    if n < 2:
        raise RecordingError(f"a face holds {v.shape[0]} samples; at least {2 * batches} are needed")
    bm = v[: n * batches].reshape(batches, n, -1).mean(axis=1)
    return v.mean(axis=0), np.var(bm, axis=0, ddof=1) / batches, v.shape[0]


def face_table(x: np.ndarray, faces: dict[str, list[slice]], batches: int = 10):
    """Per face (FACES order): means (6, m), variances of the means (6, m), samples (6,)."""
    rows = [pooled_statistics(x, faces[f], batches) for f in FACES]
    return np.array([r[0] for r in rows]), np.array([r[1] for r in rows]), np.array([r[2] for r in rows])


def face_reference(g: float) -> np.ndarray:
    """Specific force (6, 3) on the faces in FACES order: +-g along the up axis."""
    F = np.zeros((6, 3))
    for i, f in enumerate(FACES):
        F[i, "xyz".index(f[1])] = g if f[0] == "+" else -g
    return F


def _gls(X: np.ndarray, y: np.ndarray, V: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    Vi = np.linalg.inv(V)
    cov = np.linalg.inv(X.T @ Vi @ X)
    return cov @ X.T @ Vi @ y, cov


def _term(F: np.ndarray, name: str) -> np.ndarray:
    idx = ["fx", "fy", "fz"]
    parts = name.split("*")
    if len(parts) == 1 and name.endswith("^2"):
        return F[:, idx.index(name[:-2])] ** 2
    return np.prod([F[:, idx.index(p)] for p in parts], axis=0)


def select_terms(F: np.ndarray, y: np.ndarray, var: np.ndarray, axis: int, min_dof: int = 2) -> tuple[list, list]:
    """Extra terms for one axis (module doc): (chosen names, [(name, reason) left out])."""
    base = np.column_stack([np.ones(len(y)), F])
    own = f"f{'xyz'[axis]}^2"
    cands = [own] + ["fx*fy", "fx*fz", "fy*fz"]
    chosen, left = [], []
    X = base
    for c in cands:
        col = _term(F, c)
        Xc = np.column_stack([X, col])
        sv = np.linalg.svd(Xc / np.maximum(np.linalg.norm(Xc, axis=0), 1e-300), compute_uv=False)
        if sv[-1] < 1e-6:
            left.append((c, "not identifiable on these positions (it is zero or a combination of the other "
                            "terms on every face)"))
            continue
        if len(y) - Xc.shape[1] < min_dof:
            left.append((c, f"{len(y)} positions leave {len(y) - Xc.shape[1]} residual degree(s) of freedom "
                            f"with it; at least {min_dof} are needed to test it"))
            continue
        V0 = np.diag(var) + white_variance_reml(X, y, np.diag(var)) * np.eye(len(y))
        V1 = np.diag(var) + white_variance_reml(Xc, y, np.diag(var)) * np.eye(len(y))
        if _bic(Xc, y, V1) < _bic(X, y, V0):
            chosen.append(c)
            X = Xc
        else:
            left.append((c, "tested: does not lower the BIC"))
    return chosen, left


def _bic(X, y, V) -> float:
    b, _ = _gls(X, y, V)
    r = y - X @ b
    return float(r @ np.linalg.solve(V, r) + np.linalg.slogdet(V)[1] + X.shape[1] * np.log(len(y)))


def fit_accelerometer(u_faces: np.ndarray, var_faces: np.ndarray, g: float, sensitivity=np.ones(3),
                      min_dof: int = 2, F: np.ndarray | None = None, unit: str = "1") -> dict:
    """The accelerometer's forward model on per-face means u_faces (n, 3) (SI, indicated) with the
    variances of those means (n, 3); F (n, 3) the reference (default: the six faces). Returns
    {'parameters': [{name, unit, estimate, std_error}], 'terms': {axis: names}, 'left_out': [...],
    'C', 'c' (the forward model's linear part and constant)}."""
    F = face_reference(g) if F is None else F
    betas, covs, terms, left = [], [], {}, {}
    for j, a in enumerate("xyz"):
        chosen, lo = select_terms(F, u_faces[:, j], var_faces[:, j], j, min_dof)
        for n, r in lo:
            left.setdefault((n if "*" in n else "own square", r), []).append(f"A_{a}")
        X = np.column_stack([np.ones(len(F)), F] + [_term(F, c) for c in chosen])
        K = np.diag(var_faces[:, j])
        V = K + white_variance_reml(X, u_faces[:, j], K) * np.eye(len(F))
        b, cov = _gls(X, u_faces[:, j], V)
        betas.append(b)
        covs.append(cov)
        terms[a] = ["1", "fx", "fy", "fz", *chosen]
    sizes = [len(b) for b in betas]
    off = np.concatenate([[0], np.cumsum(sizes)])
    beta = np.concatenate(betas)
    cov = np.zeros((off[-1], off[-1]))
    for j in range(3):
        cov[off[j]:off[j + 1], off[j]:off[j + 1]] = covs[j]
    sens = np.asarray(sensitivity, float)
    own = [terms["xyz"[j]].index(f"f{'xyz'[j]}^2") if f"f{'xyz'[j]}^2" in terms["xyz"[j]] else None
           for j in range(3)]

    def h(x):
        C = np.array([x[off[j] + 1:off[j] + 4] for j in range(3)])
        c = np.array([x[off[j]] for j in range(3)])
        G = np.diag(C)
        out = list(G * sens) + [C[i, k] / C[i, i] for i in range(3) for k in range(3) if i != k] + list(c / G)
        return np.array(out + [x[off[j] + own[j]] / G[j] for j in range(3) if own[j] is not None])

    est, se = h(beta), np.sqrt(np.clip(np.diag(delta_cov(h, beta, cov)), 0, None))
    names = ([(f"sensitivity_{a}", f"{unit}/(m/s^2)") for a in "xyz"]
             + [(f"misalignment_{'xyz'[i]}{'xyz'[k]}", "rad") for i in range(3) for k in range(3) if i != k]
             + [(f"bias_{a}", "m/s^2") for a in "xyz"]
             + [(f"nonlinearity_{'xyz'[j]}", "1/(m/s^2)") for j in range(3) if own[j] is not None])
    C = np.array([beta[off[j] + 1:off[j] + 4] for j in range(3)])
    c = np.array([beta[off[j]] for j in range(3)])
    return {"parameters": [{"name": n, "unit": u, "estimate": float(e), "std_error": float(s)}
                           for (n, u), e, s in zip(names, est, se)],
            "terms": terms, "left_out": [f"left out: {n} ({', '.join(ax)}): {r}" for (n, r), ax in left.items()],
            "C": C, "c": c, "coef_cov": cov}


def site_gravity(rec: Recording) -> float:
    """Local gravity (m/s^2) from the recording's site metadata (default site when absent)."""
    return Site.from_dict(rec.meta.get("site", {})).gravity_m_s2
