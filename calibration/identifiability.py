"""Identifiability of a linear model: the rank test of a design matrix and, when it fails, the
message that names the terms the data cannot separate and the linear relation between them.

Rank test: the columns of X (n, p) are scaled to unit norm, X/|X| = U S V'; the design is rank
deficient when s_min <= max(n, p) eps s_max. The null space (the last rows of V') in echelon form
gives one relation per dependency, sum_j c_j X_j = 0, printed as ``last = sum(...)``.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from imurig.kernel.errors import UnidentifiableTermsError

#: A term takes part in a linear dependency if its component in a null-space
#: vector exceeds this fraction of the vector's largest component.
RELATIVE_SUPPORT_TOL = 1e-6


def as_float_array(a, what: str) -> np.ndarray:
    """``a`` as float64, refused (ValueError) if it is not real numeric."""
    arr = np.asarray(a)
    if arr.dtype.kind not in "biuf":
        raise ValueError(f"{what} must be a real numeric array, got dtype {arr.dtype}")
    return arr.astype(np.float64, copy=False)


def _rref_rows(M: np.ndarray, tol: float) -> np.ndarray:
    """Reduced row echelon form of ``M`` (k, p) with partial pivoting (small matrices)."""
    A = M.astype(np.float64, copy=True)
    k, p = A.shape
    r = 0
    for c in range(p):
        if r == k:
            break
        piv = r + int(np.argmax(np.abs(A[r:, c])))
        if abs(A[piv, c]) <= tol:
            continue
        A[[r, piv]] = A[[piv, r]]
        A[r] /= A[r, c]
        others = np.arange(k) != r
        A[others] -= np.outer(A[others, c], A[r])
        r += 1
    return A[:r]


def _format_relation(names: list[str], c: np.ndarray, support: np.ndarray) -> tuple[str, str]:
    """Express ``sum_j c_j X_j = 0`` as ``last = sum(...)``; returns (relation, dependent term)."""
    idx = np.flatnonzero(support)
    k = idx[-1]
    if idx.size == 1:
        return f"column of '{names[k]}' is identically zero (the term is never excited)", names[k]
    parts = []
    for j in idx[:-1]:
        a = -c[j] / c[k]
        mag = f"{abs(a):.6g}"
        if names[j] == "1":
            body = mag
        else:
            body = names[j] if mag == "1" else f"{mag}*{names[j]}"
        sign = "-" if a < 0 else "+"
        parts.append((sign, body))
    rhs = ("-" if parts[0][0] == "-" else "") + parts[0][1]
    for sign, body in parts[1:]:
        rhs += f" {sign} {body}"
    return f"{names[k]} = {rhs}", names[k]


def unidentifiable_error(names: list[str], Vt: np.ndarray, sv: np.ndarray, tol: float,
                         scale: np.ndarray) -> UnidentifiableTermsError:
    """The error naming the dependent terms of a rank-deficient design (module doc)."""
    p = len(names)
    rank = int(np.sum(sv > tol))
    null = Vt[rank:]  # (k, p) orthonormal basis of the null space (scaled coordinates)
    # echelon form with pivots taken from the *last* columns: each row then expresses
    # one distinct later term through earlier ones (and disjoint dependencies separate)
    rows = _rref_rows(null[:, ::-1], 1e-9)[:, ::-1]
    supports = np.abs(rows) > RELATIVE_SUPPORT_TOL * np.max(np.abs(rows), axis=1, keepdims=True)
    # merge dependencies that share terms into groups
    parent = list(range(len(rows)))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i in range(len(rows)):
        for j in range(i + 1, len(rows)):
            if np.any(supports[i] & supports[j]):
                parent[find(i)] = find(j)
    groups: dict[int, list[int]] = {}
    for i in range(len(rows)):
        groups.setdefault(find(i), []).append(i)
    involved = np.any(supports, axis=0)
    terms = [names[j] for j in range(p) if involved[j]]
    lines = []
    drop = []
    for members in groups.values():
        gsupport = np.any(supports[members], axis=0)
        gnames = [names[j] for j in range(p) if gsupport[j]]
        rels = []
        members = sorted(members, key=lambda i: np.flatnonzero(supports[i])[-1])
        for i in members:
            rel, dep = _format_relation(names, rows[i] / scale, supports[i])
            rels.append(rel)
            drop.append(dep)
        lines.append(f"  - {{{', '.join(gnames)}}}: " + "; ".join(rels))
    msg = (
        f"design matrix is rank deficient (numerical rank {rank} of {p} columns, "
        f"{p - rank} linear dependenc{'y' if p - rank == 1 else 'ies'}): these terms cannot be separated "
        f"by the data:\n" + "\n".join(lines) + "\n"
        "Fix: add positions/observations that excite these terms independently of each other, "
        f"or drop terms (e.g. drop {', '.join(repr(d) for d in sorted(drop, key=names.index))})."
    )
    return UnidentifiableTermsError(msg, terms)


def check_identifiable(X: np.ndarray, names: Sequence[str]) -> None:
    """Raise :class:`UnidentifiableTermsError` if the (n, p) design ``X`` is rank deficient.

    Same test as :func:`fit_ols` (column-scaled SVD, tolerance
    ``max(n, p) * eps * s_max``), but also usable when n <= p and without y.
    """
    X = as_float_array(X, "X")
    if X.ndim != 2 or X.shape[1] != len(names) or X.shape[1] == 0:
        raise ValueError(f"X must be (n, {len(names)}) with one column per name, got {X.shape}")
    if not np.isfinite(X).all():
        raise ValueError("X contains NaN or inf")
    n, p = X.shape
    scale = np.linalg.norm(X, axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    _, sv, Vt = np.linalg.svd(X / scale, full_matrices=True)
    tol = max(n, p) * np.finfo(np.float64).eps * (sv[0] if sv.size else 0.0)
    if sv.size < p or sv[-1] <= tol:
        raise unidentifiable_error(list(names), Vt, sv, tol, scale)
